"""The studio (`graphkit serve`) in a real headless Chromium against a real server process.

Test graphs use the small image nodes of tests/support/studionodes.py; the paper graphs in
graphs/ are opened (not run) to check that the page draws every one of them.
"""
from __future__ import annotations

import collections

import json
import os
import signal
import threading
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, engine_env, graphkit
from studio_support import (Server, browser_page, click_node, drawn_nodes, need_browser, node_state, run_status,
                            wait_for, wait_graph, wait_run)

pytestmark = pytest.mark.xdist_group("studio")

GRAPH = """\
# yaml-language-server: $schema=../graph.schema.json
graphkit: 1
name: studio_test
params:
  level: 0.25     # linear level of the flat image (a comment to keep)
nodes:
  flat:
    type: Flat
    params: {level: "${params.level}", size: 16}
  gain:
    type: Gain
    inputs: {image: flat.image}
    params: {stops: 0.0}   # exposure change
  side:
    type: Flat
    params: {level: 0.5, size: 8}
  save:
    type: SaveImage
    inputs: {image: gain.image}
    params: {path: gain.exr}
  save_side:
    type: SaveImage
    inputs: {image: side.image}
    params: {path: side.exr}
outputs: {gain: save.file, side: save_side.file}
"""


@pytest.fixture(scope="module")
def pw():
    need_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        yield p


@pytest.fixture
def browser(pw):
    b, ctx = browser_page(pw)
    errors = []
    ctx.on("weberror", lambda e: errors.append(str(e.error)))
    yield ctx, errors
    ctx.close()
    b.close()


@pytest.fixture
def server(tmp_path):
    made = []

    def start(text=GRAPH, *extra, name="g.yaml", **kw):
        p = tmp_path / name
        p.write_text(text)
        s = Server(p, tmp_path, *extra, **kw)
        made.append(s)
        return s, p

    yield start
    for s in made:
        s.stop()


def open_page(ctx, s):
    page = ctx.new_page()
    page.goto(s.url)
    wait_graph(page)
    return page


def manifest(s):
    return json.loads((s.out / "manifest.json").read_text())


def srgb8(x):
    """8-bit sRGB of a linear value (IEC 61966-2-1 through colour-science: the outside reference)."""
    import colour

    return int(np.round(np.clip(colour.cctf_encoding(np.clip(x, 0, 1), function="sRGB"), 0, 1) * 255))


def preview_pixel(page):
    """The centre pixel of the preview as the browser shows it (the preview canvas read back)."""
    return page.evaluate("""() => { const c = document.getElementById('preview');
        return Array.from(c.getContext('2d').getImageData(c.width >> 1, c.height >> 1, 1, 1).data); }""")


# ---------------------------------------------------------------------------------------------


def test_page_loads_for_every_graph(pw, tmp_path):
    """Each graph in graphs/ opens (without running): every node drawn, graph params as controls;
    zoomed out to a quarter, most nodes still show their names (drawn at a size read on screen)."""
    import yaml

    from graphkit.graphfile import load_graph
    from graphkit.registry import default_registry

    b, ctx = browser_page(pw)
    try:
        for g in sorted((ROOT / "graphs").glob("*.yaml")):
            data = yaml.safe_load(g.read_text())
            s = Server(g, tmp_path / g.stem, "--no-run", plugins="")
            try:
                errors = []
                page = ctx.new_page()
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.goto(s.url)
                wait_graph(page)
                drawn = drawn_nodes(page)
                # every node; a swept node's instances (foreach: NODE[INSTANCE]) as one node with their count
                names = list(load_graph(g, default_registry()).nodes)
                instances = collections.Counter(n.split("[")[0] for n in names if "[" in n)
                assert sorted(drawn) == sorted({n.split("[")[0] for n in names}), g.name
                titles = page.evaluate("Object.fromEntries(Object.entries(studio.editor.nodes).map(([k, n]) => [k, n.title]))")
                for n in drawn:
                    assert titles[n] == (f"{n} ×{instances[n]}" if n in instances else n), (g.name, n)
                assert page.eval_on_selector("#errors", "e => e.hidden"), (g.name, page.inner_text("#errors"))
                labelled = page.evaluate("""() => { const e = studio.editor, c = e.canvas.canvas;
                    e.canvas.ds.changeScale(0.25, [c.width / 2, c.height / 2]); e.canvas.draw(true, true);
                    return +document.getElementById('graph').dataset.labelled; }""")
                assert labelled >= len(drawn) / 2, (g.name, labelled, len(drawn))
                gp = page.eval_on_selector_all("#gp-controls .ctl", "es => es.map(e => e.dataset.param)")
                assert gp == list(data.get("params") or {}), g.name
                assert not errors, (g.name, errors)
                page.close()
            finally:
                assert s.stop() == 0
            assert not (s.cache / "keys").exists() or not any((s.cache / "keys").rglob("*.json")), \
                f"{g.name}: --no-run ran something"
    finally:
        ctx.close()
        b.close()


