"""The studio's probe view (nodes/paris/studio_view.py ProbeView + probe_view.js): where
ProbeLight refuses to find the mirror ball, a person marks it.  The sample capture's probe
(nodes/paris/data/sample_capture, 128², ball at (64, 64) radius 28.45) is refused by the finder
(a uniform environment: its rim a thin line, not a mirror's), so the view starts from the
circle the finder was not sure of and shows the refusal; the circle is dragged in real headless Chromium (Debian's), the direction
readout is ProbeLight's own, and "apply" writes the graph params the node's circle is bound to
into the graph file (comments kept) through the studio's edit and save path.  The server side
refuses bad circles with ProbeLight's own messages and writes nothing then."""
from __future__ import annotations

import contextlib
import json

import numpy as np
import pytest

from conftest import ROOT, graphkit
from studio_support import Server, browser_page, click_node, need_browser, wait_for, wait_graph

pytestmark = pytest.mark.xdist_group("studio")

GRAPH = """\
# ProbeLight on the sample probe, its ball to be marked (a comment to keep)
graphkit: 1
name: probe_mark
params:
  data: "builtin:sample_capture"
  # the ball (pixels); null: ProbeLight finds it
  ball_x: null
  ball_y: null     # its centre's y
  ball_radius: null
nodes:
  probe_photo: {type: LoadImage, params: {path: "${params.data}/probe.exr"}}
  probe:
    type: ProbeLight
    inputs: {probe: probe_photo.image}
    params: {centre_x: "${params.ball_x}", centre_y: "${params.ball_y}", radius: "${params.ball_radius}"}
  save: {type: SaveImage, inputs: {image: probe.classes}, params: {path: classes.exr}}
outputs:
  classes: save.file
"""


SAMPLE_PROBE = ROOT / "nodes" / "paris" / "data" / "sample_capture" / "probe.exr"


def probelight_direction(cx, cy, r):
    """The flash direction ProbeLight gives on the sample probe with this circle."""
    return probelight_direction_of(SAMPLE_PROBE, cx, cy, r)


def probelight_direction_of(path, cx, cy, r):
    """The flash direction ProbeLight gives on the probe file ``path`` with this circle."""
    from graphkit import Image
    from nodes.io.images import read_image
    from nodes.paris.probe import ProbeLight

    px, _ = read_image(str(path))
    out = ProbeLight(ProbeLight.Params(centre_x=cx, centre_y=cy, radius=r)).compute(probe=Image(px))
    return np.array(out["light"].direction)


@pytest.fixture
def studio(tmp_path):
    from graphkit.studio.core import Studio

    p = tmp_path / "g.yaml"
    p.write_text(GRAPH)
    st = Studio(p, cache=str(tmp_path / "c"), out=None)
    assert st.wait_idle(60)["status"] == "failed"  # the finder refuses the sample probe
    yield st, p
    st.close()


