"""The studio's graph pane under a node drag, in headless Chromium (Debian's chromium, driven by
playwright): face_relight.yaml (39 nodes), a 200-instance sweep graph (603 graph nodes, drawn
as 6) and a graph of 200 distinct nodes, each opened with --no-run.

For each graph: a node is dragged with the mouse over 60 moves while the page records the time
between animation frames (performance.now() in requestAnimationFrame); then the canvas is
redrawn 30 times with a node moved each time, timing LGraphCanvas.draw alone; and the time of
ELK's layout on open (in a Web Worker) and the longest main-thread task while the page opened.

    .venv/bin/python benchmarks/bench_studio_editor.py

Prints, per graph: nodes drawn, frame interval median / p95 during the drag (16.7 ms = every
frame at 60 Hz), one redraw's median / p95, layout ms, longest task on open (ms; 0 = none over 50 ms).
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "support")]

from studio_support import Server, browser_page, wait_graph  # noqa: E402


def sweep_graph(folder: Path, n: int = 200) -> Path:
    vals = ", ".join(f"{{s: {1 + i * 0.05:.2f}}}" for i in range(n))
    p = folder / f"sweep{n}.yaml"
    p.write_text(f"""graphkit: 1
name: sweep{n}
sweeps:
  v:
    values: [{vals}]
nodes:
  photo: {{type: LoadImage, params: {{path: "builtin:astronaut"}}}}
  blur: {{type: Blur, foreach: v, inputs: {{image: photo.image}}, params: {{sigma_px: "${{v.s}}"}}}}
  ratio: {{type: RatioImage, foreach: v, inputs: {{a: photo.image, b: blur.image}}}}
  save: {{type: SaveImage, foreach: v, inputs: {{image: ratio.ratio}}, params: {{path: "r/${{v.name}}.exr"}}}}
  sheet: {{type: ContactSheet, inputs: {{images: "ratio[*].ratio"}}}}
  save_sheet: {{type: SaveImage, inputs: {{image: sheet.image}}, params: {{path: sheet.png, bits: 8}}}}
""")
    return p


def flat_graph(folder: Path, n: int = 200) -> Path:
    lines = ["graphkit: 1", f"name: flat{n}", "nodes:", '  n0: {type: LoadImage, params: {path: "builtin:astronaut"}}']
    lines += [f"  n{i}: {{type: Blur, inputs: {{image: n{(i - 1) // 2}.image}}, params: {{sigma_px: 1.0}}}}"
              for i in range(1, n)]
    p = folder / f"flat{n}.yaml"
    p.write_text("\n".join(lines) + "\n")
    return p


FRAMES = """() => { window.frames_ = []; let last = performance.now();
  const f = t => { window.frames_.push(t - last); last = t; if (window.frames_.length < 2000) requestAnimationFrame(f); };
  requestAnimationFrame(f); }"""
REDRAW = """() => { const c = studio.editor.canvas, n = Object.values(studio.editor.nodes)[0], ts = [];
  for (let i = 0; i < 30; i++) { n.pos[0] += 1; const t0 = performance.now(); c.draw(true, true); ts.push(performance.now() - t0); }
  ts.sort((a, b) => a - b); return [ts[15], ts[28]]; }"""


# every main-thread task over 50 ms from the page's start (Chromium's Long Tasks API)
LONG_TASKS = """window.longTasks_ = [];
new PerformanceObserver(l => { for (const e of l.getEntries()) window.longTasks_.push(e.duration); })
  .observe({ type: 'longtask', buffered: true });"""


def measure(pw, graph: Path, tmp: Path) -> dict:
    s = Server(graph, tmp / graph.stem, "--no-run", plugins="")
    try:
        b, ctx = browser_page(pw)
        page = ctx.new_page()
        page.add_init_script(LONG_TASKS)
        page.goto(s.url)
        wait_graph(page, timeout=120_000)
        page.wait_for_timeout(500)
        names = page.evaluate("Object.keys(studio.editor.nodes)")
        x, y = page.evaluate("n => studio.editor.nodePoint(n)", names[len(names) // 2])
        page.evaluate(FRAMES)
        page.mouse.move(x, y)
        page.mouse.down()
        for i in range(60):
            page.mouse.move(x + 3 * i, y + 2 * i)
        page.mouse.up()
        frames = sorted(page.evaluate("window.frames_.slice(2)"))
        draw = page.evaluate(REDRAW)
        out = {"drawn_nodes": len(names), "graph_nodes": page.evaluate("studio.state.nodes.length"),
               "frame_ms_median": round(frames[len(frames) // 2], 1),
               "frame_ms_p95": round(frames[int(len(frames) * 0.95)], 1),
               "redraw_ms_median": round(draw[0], 2), "redraw_ms_p95": round(draw[1], 2),
               "layout_ms": round(page.evaluate("studio.editor.layoutMs"), 0),
               # the page blocked while it opened: the longest main-thread task (layout off it)
               "longest_task_ms_on_open": round(max(page.evaluate("window.longTasks_"), default=0), 0)}
        b.close()
        return out
    finally:
        s.stop()


def main():
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as d, sync_playwright() as pw:
        tmp = Path(d)
        graphs = [ROOT / "graphs" / "face_relight.yaml", sweep_graph(tmp), flat_graph(tmp)]
        print(json.dumps({g.name: measure(pw, g, tmp) for g in graphs}, indent=1))


if __name__ == "__main__":
    main()
