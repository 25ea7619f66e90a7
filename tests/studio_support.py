"""Shared helpers of the studio tests: a real `graphkit serve` process and headless Chromium.

Chromium is Debian's (``/usr/bin/chromium``, installed by ``make sysdeps``), driven by
playwright with ``executable_path`` (no browser download).
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import engine_env

CHROMIUM = os.environ.get("GRAPHKIT_TEST_CHROMIUM", "/usr/bin/chromium")
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--no-first-run", "--disable-quic"]
WEBGL_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def need_browser():
    try:
        import playwright  # noqa: F401
    except ImportError:
        pytest.skip(reason="playwright is not installed (make test installs the test extra)")
    if not (os.path.exists(CHROMIUM) or shutil.which(CHROMIUM)):
        pytest.skip(reason=f"{CHROMIUM} not found (make sysdeps installs Debian's chromium)")


class Server:
    """`graphkit serve` in a subprocess; ``url`` holds the token."""

    def __init__(self, graph, tmp: Path, *extra, env=None, plugins="studionodes", cache=None):
        self.cache, self.out = Path(cache) if cache else tmp / "cache", tmp / "out"
        e = engine_env({"GRAPHKIT_PLUGINS": plugins} if plugins else None)
        if env:
            e.update(env)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "graphkit", "serve", str(graph), "--cache", str(self.cache),
             "--out", str(self.out), *map(str, extra)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=e)
        line = self.proc.stdout.readline()
        m = re.search(r"(http://127\.0\.0\.1:(\d+)/)\?token=(\S+)", line)
        if not m:
            self.proc.kill()
            raise AssertionError(f"no URL printed: {line!r} {self.proc.stderr.read()}")
        self.base, self.port, self.token = m.group(1), int(m.group(2)), m.group(3)
        self.url = f"{self.base}?token={self.token}"

    def api(self, path, body=None, token=True):
        import json
        import urllib.request

        req = urllib.request.Request(self.base.rstrip("/") + path, method="POST" if body is not None else "GET",
                                     data=None if body is None else json.dumps(body).encode(),
                                     headers={"x-graphkit-token": self.token} if token else {})
        with urllib.request.urlopen(req, timeout=30) as r:
            return json.loads(r.read())

    def stop(self, sig=signal.SIGINT, timeout=20):
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise AssertionError(f"graphkit serve did not stop within {timeout}s of {sig!r}")
        self.stderr = self.proc.stderr.read()
        return self.proc.returncode


def browser_page(pw, webgl=False, viewport=(1400, 850)):
    b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS + (WEBGL_ARGS if webgl else []))
    ctx = b.new_context(viewport={"width": viewport[0], "height": viewport[1]})
    return b, ctx


def wait_for(fn, timeout=30.0, what="condition"):
    end = time.time() + timeout
    last = None
    while time.time() < end:
        last = fn()
        if last:
            return last
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what} (last: {last!r})")


def run_status(page):
    return page.eval_on_selector("#run-status", "e => [e.dataset.status, +e.dataset.gen]")


def wait_run(page, status="ok", after_gen=0, timeout=60):
    return wait_for(lambda: (lambda s: s[0] == status and s[1] > after_gen and s)(run_status(page)),
                    timeout, f"run status {status}")


def node_state(page, name):
    """The state the graph pane shows on node ``name`` (idle, running, done, cached, failed, …)."""
    return page.evaluate("n => studio.editor.nodes[n]?.gkState", name)


def wait_graph(page, timeout=30000):
    """Until the graph pane has drawn and laid out the graph's nodes."""
    page.wait_for_function("() => +document.getElementById('graph').dataset.laidOut > 0", timeout=timeout)


def open_view(ctx, s, node, errors: list):
    """A new page on studio ``s`` (its console errors into ``errors``), once its run is done,
    with ``node`` clicked so that its live view mounts."""
    page = ctx.new_page()
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.goto(s.url)
    wait_graph(page)
    wait_for(lambda: page.eval_on_selector("#run-status", "e => e.dataset.status") == "ok", 120, "the run")
    click_node(page, node)
    return page


def drawn_nodes(page):
    return page.evaluate("Object.keys(studio.editor.nodes)")


def click_node(page, name):
    """A real mouse click on node ``name``'s title bar in the graph canvas, until the editor
    has it selected.  The canvas selects on the button's release, which ``mouse.click`` waits
    for, so the selection is checked at once, with no time limit (a busy machine makes any
    limit a guess); a click the canvas took for the second half of a double-click selects
    nothing: it is clicked again once litegraph's double-click time (300 ms) has passed."""
    want = name.split("[")[0]
    for _ in range(3):
        x, y = page.evaluate("n => studio.editor.nodePoint(n)", want)
        page.mouse.click(x, y)
        if page.evaluate("n => studio.editor.selected === n", want):
            return
        page.wait_for_timeout(350)
    raise AssertionError(f"a click on node {name!r} does not select it")


def drag_link(page, src, out_port, dst, in_port):
    """Drag with the mouse from output socket ``src.out_port`` to input socket ``dst.in_port``."""
    x0, y0 = page.evaluate("a => studio.editor.slotPoint(a[0], a[1], false)", [src, out_port])
    x1, y1 = page.evaluate("a => studio.editor.slotPoint(a[0], a[1], true)", [dst, in_port])
    page.mouse.move(x0, y0)
    page.mouse.down()
    page.mouse.move((x0 + x1) / 2, (y0 + y1) / 2, steps=4)
    page.mouse.move(x1, y1, steps=4)
    page.mouse.up()