def test_probe_view_refuses_bad_circles_with_probelights_messages(studio):
    """In process: the view starts from the finder's best circle and says why ProbeLight
    refused; frame() is ProbeLight's compute with the circle given (its direction, bit for bit),
    and a circle it cannot use is refused with its own message (its Params' for a radius ≤ 0, its
    compute's for a circle off the image); commit() checks the circle before it gives any change."""
    from graphkit import BadInput
    from nodes.io.images import read_image
    from nodes.paris import ballfind
    from nodes.paris.studio_view import ProbeView

    st, _ = studio
    v = ProbeView(st, "probe")
    d = v.data()
    # the finder's best circle, which it refused (a thin line, not a mirror's rim): the start
    best = ballfind.find_ball(read_image(str(SAMPLE_PROBE))[0])
    assert not best.confident
    assert d["how"] == "best" and d["circle"] == {"centre_x": round(best.cx, 2), "centre_y": round(best.cy, 2),
                                                  "radius": round(best.r, 2)}
    assert np.hypot(best.cx - 64.0, best.cy - 64.0) < 1.0
    assert "cannot find the mirror ball with confidence" in d["reason"]
    assert "mark the ball in the studio" in d["reason"]  # the refusal points to this view
    assert (d["width"], d["height"], d["probe"]) == (128, 128, {"node": "probe_photo", "port": "image"})
    assert d["exposure"] == 3.2  # the probe's median 0.020 shown at 0.18
    good = {"centre_x": 64.0, "centre_y": 64.0, "radius": 28.45}
    f = v.frame(good)
    assert f["direction"] == list(probelight_direction(64.0, 64.0, 28.45))
    assert f["frame"].startswith("probe camera")
    bad = [({**good, "radius": -3.0}, "radius", "Input should be greater than 0 (got -3.0)"),
           ({**good, "centre_x": 400.0}, "probe", "the ball (centre 400.0, 64.0, radius 28.4 px) covers too few pixels"),
           ({**good, "centre_y": None}, "centre_y", "give a number (got None)"),
           ({**good, "radius": True}, "radius", "give a number (got True)")]
    for values, port, message in bad:
        for call in (v.frame, v.commit):
            with pytest.raises(BadInput) as e:
                call(values)
            assert (e.value.port, e.value.message) == (port, message)
    # the circle bound to graph params: those change, the node keeps its references
    assert v.commit({"centre_x": 66.004, "centre_y": 63.0, "radius": 28.5}) == [
        {"node": None, "param": "ball_x", "value": 66.0}, {"node": None, "param": "ball_y", "value": 63.0},
        {"node": None, "param": "ball_radius", "value": 28.5}]


def test_a_circle_written_as_node_params_is_added_to_the_node(tmp_path):
    """A ProbeLight whose circle is not in the graph file: apply adds the three params to the
    node's own params (the rest of the file as it was)."""
    from graphkit.studio.core import Studio
    from nodes.paris.studio_view import ProbeView

    p = tmp_path / "g.yaml"
    text = GRAPH.replace('    params: {centre_x: "${params.ball_x}", centre_y: "${params.ball_y}", '
                         'radius: "${params.ball_radius}"}\n', "    params: {saturation: 0.98}   # kept\n")
    p.write_text(text)
    st = Studio(p, cache=str(tmp_path / "c"), out=None)
    try:
        st.wait_idle(60)
        v = ProbeView(st, "probe")
        changes = v.commit({"centre_x": 64, "centre_y": 64.5, "radius": 28.45})
        assert changes == [{"node": "probe", "param": k, "value": x}
                           for k, x in (("centre_x", 64.0), ("centre_y", 64.5), ("radius", 28.45))]
        assert st.set_params(changes)["ok"]
        assert st.doc.text == text.replace("{saturation: 0.98}", "{saturation: 0.98, centre_x: 64.0, centre_y: 64.5, radius: 28.45}")
    finally:
        st.close()


def test_the_view_starts_from_the_circle_probelight_found(tmp_path):
    """Where ProbeLight finds the ball (a synthetic probe of tests/test_paris_probe_ring.py,
    no ring), the view starts from the circle it found, with no refusal."""
    from graphkit.studio.core import Studio
    from nodes.io.images import encode_image
    from nodes.paris.studio_view import ProbeView
    from test_paris_probe_ring import CX, CY, R, _flash, _probe

    (tmp_path / "probe.exr").write_bytes(encode_image(_probe(_flash(20.0)).pixels, ".exr", 32))
    p = tmp_path / "g.yaml"
    p.write_text(GRAPH.replace("${params.data}/probe.exr", "probe.exr").replace(
        '    params: {centre_x: "${params.ball_x}", centre_y: "${params.ball_y}", radius: "${params.ball_radius}"}\n',
        ""))
    st = Studio(p, cache=str(tmp_path / "c"), out=None)
    try:
        assert st.wait_idle(60)["status"] == "ok"
        d = ProbeView(st, "probe").data()
        assert d["how"] == "found" and d["reason"] == ""
        assert np.allclose([d["circle"][k] for k in ("centre_x", "centre_y", "radius")], [CX, CY, R], atol=0.5)
    finally:
        st.close()