def test_slider_changes_preview_and_only_downstream_reruns(browser, server):
    ctx, errors = browser
    s, _ = server()
    page = open_page(ctx, s)
    wait_run(page)
    first = manifest(s)
    assert all(not n["hit"] for n in first["nodes"].values())
    click_node(page, "gain")
    page.wait_for_selector('#node-panel .ctl[data-param="stops"] input[type=range]')
    # the preview canvas is drawn when its pixels arrive (fetched, or pushed over the websocket):
    # wait until it shows gain's output (data-digest is set once the pixels are on the canvas)
    (gain_digest,) = first["nodes"]["gain"]["outputs"].values()
    wait_for(lambda: page.get_attribute("#preview", "data-digest") == gain_digest, what="gain's preview")
    assert preview_pixel(page)[:3] == [srgb8(0.25)] * 3
    gen = run_status(page)[1]
    before = page.get_attribute("#preview", "data-digest")
    page.fill('#node-panel .ctl[data-param="stops"] input[type=range]', "1")
    wait_run(page, after_gen=gen)
    wait_for(lambda: page.get_attribute("#preview", "data-digest") not in (before, None, ""), what="new preview")
    assert preview_pixel(page)[:3] == [srgb8(0.5)] * 3  # 0.25 × 2¹
    m = manifest(s)
    reran = sorted(n for n, v in m["nodes"].items() if not v["hit"])
    assert reran == ["gain", "save"], m["nodes"]
    assert m["nodes"]["flat"]["hit"] and m["nodes"]["side"]["hit"]
    from conftest import read_exr

    assert np.allclose(read_exr(s.out / "gain.exr"), 0.5, atol=1e-3)  # the usual --out files
    assert not errors


