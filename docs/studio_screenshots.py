"""Screenshots of the studio on the four paper graphs (README), with Debian's headless Chromium.

    .venv/bin/python docs/studio_screenshots.py [--cache DIR] [--probe-view]

Each graph is opened with `graphkit serve`, run through the cache (the first time takes
minutes: FaceMesh, fits, radiosity), a node with a live view is selected, and the page is
saved as docs/studio_<graph>.png.  ``--probe-view``: only docs/studio_probe_view.png, ProbeLight's
view on a varied probe the finder refuses, the ball marked by hand and snapped to its outline.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "support")]

from studio_support import Server, browser_page, click_node, wait_graph, wait_run  # noqa: E402

SHOTS = {  # graph: (node to select, preview)
    "face_relight": ("left60", "sheet.image"),
    "blush": ("rig", "sheet.image"),
    "room_relight": ("a_off", "sheet.image"),
    "makeup": ("made_up", "sheet.image"),
}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", default=os.environ.get("GRAPHKIT_CACHE", str(ROOT / ".graphkit-cache")))
    ap.add_argument("--probe-view", action="store_true", help="only the probe view's screenshot")
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    import cv2

    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        b, ctx = browser_page(pw, webgl=True, viewport=(1400, 860))
        if args.probe_view:
            return probe_view(ctx, Path(tmp))
        for g, (node, preview) in SHOTS.items():
            s = Server(ROOT / "graphs" / f"{g}.yaml", Path(tmp) / g, plugins="", cache=args.cache)
            try:
                page = ctx.new_page()
                page.goto(s.url)
                wait_graph(page)
                wait_run(page, timeout=3600)
                click_node(page, node)
                page.select_option("#preview-select", preview)
                page.wait_for_function("() => document.getElementById('preview').dataset.digest")
                if page.query_selector("#view-panel:not([hidden])"):
                    # an image view (a frame in) or a WebGL view (a canvas)
                    page.wait_for_function("() => { const i = document.querySelector('#view-body img.view-img');"
                                           " return (i && +i.dataset.frames > 0 && i.complete)"
                                           " || document.querySelector('#view-body canvas'); }", timeout=120_000)
                    page.wait_for_timeout(1500)
                page.evaluate("studio.editor.fit()")
                raw = Path(tmp) / f"{g}.png"
                page.screenshot(path=str(raw))
                img = cv2.imread(str(raw))
                img = cv2.resize(img, (1050, round(img.shape[0] * 1050 / img.shape[1])), interpolation=cv2.INTER_AREA)
                out = ROOT / "docs" / f"studio_{g}.png"
                cv2.imwrite(str(out), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
                print(out, out.stat().st_size // 1024, "KiB")
                page.close()
            finally:
                s.stop()
        ctx.close()
        b.close()


def probe_view(ctx, tmp: Path):
    """ProbeLight's view (nodes/paris/probe_view.js) on a varied Mitsuba probe the finder refuses
    (nodes/paris/data/varied_probes.py, tune tv01 at 3×, 1152×864): the refusal, a circle typed
    in as a hand would mark it (the true circle of make_probes.truth 2.5 px right, 1.5 px up,
    1.5 px larger), then "Snap to outline": the snapped circle, its note and the direction
    ProbeLight gives for it."""
    from nodes.io.images import encode_image
    from nodes.paris.data.make_probes import render, truth
    from nodes.paris.data.varied_probes import varied

    spec = varied("tune", 2, scale=3)[1]
    (tmp / "probe.exr").write_bytes(encode_image(render(spec), ".exr", 16))
    t = truth(spec)
    g = tmp / "probe_mark.yaml"
    g.write_text(f"""graphkit: 1
name: probe_mark
nodes:
  probe_photo: {{type: LoadImage, params: {{path: probe.exr}}}}
  probe: {{type: ProbeLight, inputs: {{probe: probe_photo.image}}, params: {{fov_deg: {t['fov_deg']}}}}}
  save: {{type: SaveImage, inputs: {{image: probe.classes}}, params: {{path: classes.exr}}}}
outputs: {{classes: save.file}}
""")
    s = Server(g, tmp, plugins="", cache=tmp / "cache")
    try:
        page = ctx.new_page()
        page.goto(s.url)
        wait_graph(page)
        page.wait_for_function("() => document.getElementById('run-status').dataset.status === 'failed'",
                               timeout=60_000)
        click_node(page, "probe")
        page.wait_for_selector(".probe-view .probe-reason", timeout=60_000)
        n = page.get_attribute(".probe-readout", "data-frames")
        hand = {"centre_x": t["centre_x"] + 2.5, "centre_y": t["centre_y"] - 1.5, "radius": t["radius"] + 1.5}
        for k in ("centre_x", "centre_y", "radius"):
            page.fill(f'.probe-view input[data-key="{k}"]', f"{hand[k]:.2f}")
        page.wait_for_function("n => +document.querySelector('.probe-readout').dataset.frames > n + 1", arg=int(n))
        n = page.get_attribute(".probe-readout", "data-frames")
        page.click(".probe-snap")
        page.wait_for_function("() => document.querySelector('.probe-snapped').dataset.sure !== undefined",
                               timeout=60_000)
        page.wait_for_function("n => +document.querySelector('.probe-readout').dataset.frames > n", arg=int(n))
        page.wait_for_timeout(500)
        out = ROOT / "docs" / "studio_probe_view.png"
        page.locator("#view-panel").screenshot(path=str(out))
        print(out, out.stat().st_size // 1024, "KiB; true direction", t["direction"])
    finally:
        s.stop()

if __name__ == "__main__":
    main()