def test_snap_in_process_gives_the_outline_and_how_far_to_trust_it(studio):
    """frame() with ``snap`` answers ProbeLight's snap_outline near the circle (no direction):
    on the sample probe, from the starting guess 3.5 px too large, a circle within 1 px of the
    ball, not sure, and why; the circle keyed by the node's params, to 1/100 px."""
    from nodes.io.images import read_image
    from nodes.paris.probe import snap_outline
    from nodes.paris.studio_view import ProbeView

    st, _ = studio
    v = ProbeView(st, "probe")
    values = {"centre_x": 64.0, "centre_y": 64.0, "radius": 32.0}
    f = v.frame({**values, "snap": True})
    px, _ = read_image(str(SAMPLE_PROBE))
    want = snap_outline(px, (64.0, 64.0, 32.0))
    assert f["snap"]["circle"] == dict(zip(("centre_x", "centre_y", "radius"), (round(x, 2) for x in want["circle"])))
    assert np.hypot(f["snap"]["circle"]["centre_x"] - 64.0, f["snap"]["circle"]["centre_y"] - 64.0) < 1.0
    assert f["snap"]["sure"] is False and f["snap"]["reason"] == want["reason"] != ""
    assert "direction" not in f


def ws_commit(s, values, save, want_id=1):
    """Apply over the studio's websocket (as the page's Apply button): its answer."""
    from websockets.sync.client import connect

    with connect(f"ws://127.0.0.1:{s.port}/ws?token={s.token}", open_timeout=10) as c:
        c.send(json.dumps({"type": "commit", "node": "probe", "values": values, "id": want_id, "save": save}))
        while True:
            m = c.recv(timeout=30)
            if isinstance(m, str) and (m := json.loads(m)).get("type") == "commit" and m.get("id") == want_id:
                return m


def test_apply_refused_writes_nothing(tmp_path):
    """Over the websocket (token as every request): a bad circle or a file outside the graph's
    folder is refused with its message; neither the graph file nor the studio's graph changes."""
    p = tmp_path / "g.yaml"
    p.write_text(GRAPH)
    s = Server(p, tmp_path, plugins=None)
    try:
        wait_for(lambda: s.api("/api/state")["run"]["status"] == "failed", 60, "the first run")
        good = {"centre_x": 64.0, "centre_y": 64.0, "radius": 28.45}
        for values, save, message in [({**good, "radius": -1}, "g.yaml", "Input should be greater than 0"),
                                      ({**good, "centre_x": -90}, "g.yaml", "covers too few pixels"),
                                      (good, "../g.yaml", "the studio saves only into the graph's folder"),
                                      (good, "g.txt", "a graph file name ends in .yaml")]:
            m = ws_commit(s, values, save)
            assert m["ok"] is False and message in m["errors"][0]["text"], m
            assert "Traceback" not in m["errors"][0]["text"]
        assert p.read_text() == GRAPH and not (tmp_path.parent / "g.yaml").exists()
        st = s.api("/api/state")
        assert st["graph_params"]["ball_x"] is None and not st["graph"]["dirty"]
    finally:
        s.stop()


@pytest.fixture(scope="module")
def pw():
    need_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        yield p


@contextlib.contextmanager
def probe_page(pw, graph, tmp_path, status):
    """The studio on ``graph`` in a headless Chromium page, its run ended with ``status``, the
    ProbeLight node clicked: (page, the page's errors, the server)."""
    s = Server(graph, tmp_path, plugins=None)
    b, ctx = browser_page(pw)
    errors = []
    ctx.on("weberror", lambda e: errors.append(str(e.error)))
    try:
        page = ctx.new_page()
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.goto(s.url)
        wait_graph(page)
        wait_for(lambda: page.eval_on_selector("#run-status", "e => e.dataset.status") == status, 60, "the run")
        click_node(page, "probe")
        yield page, errors, s
    finally:
        ctx.close()
        b.close()
        s.stop()


