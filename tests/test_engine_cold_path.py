"""The cold path's cuts keep their promises (issue 10, cold overhead).

- A run whose key lock was free takes it with one system call and does not look the key up a
  second time; a run that had to wait for the lock (another run was computing that key) looks
  again and uses that run's result: two runs sharing a cache compute a key once.
- Objects a run has stored or read back are not looked for again while it holds the run lock,
  and only then: after the run, an object removed from the cache is written again by the next
  run that makes it; a quarantined object is forgotten at once.
- Temp names carry the pid of the process that writes them, also in a forked child.
"""
from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from graphkit.executor import run_local
from graphkit.graphfile import load_graph
from graphkit.runner import Session
from graphkit.store import Store, value_parts
from graphkit.types import ARRAY

SLOW = """\
graphkit: 1
name: slow
nodes:
  s: {type: Slow, params: {seconds: 0.4, megabytes: 0.001}}
outputs: {s: s.out}
"""

PASS = """\
graphkit: 1
name: pass
nodes:
  c: {type: Const, params: {value: 3.0}}
  n1: {type: Noop, inputs: {x: c.out}, params: {i: 1}}
  n2: {type: Noop, inputs: {x: n1.out}, params: {i: 2}}
outputs: {n2: n2.out}
"""


def test_a_run_that_waited_for_the_key_lock_uses_the_other_runs_result(write, engine_registry, tmp_path, monkeypatch):
    """Two runs (two Store objects: two open file descriptions, as two processes have) start the
    same slow node together: the second waits for the key lock, looks again, and hits."""
    import enginenodes

    calls = []
    real = enginenodes.Slow.compute
    monkeypatch.setattr(enginenodes.Slow, "compute", lambda self, x=None: (calls.append(1), real(self, x))[1])
    g = load_graph(write("slow.yaml", SLOW), engine_registry)
    results, errors = [], []

    def run():
        try:
            results.append(run_local(Session(g, engine_registry, Store(tmp_path / "c").open()), ["s"]))
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=run) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors, errors
    assert len(calls) == 1, f"the slow node was computed {len(calls)} times by two runs sharing a cache"
    (a,), (b,) = [[o for o in r.outcomes.values()] for r in results]
    assert sorted([a.hit, b.hit]) == [False, True] and a.outputs == b.outputs


def test_a_free_key_lock_says_it_did_not_wait_and_a_held_one_that_it_did(tmp_path):
    s1, s2 = Store(tmp_path / "c").open(), Store(tmp_path / "c").open()
    key = "ab" * 16
    with s1.key_lock(key) as waited:
        assert waited is False
        got = []
        t = threading.Thread(target=lambda: got.append(s2.key_lock(key).__enter__()))
        t.start()
        t.join(0.3)
        assert t.is_alive() and not got  # held by s1: s2 waits
    t.join(5)
    assert got == [True]
    s2.fs._ofd_lock(int(key[:15], 16)).__exit__(None, None, None)


def test_objects_known_present_only_while_the_run_lock_is_held(write, engine_registry, tmp_path):
    g = load_graph(write("pass.yaml", PASS), engine_registry)
    store = Store(tmp_path / "c").open()
    res = run_local(Session(g, engine_registry, store), ["n2"])
    digest = res.outcomes["n2"].outputs["out"]
    obj = tmp_path / "c" / "objects" / digest[:2] / digest
    assert obj.is_file() and not store._present  # forgotten when the run ended
    obj.unlink()  # e.g. removed by `cache gc` between two runs
    (tmp_path / "c" / "keys").rename(tmp_path / "c" / "keys-old")  # the next run computes again
    run_local(Session(g, engine_registry, store), ["n2"])
    assert obj.is_file(), "the next run that made the value did not store it again"

    value = np.full(4, 7.0)
    vp = value_parts(ARRAY, value)
    with store.run_lock():
        d = store.put_value(ARRAY, value, vp)
        assert d in store._present
        store.quarantine(f"objects/{d[:2]}/{d}", "test: damaged")
        assert d not in store._present  # a quarantined object is written again when next made
        store.put_value(ARRAY, value, vp)
        assert (tmp_path / "c" / "objects" / d[:2] / d).is_file()


@pytest.mark.skipif(not hasattr(os, "fork"), reason="os.fork is POSIX only")
def test_temp_names_carry_the_writing_process_pid_after_a_fork(tmp_path):
    from graphkit.store import localfs as store_mod

    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: report the pid its temp names would carry
        os.write(w, str(store_mod._PID[0] == os.getpid()).encode())
        os._exit(0)
    os.close(w)
    said = os.read(r, 16)
    os.waitpid(pid, 0)
    assert said == b"True" and store_mod._PID[0] == os.getpid()
