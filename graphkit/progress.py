"""Progress display for `graphkit run`: a live rich table on a terminal, plain lines otherwise."""
from __future__ import annotations

import sys
import threading
import time

from .executor import Progress
from .runner import NodeOutcome


class PlainProgress(Progress):
    """One line per finished node on stderr (CI logs, pipes)."""

    def __init__(self, stream=None, quiet: bool = False):
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self._lock = threading.Lock()
        self.n = self.total = 0

    def _say(self, line: str) -> None:
        with self._lock:
            print(line, file=self.stream, flush=True)

    def start(self, total):
        self.total = total

    def done(self, o: NodeOutcome):
        self.n += 1
        if not self.quiet:
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

    def __init__(self):
        from rich.console import Console
        from rich.live import Live

        self.console = Console(stderr=True)
        self.rows: dict[str, list] = {}
        self.total = 0
        self.max_rows = 24
        self._lock = threading.Lock()
        self.live = Live(self._table(), console=self.console, refresh_per_second=8, transient=False)

    def _table(self):
        from rich.table import Table

        t = Table(box=None, show_header=True, header_style="bold")
        t.add_column("node")
        t.add_column("type", style="dim")
        t.add_column("state")
        t.add_column("s", justify="right")
        style = {"cached": "cyan", "running": "yellow", "done": "green"}
        now = time.perf_counter()
        rows = list(self.rows.items())
        if len(rows) > self.max_rows:  # big graphs: what runs now, the latest finished, a count
            running = [r for r in rows if r[1][1] == "running"]
            finished = [r for r in rows if r[1][1] != "running"]
            counts = {st: sum(1 for r in finished if r[1][1] == st) for st in ("done", "cached")}
            t.caption = f"{counts['done']} done, {counts['cached']} cached, {len(running)} running of {self.total}"
            rows = finished[-(self.max_rows - min(len(running), self.max_rows // 2)):] + running[: self.max_rows // 2]
        for name, (typ, state, t0, secs, note) in rows:
            s = secs if secs is not None else now - t0
            t.add_row(name, typ, f"[{style.get(state, '')}]{state}[/] {note}", f"{s:.2f}")
        return t

    def start(self, total):
        self.total = total
        self.live.start()

    def running(self, node, node_type):
        with self._lock:
            self.rows[node] = [node_type, "running", time.perf_counter(), None, ""]
            self.live.update(self._table())

    def done(self, o):
        with self._lock:
            self.rows[o.name] = [o.type, "cached" if o.hit else "done", 0, o.seconds,
                                 "" if o.backend == "numpy" else f"({o.backend})"]
            self.live.update(self._table())

    def report(self, node, fraction, message):
        with self._lock:
            if node in self.rows:
                self.rows[node][4] = f"{fraction:.0%} {message}"
                self.live.update(self._table())

    def notice(self, message):
        self.console.print(message)

    def finish(self, ok):
        self.live.update(self._table())
        self.live.stop()


def make_progress(quiet: bool = False) -> Progress:
    if not quiet and sys.stderr.isatty():
        return RichProgress()
    return PlainProgress(quiet=quiet)