def drag(page, sel, dx, dy):
    """A real mouse drag of the SVG handle ``sel`` by (dx, dy) screen pixels."""
    h = page.locator(sel)
    h.scroll_into_view_if_needed()
    b = h.bounding_box()
    x, y = b["x"] + b["width"] / 2, b["y"] + b["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + dx / 2, y + dy / 2, steps=2)
    page.mouse.move(x + dx, y + dy, steps=2)
    page.mouse.up()


def test_mark_the_ball_in_the_browser_and_apply(pw, tmp_path):
    """The refused probe in the page: the refusal shown, the whole photo at full size, the circle
    the finder refused to start from (then (64, 64, 32) typed in); at 4:1 a
    drag of the centre handle by (+8, −4) screen px moves the centre by exactly (+2, −1) probe
    px, one of the radius handle by −14 px makes the radius 28.5; the readout is ProbeLight's
    direction for that circle (a radius typed < 0: ProbeLight's message); Apply writes ball_x/ball_y/ball_radius into the graph file
    (comments and order kept), `graphkit validate` accepts it and the re-run succeeds."""
    from nodes.io.images import read_image
    from nodes.paris import ballfind

    p = tmp_path / "g.yaml"
    p.write_text(GRAPH)
    with probe_page(pw, p, tmp_path, "failed") as (page, errors, s):
        page.wait_for_selector("#view-body .probe-view .probe-reason")
        assert "ProbeLight refused: " in page.inner_text(".probe-reason")
        assert "mark the ball in the studio" in page.inner_text(".probe-reason")
        page.wait_for_function("() => document.querySelector('.probe-photo').naturalWidth === 128")
        page.select_option(".probe-zoom", "4")
        wait_for(lambda: page.evaluate("() => document.querySelector('.probe-photo').getBoundingClientRect().width")
                 == 512, 10, "the photo at 4:1")

        def readout(after):
            page.wait_for_function("n => +document.querySelector('.probe-readout').dataset.frames > n", arg=after)
            return page.inner_text(".probe-readout"), int(page.get_attribute(".probe-readout", "data-frames"))

        def fields():
            return [float(page.input_value(f'.probe-view input[data-key="{k}"]'))
                    for k in ("centre_x", "centre_y", "radius")]

        readout(0)
        best = ballfind.find_ball(read_image(str(SAMPLE_PROBE))[0])
        assert fields() == [round(best.cx, 2), round(best.cy, 2), round(best.r, 2)]  # the finder's best
        assert "not sure of" in page.inner_text(".probe-view .dim")
        for k, x in (("centre_x", 64), ("centre_y", 64), ("radius", 32)):  # a circle to drag from
            page.fill(f'.probe-view input[data-key="{k}"]', str(x))
        first = probelight_direction(64.0, 64.0, 32.0)
        first = f"flash direction (probe camera (x right, y down, z forward) frame): ({', '.join(f'{x:.4f}' for x in first)})"
        wait_for(lambda: page.inner_text(".probe-readout") == first, 10, "the direction for the typed circle")
        n = int(page.get_attribute(".probe-readout", "data-frames"))
        drag(page, ".probe-handle-centre", 8, -4)
        wait_for(lambda: fields()[:2] == [66.0, 63.0], 10, "the centre moved by (+2, -1) px")
        drag(page, ".probe-handle-radius", -14, 0)
        wait_for(lambda: fields() == [66.0, 63.0, 28.5], 10, "the radius 28.5 px")
        want = probelight_direction(66.0, 63.0, 28.5)
        text = f"flash direction (probe camera (x right, y down, z forward) frame): ({', '.join(f'{x:.4f}' for x in want)})"
        wait_for(lambda: readout(n)[0] == text, 10, "ProbeLight's direction for the dragged circle")
        assert text != first
        page.fill('.probe-view input[data-key="radius"]', "-3")  # typed: ProbeLight's own message
        wait_for(lambda: "port 'radius': Input should be greater than 0" in page.inner_text(".probe-readout"), 10,
                 "the message for a negative radius")
        page.fill('.probe-view input[data-key="radius"]', "28.5")
        wait_for(lambda: page.inner_text(".probe-readout") == text, 10, "the direction again")
        gen = s.api("/api/state")["run"]["gen"]
        page.click(".probe-apply")
        wait_for(lambda: "written to" in page.inner_text(".probe-applied"), 30, "the graph written")
        assert page.inner_text(".probe-applied").strip() == f"written to {p}"
        saved = p.read_text()
        assert saved == (GRAPH.replace("ball_x: null", "ball_x: 66.0").replace("ball_y: null", "ball_y: 63.0")
                         .replace("ball_radius: null", "ball_radius: 28.5"))
        cli = graphkit("validate", p)
        assert cli.returncode == 0, cli.stderr
        st = wait_for(lambda: (lambda x: x if x["run"]["gen"] > gen and x["run"]["status"] != "running" else None)(
            s.api("/api/state")), 60, "the run after apply")
        assert st["run"]["status"] == "ok" and not st["graph"]["dirty"]
        assert not errors, errors


def test_snap_a_circle_dragged_off_the_ball_in_the_browser(pw, tmp_path):
    """A probe whose ball ProbeLight finds (tests/test_paris_probe_ring.py's, 320×240): at 4:1
    the circle is dragged 3 px right and 2 px up and 1.5 px larger, "Snap to outline" brings it
    back to within 0.1 px of the ball's circle, says it is sure, and the readout is ProbeLight's
    direction for the snapped numbers; "Undo" puts the dragged circle back."""
    from nodes.io.images import encode_image
    from test_paris_probe_ring import CX, CY, R, _flash, _probe

    (tmp_path / "probe.exr").write_bytes(encode_image(_probe(_flash(20.0)).pixels, ".exr", 32))
    p = tmp_path / "g.yaml"
    p.write_text(GRAPH.replace("${params.data}/probe.exr", "probe.exr"))
    with probe_page(pw, p, tmp_path, "ok") as (page, errors, _):
        page.wait_for_selector("#view-body .probe-view .probe-snap")
        page.wait_for_function("() => document.querySelector('.probe-photo').naturalWidth === 320")
        page.select_option(".probe-zoom", "4")
        wait_for(lambda: page.evaluate("() => document.querySelector('.probe-photo').getBoundingClientRect().width")
                 == 1280, 10, "the photo at 4:1")

        def fields():
            return [float(page.input_value(f'.probe-view input[data-key="{k}"]'))
                    for k in ("centre_x", "centre_y", "radius")]

        wait_for(lambda: np.allclose(fields(), [CX, CY, R], atol=0.5), 10, "the circle found")
        found = fields()
        drag(page, ".probe-handle-centre", 12, -8)
        wait_for(lambda: np.allclose(fields()[:2], [found[0] + 3, found[1] - 2], atol=0.01), 10, "the centre dragged")
        drag(page, ".probe-handle-radius", 6, 0)
        wait_for(lambda: abs(fields()[2] - (found[2] + 1.5)) < 0.3, 10, "the radius dragged")
        dragged = fields()
        page.click(".probe-snap")
        wait_for(lambda: "snapped" in page.inner_text(".probe-snapped"), 30, "the snap")
        assert page.get_attribute(".probe-snapped", "data-sure") == "true", page.inner_text(".probe-snapped")
        assert "snapped to the ball's outline" in page.inner_text(".probe-snapped")
        snapped = fields()
        assert np.hypot(snapped[0] - CX, snapped[1] - CY) < 0.1 and abs(snapped[2] - R) < 0.1, snapped
        want = probelight_direction_of(tmp_path / "probe.exr", *snapped)
        text = f"flash direction (probe camera (x right, y down, z forward) frame): ({', '.join(f'{x:.4f}' for x in want)})"
        wait_for(lambda: page.inner_text(".probe-readout") == text, 10, "ProbeLight's direction for the snapped circle")
        page.click(".probe-undo")
        wait_for(lambda: fields() == dragged, 10, "the dragged circle back")
        assert page.inner_text(".probe-snapped").strip() == ""
        assert not errors, errors