def test_request_without_token_is_refused(server):
    s, _ = server()
    for path in ("/", "/api/state", "/static/app.js", "/api/preview?node=flat&port=image", "/api/manifest"):
        for url in (s.base.rstrip("/") + path, s.base.rstrip("/") + path + ("&" if "?" in path else "?") + "token=wrong"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(url, timeout=10)
            assert e.value.code == 403, url
    for path, body in [("api/params", {"changes": [{"node": "gain", "param": "stops", "value": 2}]}), ("api/params", {}),
                       ("api/edit", {"edits": [{"op": "remove_node", "name": "gain"}]}), ("api/undo", {}),
                       ("api/stop", {}), ("api/save", {"path": "x.yaml"})]:
        req = urllib.request.Request(s.base + path, data=json.dumps(body).encode(), method="POST")
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(req, timeout=10)
        assert e.value.code == 403
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(s.base + "api/nodes", timeout=10)
    assert e.value.code == 403
    assert "gain" in [n["name"] for n in s.api("/api/state")["nodes"]]  # nothing was edited
    from websockets.exceptions import WebSocketException
    from websockets.sync.client import connect

    def ws(url, **kw):
        with connect(url, open_timeout=10, **kw) as c:
            return c.recv(timeout=10)

    ws_url = f"ws://127.0.0.1:{s.port}/ws"
    with pytest.raises(WebSocketException):
        ws(ws_url)
    with pytest.raises(WebSocketException):
        ws(ws_url + "?token=nope")
    with pytest.raises(WebSocketException):  # the token, from another site
        ws(ws_url + f"?token={s.token}", origin="http://evil.example")
    assert json.loads(ws(ws_url + f"?token={s.token}"))["type"] == "state"
    assert s.api("/api/state")["graph"]["name"] == "studio_test"
    # nothing was changed by the refused requests
    assert s.api("/api/state")["nodes"][1]["params"]["stops"] == 0.0


def test_param_change_over_the_websocket(server):
    """The page's sliders send {type: params} over the socket: the same set_params as POST
    /api/params (the loader's message for a bad value, nothing applied), answered by id."""
    from websockets.sync.client import connect

    s, path = server()

    def answer(c, want_id):
        while True:
            m = json.loads(c.recv(timeout=20))
            if m.get("type") == "params" and m.get("id") == want_id:
                return m

    with connect(f"ws://127.0.0.1:{s.port}/ws?token={s.token}", open_timeout=10) as c:
        assert json.loads(c.recv(timeout=10))["type"] == "state"
        wait_for(lambda: s.api("/api/state")["run"]["status"] == "ok", 60, "the first run")
        c.send(json.dumps({"type": "params", "id": 1, "changes": [{"node": "gain", "param": "stops", "value": 9}]}))
        bad = answer(c, 1)
        assert bad["ok"] is False and "less than or equal to 4" in bad["errors"][0]["text"], bad
        assert f"{path}:" in bad["errors"][0]["text"] and "Traceback" not in bad["errors"][0]["text"]
        c.send(json.dumps({"type": "params", "id": 2, "changes": "nope"}))
        assert answer(c, 2)["ok"] is False
        gen = s.api("/api/state")["run"]["gen"]
        c.send(json.dumps({"type": "params", "id": 3, "changes": [{"node": "gain", "param": "stops", "value": 1}]}))
        got = answer(c, 3)
        assert got == {"type": "params", "id": 3, "ok": True, "errors": [], "gen": got["gen"]} and got["gen"] > gen
        st = wait_for(lambda: (lambda x: x if x["run"]["gen"] >= got["gen"] and x["run"]["status"] == "ok" else None)(
            s.api("/api/state")), 60, "the run of the change")
        assert st["run"]["computed"] == ["gain", "save"]
        assert next(n for n in st["nodes"] if n["name"] == "gain")["params"]["stops"] == 1.0


def test_an_edit_shows_its_run_as_running_at_once(browser, server):
    """When the page's param change is answered, the status already shows the run that change
    started, as running — not the last run's "ok" until the new run's first event (a user read
    that "ok" as the edit's result) — and an older run's state is not shown after it."""
    ctx, errors = browser
    s, _ = server()
    page = open_page(ctx, s)
    wait_run(page)
    click_node(page, "gain")
    page.wait_for_selector('#node-panel .ctl[data-param="stops"] input[type=range]')
    gen = run_status(page)[1]
    # what the status shows just after the page has handled the params answer (a macrotask
    # after it: the answer's promise and what follows it in the page have run by then)
    page.evaluate("""() => {
      window.seen = [];
      const ws = studio.ws, handle = ws.onmessage;
      ws.onmessage = ev => {
        handle(ev);
        const m = typeof ev.data === 'string' ? JSON.parse(ev.data) : {};
        if (m.type === 'params') setTimeout(() => { const e = document.getElementById('run-status');
          window.seen.push([m.gen, e.dataset.status, +e.dataset.gen]); }, 0);
      };
    }""")
    page.fill('#node-panel .ctl[data-param="stops"] input[type=range]', "1")
    wait_run(page, after_gen=gen)
    seen = wait_for(lambda: page.evaluate("window.seen"), what="the params answer")
    new, status, shown = seen[0]
    assert new > gen and shown == new and status in ("running", "ok"), seen   # ("ok": the new run's)
    status, shown = run_status(page)
    assert status == "ok" and shown >= new
    assert not errors


def test_out_of_range_value_shows_the_schema_error(browser, server, tmp_path):
    ctx, errors = browser
    s, path = server()
    page = open_page(ctx, s)
    wait_run(page)
    num = '#gp-controls .ctl[data-param="level"] input[type=number]'
    page.fill(num, "3")
    page.press(num, "Enter")
    err = wait_for(lambda: page.inner_text('#gp-controls .ctl[data-param="level"] .err'), what="error text")
    cli = graphkit("validate", path, "--set", "level=3", env=engine_env({"GRAPHKIT_PLUGINS": "studionodes"}))
    assert cli.returncode == 2
    assert err.strip() == cli.stderr.strip(), (err, cli.stderr)
    assert "less than or equal to 1" in err and "Traceback" not in err
    assert f"{path}:" in err  # file:line:col
    # the bad value was not applied: the graph still runs with the old one
    st = s.api("/api/state")
    assert st["graph_params"]["level"] == 0.25 and st["graph"]["valid"]
    assert not errors


def test_invalid_graph_opens_with_its_errors_and_runs_nothing(browser, server):
    ctx, errors = browser
    bad = GRAPH.replace("type: Gain", "type: Gian").replace("{path: gain.exr}", "{path: gain.exr, bits: 7}")
    s, path = server(bad)
    page = open_page(ctx, s)
    text = wait_for(lambda: page.inner_text("#errors") if not page.eval_on_selector("#errors", "e => e.hidden") else "",
                    what="errors shown")
    cli = graphkit("validate", path, env=engine_env({"GRAPHKIT_PLUGINS": "studionodes"}))
    assert cli.returncode == 2
    assert text.strip() == cli.stderr.strip()
    assert f"{path}:11:11: error: node 'gain': unknown node type 'Gian'; did you mean 'Gain'?" in text
    assert sorted(drawn_nodes(page)) == \
        ["flat", "gain", "save", "save_side", "side"]
    assert run_status(page)[0] in ("idle", "invalid")
    assert not any((s.cache / "keys").rglob("*.json")) if (s.cache / "keys").exists() else True
    assert not s.out.exists()
    assert not errors


def test_failing_node_shows_its_message_and_the_rest_keeps_working(browser, server):
    ctx, errors = browser
    text = GRAPH.replace("outputs: {gain: save.file, side: save_side.file}", """\
  boom:
    type: Boom
    inputs: {image: side.image}
  after_boom:
    type: Gain
    inputs: {image: boom.image}
outputs: {gain: save.file, side: save_side.file, boom: after_boom.image}
""")
    s, path = server(text)
    page = open_page(ctx, s)
    wait_run(page, "failed")
    cli = graphkit("run", path, "--cache", s.cache, "--out", s.out / "cli",
                   env=engine_env({"GRAPHKIT_PLUGINS": "studionodes"}))
    assert cli.returncode == 1
    assert node_state(page, "boom") == "failed"
    assert node_state(page, "after_boom") == "blocked"
    assert node_state(page, "gain") in ("done", "cached") and node_state(page, "save") in ("done", "cached")
    click_node(page, "boom")
    msg = page.inner_text("#node-msg")
    assert msg.strip() and msg.strip() in cli.stderr, (msg, cli.stderr)
    assert "boom went the node" in msg and "Traceback" not in msg
    # the page keeps working: a change elsewhere runs
    click_node(page, "gain")
    gen = run_status(page)[1]
    page.fill('#node-panel .ctl[data-param="stops"] input[type=range]', "2")
    wait_run(page, "failed", after_gen=gen)
    wait_for(lambda: node_state(page, "gain") == "done", what="gain re-ran")
    assert s.api("/api/state")["run"]["computed"] == ["gain", "save"]
    # a failed run writes no --out files (as the CLI)
    assert not (s.out / "manifest.json").exists()
    assert not errors


def test_second_tab_sees_the_same_state(browser, server):
    ctx, errors = browser
    s, _ = server()
    a = open_page(ctx, s)
    wait_run(a)
    b = ctx.new_page()
    b.goto(s.base)  # the cookie set by the first tab carries the token
    wait_graph(b)
    wait_run(b)
    a.fill('#gp-controls .ctl[data-param="level"] input[type=range]', "0.75")
    wait_for(lambda: b.input_value('#gp-controls .ctl[data-param="level"] input[type=number]') == "0.75",
             what="the other tab's control")
    wait_run(b, after_gen=1)
    wait_for(lambda: a.get_attribute("#preview", "data-digest") == b.get_attribute("#preview", "data-digest")
             and a.get_attribute("#preview", "data-digest"), what="the same preview")
    assert preview_pixel(b)[:3] == [srgb8(0.75)] * 3
    assert not errors


def test_save_as_graph_keeps_comments(browser, server, tmp_path):
    ctx, errors = browser
    s, path = server()
    page = open_page(ctx, s)
    wait_run(page)
    click_node(page, "gain")
    page.fill('#node-panel .ctl[data-param="stops"] input[type=number]', "1.5")
    page.press('#node-panel .ctl[data-param="stops"] input[type=number]', "Enter")
    wait_for(lambda: s.api("/api/state")["graph"]["dirty"], what="edited")
    page.once("dialog", lambda d: d.accept("saved.yaml"))
    page.click("#save-btn")
    saved = tmp_path / "saved.yaml"
    wait_for(saved.exists, what="saved file")
    text = saved.read_text()
    assert "params: {stops: 1.5}   # exposure change" in text
    assert "# linear level of the flat image (a comment to keep)" in text
    assert text.replace("stops: 1.5", "stops: 0.0") == GRAPH
    cli = graphkit("run", saved, "--cache", s.cache, "--out", tmp_path / "o2",
                   env=engine_env({"GRAPHKIT_PLUGINS": "studionodes"}))
    assert cli.returncode == 0, cli.stderr
    assert "0 computed" in cli.stderr  # the studio's run already cached every node
    assert not errors


@pytest.mark.parametrize("how", ["ctrl-c", "close-page"])
def test_interrupting_leaves_no_partial_cache_entry_or_output(browser, server, how):
    ctx, errors = browser
    text = GRAPH.replace("  save:\n    type: SaveImage\n    inputs: {image: gain.image}", """\
  nap:
    type: Nap
    inputs: {image: gain.image}
    params: {seconds: 5.0}   # long enough to be running once a loaded machine's page is up
  save:
    type: SaveImage
    inputs: {image: nap.image}""")
    s, _ = server(text)
    page = open_page(ctx, s)
    wait_for(lambda: node_state(page, "nap") == "running", what="nap running")
    if how == "close-page":
        page.close()
        wait_for(lambda: s.api("/api/state")["run"]["status"] == "ok", what="the run to finish")
        assert json.loads((s.out / "manifest.json").read_text())["nodes"]["nap"]["hit"] is False
    rc = s.stop(signal.SIGINT)
    assert rc == 0, s.stderr
    assert "Traceback" not in s.stderr
    leftovers = [p for p in (s.cache / "tmp").rglob("*")] if (s.cache / "tmp").exists() else []
    assert leftovers == []
    if s.out.exists():
        assert not [p for p in s.out.rglob("*") if p.name.endswith(".tmp")]
    if how == "ctrl-c":
        assert not (s.out / "manifest.json").exists()  # the run did not finish: nothing exported
    # every record in the cache is whole and names objects that exist
    r = graphkit("cache", "verify", "--cache", s.cache)
    assert r.returncode == 0, r.stdout + r.stderr


def napping_studio(tmp_path, engine_registry):
    """A Studio over GRAPH with a 1 s Nap node before the save (a run to stop or supersede)."""
    import enginenodes  # noqa: F401
    import studionodes

    from graphkit.studio.core import Studio

    engine_registry.add_provider("nodes", "tests", studionodes)
    p = tmp_path / "g.yaml"
    p.write_text(GRAPH.replace("  save:\n    type: SaveImage\n    inputs: {image: gain.image}", """\
  nap:
    type: Nap
    inputs: {image: gain.image}
    params: {seconds: 1.0}
  save:
    type: SaveImage
    inputs: {image: nap.image}"""))
    return Studio(p, cache=str(tmp_path / "c"), out=str(tmp_path / "o"), registry=engine_registry)


def test_newer_change_supersedes_a_stale_run(tmp_path, engine_registry):
    """Python-level: two quick changes; the first run stops at its next progress report."""
    st = napping_studio(tmp_path, engine_registry)
    try:
        wait_for(lambda: st.nodes.get("nap", {}).get("state") == "running", what="nap running")
        assert st.set_params([{"node": "nap", "param": "salt", "value": 1}])["ok"]
        info = st.wait_idle(30)
        assert info["status"] == "ok"
        m = json.loads((tmp_path / "o" / "manifest.json").read_text())
        rec = st.store.get_record(m["nodes"]["nap"]["key"])
        assert rec["parts"]["params"]["salt"] == 1
        # the stale run's nap (salt 0) never finished, so it was never cached
        keys = [st.store.get_record(f.stem) for f in (tmp_path / "c" / "keys").rglob("*.json")]
        assert sorted(k["parts"]["params"].get("salt") for k in keys if k["node"] == "nap") == [1]
    finally:
        st.close()


def test_a_studio_run_tells_its_nodes_they_are_in_a_live_session(tmp_path, engine_registry, monkeypatch):
    """Python-level: Context.interactive is True in the studio's runs (a node may prepare for
    the next change in the background, as Render fills its visibility basis) and False in a
    batch run of the same graph."""
    import studionodes

    from graphkit.api import run_graph

    seen, real = [], studionodes.Nap.compute

    def compute(self, image):
        seen.append(self.ctx.interactive)
        return real(self, image)
    monkeypatch.setattr(studionodes.Nap, "compute", compute)
    st = napping_studio(tmp_path, engine_registry)
    try:
        assert st.wait_idle(30)["status"] == "ok"
    finally:
        st.close()
    run_graph(tmp_path / "g.yaml", cache=tmp_path / "batch", registry=engine_registry)
    assert seen == [True, False]


def test_background_progress_reaches_the_node_after_its_run(tmp_path, engine_registry, monkeypatch):
    """Python-level: a node's work in a thread of its own after its compute returned reports
    through Context.background_progress; the studio sends it as the node's background /
    background_message (events and state: the page shows it on the node) after the run ended.
    In a batch run, and with a hook that raises, the call does nothing and never raises."""
    import studionodes

    from graphkit.api import run_graph
    from graphkit.node import Context

    real, threads = studionodes.Nap.compute, []

    def compute(self, image):
        out = real(self, image)
        ctx, go = self.ctx, threading.Event()
        threads.append((go, threading.Thread(target=lambda: go.wait(30) and [
            ctx.background_progress(f, "warming up") for f in (0.25, 1.0)])))
        threads[-1][1].start()
        return out
    monkeypatch.setattr(studionodes.Nap, "compute", compute)
    st = napping_studio(tmp_path, engine_registry)
    events = []
    try:
        assert st.wait_idle(30)["status"] == "ok"
        st.subscribe(lambda ev: events.append(ev) if ev.get("name") == "nap" else None)
        go, t = threads[0]
        go.set()  # (after the run)
        t.join(30)
        assert [(e["background"], e["background_message"]) for e in events] == [(0.25, "warming up"), (1.0, "warming up")]
        assert all(e["state"] == "done" for e in events)
        nap = next(n for n in st.state()["nodes"] if n["name"] == "nap")
        assert (nap["background"], nap["background_message"]) == (1.0, "warming up")
    finally:
        st.close()
    run_graph(tmp_path / "g.yaml", cache=tmp_path / "batch", registry=engine_registry)
    go, t = threads[1]
    go.set()
    t.join(30)
    assert not t.is_alive()

    def boom(fraction, message):
        raise RuntimeError("a page went away")
    Context(background=boom).background_progress(0.5, "x")  # does not raise


def test_background_progress_is_shown_on_the_node(browser, server, tmp_path):
    """A node's background work (Context.background_progress) in the page: on the node (the
    editor's state) and in its panel while it runs, gone once it reports 1."""
    ctx, errors = browser
    s, _ = server(GRAPH.replace("    type: Gain\n", "    type: Warm\n").replace("    params: {stops: 0.0}   # exposure change\n", ""))
    page = open_page(ctx, s)
    wait_run(page)
    click_node(page, "gain")
    wait_for(lambda: page.inner_text("#node-msg") == "warming up 50 %", what="the warm-up in the panel")
    assert page.evaluate("studio.editor.state.gain.background") == 0.5
    (tmp_path / "warm.done").write_text("")
    wait_for(lambda: page.evaluate("studio.editor.state.gain.background") == 1, what="the warm-up's end")
    assert page.inner_text("#node-msg") == ""
    assert not errors


def test_stop_ends_a_run_at_the_next_node(tmp_path, engine_registry):
    """Python-level: Stop (the editor's button, /api/stop) ends the run going; what it finished
    stays cached and the node it was in never is."""
    st = napping_studio(tmp_path, engine_registry)
    try:
        wait_for(lambda: st.nodes.get("nap", {}).get("state") == "running", what="nap running")
        st.stop()
        assert st.wait_idle(30)["status"] == "superseded"
        assert not (tmp_path / "o" / "manifest.json").exists()
        cached = {st.store.get_record(f.stem)["node"] for f in (tmp_path / "c" / "keys").rglob("*.json")}
        assert "gain" in cached and "nap" not in cached
    finally:
        st.close()


def test_live_view_hook_draws_frames_and_commits(browser, server):
    """A node class names a LiveView (studio_view); its ES module's slider draws through
    frame() over the websocket and, on release, commit() edits the graph and it re-runs."""
    ctx, errors = browser
    s, _ = server(GRAPH.replace("type: Gain", "type: ViewGain").replace("level: 0.25 ", "level: 0.125"))
    page = open_page(ctx, s)
    wait_run(page)
    click_node(page, "gain")
    sel = '#view-body input[type=range][data-key="stops"]'
    page.wait_for_selector(sel)
    page.wait_for_function("() => +document.querySelector('#view-body img.view-img').dataset.frames > 0")
    gen = run_status(page)[1]
    page.fill(sel, "2")  # input (frames) then change (commit)
    wait_for(lambda: page.evaluate("""() => { const i = document.querySelector('#view-body img.view-img');
        if (!i.complete || !i.naturalWidth) return null;
        const c = document.createElement('canvas'); c.width = i.naturalWidth; c.height = i.naturalHeight;
        const g = c.getContext('2d'); g.drawImage(i, 0, 0);
        return g.getImageData(4, 4, 1, 1).data[0]; }""") == srgb8(0.5), what="the view's frame at 0.125 × 2²")
    wait_run(page, after_gen=gen)
    st = s.api("/api/state")
    assert next(n for n in st["nodes"] if n["name"] == "gain")["params"]["stops"] == 2.0
    assert st["run"]["computed"] == ["gain", "save"]
    assert not errors


def test_preview_on_show_goes_out_before_the_rest_of_the_run(tmp_path, engine_registry):
    """Python-level: once a page has asked for gain's preview, a change that re-runs gain
    computes gain first, pushes the new pixels (the new digest; raw RGBA for a loopback page)
    before gain's node event, and the run goes on to the file writer only after the page
    said "shown" (Studio.served)."""
    import io
    import threading
    import time

    from PIL import Image as PILImage

    import enginenodes  # noqa: F401
    import studionodes

    from graphkit.studio.core import Studio

    engine_registry.add_provider("nodes", "tests", studionodes)
    p = tmp_path / "g.yaml"
    p.write_text(GRAPH)
    st = Studio(p, cache=str(tmp_path / "c"), out=str(tmp_path / "o"), registry=engine_registry)
    events, shown_at = [], []

    def page(ev):
        events.append((time.monotonic(), ev))
        if ev.get("type") == "preview":  # the page shows it a moment later
            def shown():
                time.sleep(0.1)
                shown_at.append(time.monotonic())
                st.served(ev["digest"])
            threading.Thread(target=shown).start()

    try:
        st.wait_idle(30)
        st.subscribe(page)
        assert st.preview("gain", "image", 0.0, 0, 0)  # the page shows gain.image
        assert st.set_params([{"node": "gain", "param": "stops", "value": 1.0}])["ok"]
        info = st.wait_idle(30)
        assert info["status"] == "ok" and info["computed"] == ["gain", "save"], info
        kinds = [(ev["type"], ev.get("name") or ev.get("node"), ev.get("state")) for _, ev in events]
        i_push = kinds.index(("preview", "gain", None))
        i_done = kinds.index(("node", "gain", "done"))
        i_save = kinds.index(("node", "save", "running"))
        assert i_push < i_done < i_save, kinds
        # the preview on show is computed first: side (before gain in the graph's usual
        # order) is looked up only after gain's push
        assert i_push < kinds.index(("node", "side", "running")), kinds
        push, done = events[i_push][1], events[i_done][1]
        assert push["digest"] == done["digests"]["image"] and push["level"] == 0
        # the loopback page's push: raw RGBA for its canvas
        assert push["format"] == "rgba" and len(push["data"]) == push["width"] * push["height"] * 4
        px = np.frombuffer(push["data"], np.uint8).reshape(push["height"], push["width"], 4)
        assert (px[..., :3] == srgb8(0.5)).all() and (px[..., 3] == 255).all()  # 0.25 × 2¹
        assert shown_at and events[i_save][0] >= shown_at[0], "the writer ran before the page showed the preview"
        # the page's request for the same preview: a PNG of the same pixels
        got = np.asarray(PILImage.open(io.BytesIO(st.preview("gain", "image", 0.0, 0, 0))).convert("RGB"))
        assert (got == px[..., :3]).all()
    finally:
        st.close()


SWEEP_GRAPH = """\
graphkit: 1
name: studio_sweep
sweeps:
  lv:
    values: [{level: 0.25}, {level: 0.5}]
    name: "lv{index}"
nodes:
  flat:
    type: Flat
    foreach: lv
    params: {level: "${lv.level}", size: 8}
  gain:
    type: Gain
    foreach: lv
    inputs: {image: flat.image}
    params: {stops: 0.0}   # one gain for every instance
outputs: {}
"""


def test_a_sweep_node_is_edited_from_its_panel(browser, server):
    """A sweep is drawn as one node; its panel edits the graph file's node (every instance),
    and a param bound to the sweep's values is shown as bound, not as a control that would
    overwrite the reference."""
    ctx, errors = browser
    s, _ = server(SWEEP_GRAPH)
    page = open_page(ctx, s)
    wait_run(page)
    assert sorted(drawn_nodes(page)) == ["flat", "gain"]
    click_node(page, "flat")
    page.wait_for_selector("#node-panel h3")
    assert "instance flat[lv0]" in page.text_content("#node-panel h3")
    bound = page.inner_text('#node-panel .ctl[data-param="level"] .bound')
    assert "${lv.level}" in bound, bound
    assert not page.query_selector('#node-panel .ctl[data-param="level"] input')
    click_node(page, "gain")
    page.wait_for_selector('#node-panel .ctl[data-param="stops"] input[type=range]')
    gen = run_status(page)[1]
    page.fill('#node-panel .ctl[data-param="stops"] input[type=range]', "1")
    wait_run(page, after_gen=gen)
    assert page.inner_text('#node-panel .ctl[data-param="stops"] .err').strip() == ""
    got = page.evaluate("studio.state.nodes.filter(n => n.base === 'gain').map(n => [n.params.stops, n.raw_params])")
    assert got == [[1.0, {"stops": 1.0}]] * 2, got  # the sweep node's param, so both instances
    assert not errors
