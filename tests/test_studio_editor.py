"""The studio's node editor in a real browser (Debian's chromium, driven by playwright): build
graphs/quickstart.yaml's graph on an empty canvas through the palette and mouse drags, have a
mismatched link refused with the engine's message, save, validate, run, see the preview, drag
a parameter and see the pixels change.  The server side of the edits is tested in
tests/test_studio_units.py."""
from __future__ import annotations

from pathlib import Path

import pytest

from conftest import graphkit
from studio_support import (Server, browser_page, click_node, drag_link, drawn_nodes, need_browser,
                            wait_for, wait_run)

pytestmark = pytest.mark.xdist_group("studio")
ROOT = Path(__file__).resolve().parents[1]

NODES = [("photo", "LoadImage"), ("smooth", "Blur"), ("detail", "RatioImage"), ("sheet", "ContactSheet"),
         ("save_photo", "SaveImage"), ("save_detail", "SaveImage"), ("save_sheet", "SaveImage")]
LINKS = [("photo", "image", "smooth", "image"), ("photo", "image", "detail", "a"),
         ("smooth", "image", "detail", "b"), ("photo", "image", "sheet", "images"),
         ("smooth", "image", "sheet", "images"), ("detail", "ratio", "sheet", "images"),
         ("photo", "image", "save_photo", "image"), ("detail", "ratio", "save_detail", "image"),
         ("sheet", "image", "save_sheet", "image")]
PARAMS = [("photo", "path", "builtin:astronaut"), ("save_photo", "path", "photo.exr"),
          ("save_detail", "path", "detail.exr"), ("save_sheet", "path", "contact_sheet.png")]


def links(page, node):
    return page.evaluate("n => studio.state.nodes.find(x => x.name === n)?.inputs || []", node)


def add_node(page, name, typ):
    """Add a ``typ`` node from the palette (search, Enter) and rename it ``name`` (F2)."""
    page.click("#palette-search")
    page.fill("#palette-search", typ)
    assert page.is_visible(f'#palette li[data-type="{typ}"]')
    page.press("#palette-search", "Enter")
    wait_for(lambda: any(n.startswith(typ[0].lower() + typ[1:]) for n in drawn_nodes(page)), what=f"{typ} added")
    new = next(n for n in drawn_nodes(page) if n.startswith(typ[0].lower() + typ[1:]))
    page.click("#fit-btn")
    click_node(page, new)
    page.once("dialog", lambda d: d.accept(name))
    page.keyboard.press("F2")
    wait_for(lambda: name in drawn_nodes(page), what=f"{new} renamed {name}")


def preview_pixels(page):
    return page.evaluate("""() => { const c = document.getElementById('preview');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let s = 0; for (let i = 0; i < d.length; i += 4) s += d[i] + 2 * d[i + 1] + 3 * d[i + 2]; return [c.width, s]; }""")


