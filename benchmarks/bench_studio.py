"""Studio latency in headless Chromium (Debian's chromium, driven by playwright).

(a) face_relight.yaml at 512²: a light slider of one Render (l_left60.azimuth_deg) → the
    page's preview of that Render updated (MakeLight + Render re-run through the cache, the
    rest cached).  Peer: the Render node's own compute time in the same run (from the run's
    node events), so the rest is the studio's overhead (load, keys, store write, PNG, browser).
(d) room_relight.yaml: a real-light emittance slider of Relight's live view → the view's image
    updated (Relight's linear fast path over the websocket).  Peer: the fast path's own compute
    time for the same frame (reported by the server).

    .venv/bin/python benchmarks/bench_studio.py [--n 20] [--backend opengl] [--only a|d]

Prints median, p95 and best in ms.  The first run of face_relight (FaceMesh, fit, …) and of
room_relight (radiosity) fill the cache (minutes); later runs only re-run what a slider moves.
"""
from __future__ import annotations

import argparse
import os
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "support")]

from studio_support import Server, browser_page, wait_for, wait_run  # noqa: E402


def pct(xs, q):
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))]


def report(name, xs, peer=None):
    line = f"{name}: median {statistics.median(xs):.1f} ms, p95 {pct(xs, 0.95):.1f} ms, best {min(xs):.1f} ms (n={len(xs)})"
    if peer:
        line += f"; peer median {statistics.median(peer):.1f} ms, best {min(peer):.1f} ms, ratio {statistics.median(xs) / statistics.median(peer):.2f}"
    print(line, flush=True)


SLIDE = """async ([sel, value]) => {
  const r = document.querySelector(sel);
  const before = window.studio.previewLoads;
  const t0 = performance.now();
  r.value = value; r.dispatchEvent(new Event(r.type === 'range' ? 'input' : 'change', {bubbles: true}));
  while (window.studio.previewLoads === before) await new Promise(f => setTimeout(f, 1));
  return performance.now() - t0;
}"""

VIEW_SLIDE = """async ([sel, value]) => {
  const r = document.querySelector(sel);
  const img = document.querySelector('#view-body img.view-img');
  const before = +img.dataset.frames;
  const t0 = performance.now();
  r.value = value; r.dispatchEvent(new Event('input', {bubbles: true}));
  while (+img.dataset.frames === before || !img.complete) await new Promise(f => setTimeout(f, 1));
  await img.decode();
  return performance.now() - t0;
}"""


def opened(pw, graph, tmp, cache, *extra):
    """(server, browser, context, page) with the graph open and its first run finished."""
    s = Server(ROOT / "graphs" / graph, tmp, *extra, plugins="", cache=cache)
    b, ctx = browser_page(pw)
    page = ctx.new_page()
    page.goto(s.url)
    page.wait_for_selector("#dag g.node")
    wait_run(page, timeout=3600)
    return s, b, ctx, page


def bench_a(pw, tmp, n, backend, cache):
    s, b, ctx, page = opened(pw, "face_relight.yaml", tmp, cache, *(["--backend", backend] if backend else []))
    try:
        gen = page.eval_on_selector("#run-status", "e => +e.dataset.gen")
        if s.api("/api/state")["graph_params"]["size"] != 512:
            s.api("/api/params", {"changes": [{"node": None, "param": "size", "value": 512}]})
            wait_run(page, after_gen=gen, timeout=3600)
        page.click('#dag g.node[data-node="l_left60"]')
        page.select_option("#preview-select", "left60.image")
        wait_for(lambda: page.get_attribute("#preview", "data-digest"), what="preview")
        # the slider's number box: exact values (a range input snaps to its step)
        sel = '#node-panel .ctl[data-param="azimuth_deg"] input[type=number]'
        page.wait_for_selector(sel)
        times, peer = [], []
        # values not in the cache yet: a random base per run, 6 decimals (a clock-based base
        # with 4 decimals repeated an earlier run's values when runs were ~13 s apart)
        base = -60.0 + random.SystemRandom().random()
        for i in range(n + 2):
            az = base + ((-1) ** i) * (1 + i * 0.013)
            gen0 = s.api("/api/state")["run"]["gen"]
            ms = page.evaluate(SLIDE, [sel, f"{az:.6f}"])
            st = wait_for(lambda: (lambda x: x if x["run"]["gen"] > gen0 and x["run"]["status"] in ("ok", "failed")
                                   else None)(s.api("/api/state")), 120, "the run to finish")
            assert "left60" in st["run"].get("computed", []), st["run"]
            secs = next(x for x in st["nodes"] if x["name"] == "left60").get("seconds")
            if i >= 2:  # the first moves warm up imports and the browser
                times.append(ms)
                if secs:
                    peer.append(secs * 1e3)
        report(f"(a) slider -> Render preview, face_relight 512^2{' backend ' + backend if backend else ''}", times, peer)
        print("    peer = the Render node's compute (same run)")
    finally:
        ctx.close()
        b.close()
        s.stop()


def bench_d(pw, tmp, n, cache):
    s, b, ctx, page = opened(pw, "room_relight.yaml", tmp, cache)
    try:
        page.click('#dag g.node[data-node="a_off"]')
        sel = '#view-body input[type=range][data-key="B"]'
        page.wait_for_selector(sel, timeout=120_000)
        page.wait_for_function("() => +document.querySelector('#view-body img.view-img').dataset.frames > 0")
        times, peer = [], []
        for i in range(n + 3):
            ms = page.evaluate(VIEW_SLIDE, [sel, str(0.5 + (i % 7) * 0.3)])
            info = page.inner_text("#view-body .view-info")
            if i >= 3:
                times.append(ms)
                try:
                    peer.append(float(info.split(":")[1].split("ms")[0]))
                except (IndexError, ValueError):
                    pass
        report("(d) room emittance slider -> view image, room_relight", times, peer)
        print("    peer = Relight's fast path compute for the frame (server side)")
    finally:
        ctx.close()
        b.close()
        s.stop()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--backend", default="")
    ap.add_argument("--only", choices=("a", "d"), default=None)
    ap.add_argument("--cache", default=os.environ.get("GRAPHKIT_CACHE", str(ROOT / ".graphkit-cache")),
                    help="cache folder (reuse one that already holds face_relight / room_relight)")
    args = ap.parse_args()
    os.environ["GRAPHKIT_CACHE"] = args.cache
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        if args.only in (None, "a"):
            bench_a(pw, Path(tmp) / "a", args.n, args.backend, args.cache)
        if args.only in (None, "d"):
            bench_d(pw, Path(tmp) / "d", args.n, args.cache)


if __name__ == "__main__":
    main()
