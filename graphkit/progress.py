"""Progress display for `graphkit run`: a live rich table on a terminal, plain lines otherwise.

By default only the nodes that compute are listed (a fully cached run prints nothing here, and
the CLI's one summary line); ``verbose`` also lists the cache hits."""
from __future__ import annotations

import sys
import threading
import time

from .executor import Progress
from .runner import NodeOutcome


class PlainProgress(Progress):
    """One line per finished node on stderr (CI logs, pipes)."""

    def __init__(self, stream=None, quiet: bool = False, verbose: bool = False):
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.verbose = verbose
        self._lock = threading.Lock()
        self.n = self.total = 0

    def _say(self, line: str) -> None:
        with self._lock:
            print(line, file=self.stream, flush=True)

    def start(self, total):
        self.total = total

    def done(self, o: NodeOutcome):
        self.n += 1
        if not self.quiet and (self.verbose or not o.hit):
            state = "cached" if o.hit else "done"
            self._say(f"[{self.n:>{len(str(self.total))}}/{self.total}] {state:<6} {o.name} ({o.type}"
                      f"{'' if o.backend == 'numpy' else ', ' + o.backend}) {o.seconds:.2f}s")

    def report(self, node, fraction, message):
        if not self.quiet:
            self._say(f"        {node}: {fraction:4.0%} {message}")

    def notice(self, message):
        self._say(message)


class RichProgress(Progress):
    """A live table: each node cached / running / done with seconds."""

    #: a node that is still running after this long is shown (cache hits take far less)
    SHOW_AFTER_S = 0.15

    def __init__(self, verbose: bool = False):
        from rich.console import Console
        from rich.live import Live

        self.console = Console(stderr=True)
        self.verbose = verbose
        self.rows: dict[str, list] = {}
        self.total = 0
        self.max_rows = 24
        self._lock = threading.Lock()
        self.live = Live(self, console=self.console, refresh_per_second=8, transient=False)

    def __rich__(self):  # Live re-renders this on every refresh
        with self._lock:
            return self._table()

    def _visible(self, now: float) -> list:
        out = []
        for name, row in self.rows.items():
            state = row[1]
            if state == "cached" and not self.verbose:
                continue
            if state == "running" and now - row[2] < self.SHOW_AFTER_S:
                continue
            out.append((name, row))
        return out

    def _table(self):
        from rich.table import Table
        from rich.text import Text

        now = time.perf_counter()
        rows = self._visible(now)
        if not rows:
            return Text("")

        t = Table(box=None, show_header=True, header_style="bold")
        t.add_column("node")
        t.add_column("type", style="dim")
        t.add_column("state")
        t.add_column("s", justify="right")
        style = {"cached": "cyan", "running": "yellow", "done": "green"}
        if len(rows) > self.max_rows:  # big graphs: what runs now, the latest finished, a count
            running = [r for r in rows if r[1][1] == "running"]
            finished = [r for r in rows if r[1][1] != "running"]
            counts = {st: sum(1 for r in self.rows.values() if r[1] == st) for st in ("done", "cached")}
            t.caption = f"{counts['done']} done, {counts['cached']} cached, {len(running)} running of {self.total}"
            rows = finished[-(self.max_rows - min(len(running), self.max_rows // 2)):] + running[: self.max_rows // 2]
        for name, (typ, state, t0, secs, note) in rows:
            s = secs if secs is not None else now - t0
            t.add_row(name, typ, f"[{style.get(state, '')}]{state}[/] {note}", f"{s:.2f}")
        return t

    def start(self, total):
        self.total = total
        self._stop = threading.Event()
        self._started = False
        self._poller = threading.Thread(target=self._start_when_needed, daemon=True)
        self._poller.start()

    def _start_when_needed(self):
        """Start the live table once it has a row to show (a fully cached run shows none)."""
        while not self._stop.wait(0.05):
            with self._lock:
                if self._visible(time.perf_counter()):
                    self.live.start()
                    self._started = True
                    return

    def running(self, node, node_type):
        with self._lock:
            self.rows[node] = [node_type, "running", time.perf_counter(), None, ""]

    def done(self, o):
        with self._lock:
            self.rows[o.name] = [o.type, "cached" if o.hit else "done", 0, o.seconds,
                                 "" if o.backend == "numpy" else f"({o.backend})"]

    def report(self, node, fraction, message):
        with self._lock:
            if node in self.rows:
                self.rows[node][4] = f"{fraction:.0%} {message}"

    def notice(self, message):
        self.console.print(message, markup=False, highlight=False)

    def finish(self, ok):
        stop = getattr(self, "_stop", None)
        if stop is None:
            return
        stop.set()
        self._poller.join()
        if not self._started and self._visible(time.perf_counter() + self.SHOW_AFTER_S):
            self.live.start()
            self._started = True
        if self._started:
            self.live.refresh()
            self.live.stop()


def make_progress(quiet: bool = False, verbose: bool = False) -> Progress:
    if not quiet and sys.stderr.isatty():
        return RichProgress(verbose)
    return PlainProgress(quiet=quiet, verbose=verbose)
