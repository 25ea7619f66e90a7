"""Screenshots of the studio on the four paper graphs (README), with Debian's headless Chromium.

    .venv/bin/python docs/studio_screenshots.py [--cache DIR]

Each graph is opened with `graphkit serve`, run through the cache (the first time takes
minutes: FaceMesh, fits, radiosity), a node with a live view is selected, and the page is
saved as docs/studio_<graph>.png.
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
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    import cv2

    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        b, ctx = browser_page(pw, webgl=True, viewport=(1400, 860))
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


if __name__ == "__main__":
    main()
