"""graphkit.memory.tune_malloc: glibc keeps a frame's large temporaries for the next frame.

The setting is read back by its effect in the process of a graph run (`graphkit run` through
graphkit.cli.main): three 12 MiB numpy temporaries allocated and freed again and again fault their
pages in every time under glibc's defaults (the freed heap top is trimmed), and hardly at all once
the thresholds are set.
"""

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from graphkit import memory
from graphkit.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
GLIBC = platform.libc_ver()[0] == "glibc"

PROBE = """
import resource, sys
import numpy as np
from graphkit.cli import main

assert main(["run", "-q", sys.argv[1], "--cache", sys.argv[2], "--out", sys.argv[3]]) == 0
a = np.ones((720, 1280, 3), np.float32)
for i in range(11):
    if i == 1:
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    b = a * 2; c = b + a; d = c * a
    del b, c, d
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) // 10)
"""


def _faults_per_frame(tmp_path, disable: bool) -> int:
    env = {k: v for k, v in os.environ.items() if k != "GRAPHKIT_MALLOC_TUNING_DISABLE"}
    if disable:
        env["GRAPHKIT_MALLOC_TUNING_DISABLE"] = "1"
    tag = "off" if disable else "on"
    r = subprocess.run([sys.executable, "-c", PROBE, str(ROOT / "graphs" / "quickstart.yaml"),
                        str(tmp_path / f"cache_{tag}"), str(tmp_path / f"out_{tag}")],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    return int(r.stdout.split()[-1])


@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's; elsewhere tune_malloc is a no-op (tested below)")
def test_a_graph_runs_process_reuses_freed_pages(tmp_path):
    tuned, default = _faults_per_frame(tmp_path, False), _faults_per_frame(tmp_path, True)
    # 3 × 10.5 MiB of temporaries is ~2,700 pages of 4 KiB: the default faults most of them in
    assert default > 500, default
    assert tuned < default / 5, (tuned, default)


@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's")
def test_returns_what_it_set(monkeypatch):
    monkeypatch.delenv("GRAPHKIT_MALLOC_TUNING_DISABLE", raising=False)
    assert memory.tune_malloc() == {"M_MMAP_THRESHOLD": memory.MMAP_THRESHOLD,
                                    "M_TRIM_THRESHOLD": memory.TRIM_THRESHOLD}


def test_the_environment_variable_turns_it_off(monkeypatch):
    monkeypatch.setenv("GRAPHKIT_MALLOC_TUNING_DISABLE", "1")
    assert memory.tune_malloc() == {}


def test_a_no_op_without_glibc(monkeypatch):
    monkeypatch.delenv("GRAPHKIT_MALLOC_TUNING_DISABLE", raising=False)
    monkeypatch.setattr(memory.platform, "libc_ver", lambda: ("", ""))
    assert memory.tune_malloc() == {}


def test_every_entry_point_calls_it(monkeypatch):
    """The CLI (run, serve, …), the studio started from Python and each Dask worker's session."""
    from graphkit import cli, dask_executor
    from graphkit.studio import app

    calls = []
    monkeypatch.setattr(cli, "tune_malloc", lambda: calls.append("cli"))
    monkeypatch.setattr(memory, "tune_malloc", lambda: calls.append("memory"))
    assert cli.main(["nodes"]) == 0
    with pytest.raises(UsageError):  # stops at the socket, after the call: an address that cannot be bound
        app.serve(str(ROOT / "graphs" / "quickstart.yaml"), host="256.0.0.1")
    with pytest.raises(AttributeError):  # stops at the graph (None here), after the call
        dask_executor._worker_session(object(), None, None, None)
    assert calls == ["cli", "memory", "memory"]