def test_build_quickstart_on_an_empty_canvas(tmp_path):
    need_browser()
    from playwright.sync_api import sync_playwright

    g = tmp_path / "empty.yaml"
    g.write_text("graphkit: 1\nname: quickstart\n# built in the studio\nnodes: {}\n")
    s = Server(g, tmp_path)
    try:
        with sync_playwright() as pw:
            b, ctx = browser_page(pw)
            page = ctx.new_page()
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(s.url)
            page.wait_for_function("() => document.querySelectorAll('#palette li').length > 10")
            for name, typ in NODES:
                add_node(page, name, typ)
            for src, sport, dst, dport in LINKS:
                before = len(links(page, dst))
                page.click("#fit-btn")
                drag_link(page, src, sport, dst, dport)
                wait_for(lambda: len(links(page, dst)) > before, what=f"{src}.{sport} → {dst}.{dport}")
                assert [dport, src, sport] in links(page, dst)
            assert page.is_hidden("#edit-msg")

            # a link dragged off its input and dropped on the empty canvas is removed; undo brings it back
            x, y = page.evaluate("a => studio.editor.slotPoint(a[0], a[1], true)", ["save_detail", "image"])
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x - 40, y + 200, steps=6)
            page.mouse.up()
            wait_for(lambda: links(page, "save_detail") == [], what="the link removed")
            page.keyboard.press("Control+z")
            wait_for(lambda: links(page, "save_detail") == [["image", "detail", "ratio"]], what="the link back")

            # a link whose types do not fit: refused with the loader's own message, nothing drawn
            add_node(page, "blur_x", "Blur")
            page.click("#fit-btn")
            drag_link(page, "save_photo", "file", "blur_x", "image")
            wait_for(lambda: page.is_visible("#edit-msg"), what="the refusal")
            msg = page.text_content("#edit-msg")
            assert "node 'blur_x', input 'image' takes Image but save_photo.file gives File" in msg, msg
            assert links(page, "blur_x") == []
            click_node(page, "blur_x")  # delete it again (the Delete key, on the canvas)
            page.keyboard.press("Delete")
            wait_for(lambda: "blur_x" not in drawn_nodes(page), what="blur_x deleted")
            page.keyboard.press("Control+z")  # undo brings it back, redo deletes it again
            wait_for(lambda: "blur_x" in drawn_nodes(page), what="the delete undone")
            page.keyboard.press("Control+Shift+z")
            wait_for(lambda: "blur_x" not in drawn_nodes(page), what="the delete redone")

            for node, param, value in PARAMS:
                click_node(page, node)
                field = f'#node-panel .ctl[data-param="{param}"] input[type=text]'
                page.fill(field, value)
                page.press(field, "Enter")
                wait_for(lambda: page.evaluate("a => studio.state.nodes.find(x => x.name === a[0]).raw_params[a[1]]",
                                               [node, param]) == value, what=f"{node}.{param}")
            # duplicate (Ctrl+D): the same type and params, then deleted again
            click_node(page, "photo")
            page.keyboard.press("Control+d")
            wait_for(lambda: "loadImage1" in drawn_nodes(page), what="the duplicate")
            raw = "n => studio.state.nodes.find(x => x.name === n).raw_params"
            assert page.evaluate(raw, "loadImage1") == {"path": "builtin:astronaut"}
            page.click("#fit-btn")
            click_node(page, "loadImage1")
            page.click("#delete-btn")
            wait_for(lambda: "loadImage1" not in drawn_nodes(page), what="the duplicate deleted")
            wait_for(lambda: page.evaluate("studio.state.graph.valid"), what="a valid graph")
            # the run of the graph as built (an earlier run's "ok", with the duplicate, may still be on show)
            built = sorted(name for name, _ in NODES)
            wait_for(lambda: page.evaluate("(r => r.status === 'ok' && [...r.computed, ...r.cached].sort())(studio.state.run)")
                     == built, 120, "the run of the built graph")

            page.once("dialog", lambda d: d.accept("built.yaml"))
            page.click("#save-btn")
            saved = tmp_path / "built.yaml"
            wait_for(saved.exists, what="saved file")
            text = saved.read_text()
            assert "# built in the studio" in text
            r = graphkit("validate", saved)
            assert r.returncode == 0, r.stdout + r.stderr
            _same_shape(saved, ROOT / "graphs" / "quickstart.yaml")

            # its preview: the contact sheet, then a drag on the blur's slider changes its pixels
            click_node(page, "smooth")  # (a click shows the node's own image: the sheet chosen after it)
            page.select_option("#preview-select", "sheet.image")
            wait_for(lambda: page.evaluate("(c => c.dataset.digest && c.dataset.digest === studio.state.nodes"
                                           ".find(n => n.name === 'sheet').digests.image)(document.getElementById('preview'))"),
                     what="the sheet's preview")
            w, before = preview_pixels(page)
            assert w > 500
            gen = page.evaluate("+document.getElementById('run-status').dataset.gen")
            box = page.locator('#node-panel .ctl[data-param="sigma_px"] input[type=range]').bounding_box()
            page.mouse.move(box["x"] + 4, box["y"] + box["height"] / 2)
            page.mouse.down()
            page.mouse.move(box["x"] + box["width"] * 0.3, box["y"] + box["height"] / 2, steps=5)
            page.mouse.up()
            wait_run(page, after_gen=gen, timeout=120)
            wait_for(lambda: preview_pixels(page)[1] != before, 120, "the preview's pixels to change")
            # the viewer: 1:1 shows the image pixel for pixel, B compares a second output
            page.check("#one-to-one")
            assert page.evaluate("(c => c.clientWidth === c.width)(document.getElementById('preview'))")
            page.select_option("#compare-select", "smooth.image")
            wait_for(lambda: page.evaluate("document.getElementById('preview-b').width") > 0, what="the B image")
            assert page.is_visible("#compare-split")
            # the header stays one line whatever the path and the run's status say: the page below
            # does not move when a run starts or ends (a click or a drag then would land off)
            heights = [page.evaluate("t => { const e = document.getElementById('run-status'); e.textContent = t;"
                                     " return document.querySelector('header').offsetHeight; }", t)
                       for t in ("running", "failed: " + ", ".join(n for n, _ in NODES) * 3)]
            assert heights[0] == heights[1], heights
            assert errors == []
            b.close()
    finally:
        s.stop()


def _same_shape(a: Path, b: Path) -> None:
    """The graphs in ``a`` and ``b`` have the same nodes (names, types) and links."""
    from graphkit.graphfile import load_graph
    from graphkit.registry import default_registry

    reg = default_registry()
    ga, gb = load_graph(a, reg), load_graph(b, reg)
    shape = lambda g: {n: (gn.type, sorted(map(tuple, gn.edges()))) for n, gn in g.nodes.items()}  # noqa: E731
    assert shape(ga) == shape(gb)
