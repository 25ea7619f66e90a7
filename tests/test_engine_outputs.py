"""--out is published as one unit with its manifest (issue 10): kill -9 at any moment leaves
a manifest that describes the files beside it, the next run cleans what a killed one left,
symlinked folders inside --out are refused, no output can take the manifest's name, and the
files and folders are fsynced.  Each test fails on the exporter before issue 10."""
import json
import os
import random
import signal
import time

import numpy as np
import pytest

from conftest import engine_env, graphkit

ENV = engine_env({"GRAPHKIT_PLUGINS": "enginenodes,storenodes"})
N = 250_000  # 2 MB per output file
K = 6

GRAPH = "graphkit: 1\nname: pub\nparams: {seed: 0}\nnodes:\n" \
        f"  base: {{type: Const, params: {{value: \"${{params.seed}}\", size: {N}}}}}\n" \
        + "".join(f"  o{k}: {{type: Add, inputs: {{a: base.out}}, params: {{offset: {k}}}}}\n" for k in range(K)) \
        + "outputs: {" + ", ".join(f"o{k}: o{k}.out" for k in range(K)) + "}\n"


def consistent(out, ever_published):
    """--out matches its manifest: every output holds the values of the run it names."""
    m = out / "manifest.json"
    if not m.exists():
        # only before the first publish, or while a complete stage waits to be finished
        entries = [p.name for p in out.iterdir()] if out.exists() else []
        assert not ever_published or any(e.startswith(".graphkit-publish-") for e in entries), entries
        return False
    seed = json.loads(m.read_text())["params"]["seed"]
    for k in range(K):
        f = out / f"o{k}.npy"
        assert f.exists(), f"manifest of seed {seed} but {f.name} is missing"
        a = np.load(f)
        assert a.shape == (N,) and a[0] == a[-1] == seed + k, f"manifest of seed {seed}, {f.name} holds {a[0]}"
    return True


def _run_in_child(g, cache, out, seed, reg):
    from graphkit import run_graph

    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 3
        try:
            run_graph(g, cache=cache, out=out, overrides={"seed": seed}, registry=reg, jobs=1)
            code = 0
        finally:
            os._exit(code)
    return pid


def test_kill_9_during_export_keeps_out_consistent(tmp_path, write, engine_registry):
    g, cache, out = write("g.yaml", GRAPH), tmp_path / "c", tmp_path / "o"
    t0 = time.perf_counter()
    pid = _run_in_child(g, cache, out, 1000, engine_registry)
    assert os.waitpid(pid, 0)[1] == 0
    full = time.perf_counter() - t0
    assert consistent(out, True)
    rng = random.Random(10)
    killed = attempts = 0
    # kill at a random moment of a run; a run that finished first (a loaded machine is slower
    # or faster from one run to the next) shortens the window, so 25 kills land mid-way
    while killed < 25:
        attempts += 1
        assert attempts <= 120, f"only {killed} of {attempts - 1} runs were killed mid-way"
        pid = _run_in_child(g, cache, out, attempts, engine_registry)
        time.sleep(rng.uniform(0.0, full))
        os.kill(pid, signal.SIGKILL)
        status = os.waitpid(pid, 0)[1]
        if os.WIFSIGNALED(status):
            killed += 1
        else:
            full *= 0.8
        consistent(out, True)
    pid = _run_in_child(g, cache, out, 77, engine_registry)  # the next run cleans up
    assert os.waitpid(pid, 0)[1] == 0
    assert consistent(out, True) and json.loads((out / "manifest.json").read_text())["params"]["seed"] == 77
    left = [str(p.relative_to(out)) for p in out.rglob("*")
            if p.name.startswith(".graphkit-") or p.name.endswith(".tmp")]
    assert left == []
    assert sorted(p.name for p in out.iterdir()) == sorted([f"o{k}.npy" for k in range(K)] + ["manifest.json", "report.html"])


def test_next_run_removes_stale_temps_and_stages(tmp_path, write):
    g, cache, out = write("g.yaml", "graphkit: 1\nnodes:\n  a: {type: Const}\noutputs: {a: a.out}\n"), tmp_path / "c", tmp_path / "o"
    out.mkdir()
    (out / ".a.npy.1f2e3d4c.tmp").write_bytes(b"partial")  # what a killed run of main left
    (out / ".graphkit-stage-deadbeef").mkdir()
    (out / ".graphkit-stage-deadbeef" / "a.npy").write_bytes(b"partial")
    (out / "mine.txt").write_text("a user's file")
    r = graphkit("run", g, "--cache", cache, "--out", out, env=ENV)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["a.npy", "manifest.json", "mine.txt", "report.html"]


def test_a_finished_stage_is_published_by_the_next_run(tmp_path, write):
    """A run killed after its stage was complete: the next run finishes publishing it first,
    and files of the previous run that the new manifest does not list are removed."""
    g, cache, out = write("g.yaml", "graphkit: 1\nnodes:\n  a: {type: Const}\noutputs: {a: a.out}\n"), tmp_path / "c", tmp_path / "o"
    out.mkdir()
    (out / "manifest.json").write_text(json.dumps({"files": {"old.npy": {}}}))
    (out / "old.npy").write_bytes(b"old")
    st = out / ".graphkit-publish-0123"
    st.mkdir()
    (st / "b.npy").write_bytes(b"new")
    (st / "manifest.json").write_text(json.dumps({"files": {"b.npy": {}}}))
    from graphkit.publish import recover

    fd = os.open(out, os.O_RDONLY)
    try:
        recover(fd)
    finally:
        os.close(fd)
    assert sorted(p.name for p in out.iterdir()) == ["b.npy", "manifest.json"]
    assert json.loads((out / "manifest.json").read_text()) == {"files": {"b.npy": {}}}
    r = graphkit("run", g, "--cache", cache, "--out", out, env=ENV)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["a.npy", "manifest.json", "report.html"]


def test_symlinked_folder_inside_out_is_refused(tmp_path, write):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  w: {type: WriteFile, params: {name: sub/x.txt, text: hi}}\n"
                        "outputs: {x: w.file}\n")
    out, elsewhere = tmp_path / "o", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "sub").symlink_to(elsewhere, target_is_directory=True)
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", out, env=ENV)
    assert r.returncode == 2 and "symlink" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert list(elsewhere.iterdir()) == []
    assert not (out / "manifest.json").exists()


def test_no_output_can_take_the_manifest_name(tmp_path, write):
    before = '{"mine": true}'
    for i, graph in enumerate([
        # a Scalar output called manifest would be manifest.json: refused before anything runs
        "graphkit: 1\nnodes:\n  a: {type: Const}\n  s: {type: Sum, inputs: {xs: [a.out]}}\noutputs: {manifest: s.count}\n",
        # a File output named manifest.json: refused when its name is known, nothing written
        "graphkit: 1\nnodes:\n  w: {type: WriteFile, params: {name: manifest.json, text: x}}\noutputs: {m: w.file}\n",
    ]):
        out = tmp_path / f"o{i}"
        out.mkdir()
        (out / "manifest.json").write_text(before)
        r = graphkit("run", write(f"g{i}.yaml", graph), "--cache", tmp_path / "c", "--out", out, env=ENV)
        assert r.returncode == 2 and "manifest" in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert (out / "manifest.json").read_text() == before


def test_outputs_and_folders_are_fsynced(tmp_path, write, engine_registry, monkeypatch):
    import storenodes

    from graphkit import run_graph

    engine_registry.add_provider("nodes", "tests-store", storenodes)
    g = write("g.yaml", "graphkit: 1\nnodes:\n  w: {type: WriteFile, params: {name: sub/x.txt, text: hi}}\n"
                        "  a: {type: Const}\noutputs: {x: w.file, a: a.out}\n")
    real, synced = os.fsync, []

    def spy(fd):
        with __import__("contextlib").suppress(OSError):
            synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        return real(fd)

    monkeypatch.setattr(os, "fsync", spy)
    out = tmp_path / "o"
    run_graph(g, cache=tmp_path / "c", out=out, registry=engine_registry)
    if not os.path.exists("/proc/self/fd"):
        pytest.skip(reason="needs /proc/self/fd to see which files were fsynced")
    names = {os.path.basename(p) for p in synced}
    assert {"x.txt", "a.npy", "manifest.json"} <= names, synced  # the files (in the stage)
    assert str(out) in synced and str(out / "sub") in synced, synced  # and the folders they land in


def test_a_warm_run_leaves_files_already_in_place(tmp_path, write, engine_registry):
    """Issue 25: a file that already holds the bytes the manifest records is not written again
    (same inode), but one edited since (same size and mtime put back), one with a second hard
    link and a symlink in its place are all replaced; the manifest is always published anew."""
    from graphkit import run_graph

    g = write("g.yaml", GRAPH.replace(f"size: {N}", "size: 64"))
    cache, out, other = tmp_path / "c", tmp_path / "o", tmp_path / "other.npy"

    def run(seed=0):
        run_graph(g, cache=cache, out=out, overrides={"seed": seed}, registry=engine_registry)
        assert consistent_small(out, seed)
        return {p.name: p.lstat().st_ino for p in out.iterdir()}

    first = run()
    second = run()
    assert {k: second[k] for k in second if k.endswith(".npy")} == {k: first[k] for k in first if k.endswith(".npy")}
    assert second["manifest.json"] != first["manifest.json"]
    edited = out / "o0.npy"
    st = edited.stat()
    data = bytearray(edited.read_bytes())
    data[-1] ^= 0xFF
    edited.write_bytes(bytes(data))
    os.utime(edited, ns=(st.st_atime_ns, st.st_mtime_ns))
    os.link(out / "o1.npy", tmp_path / "second-link.npy")
    other.write_bytes((out / "o2.npy").read_bytes())
    (out / "o2.npy").unlink()
    (out / "o2.npy").symlink_to(other)
    third = run()
    assert {k for k in third if third[k] != second.get(k)} == {"o0.npy", "o1.npy", "o2.npy", "manifest.json", "report.html"}
    assert not (out / "o2.npy").is_symlink() and other.read_bytes() == (out / "o2.npy").read_bytes()
    fourth = run(seed=7)  # other bytes: every output is written again
    assert all(fourth[k] != third[k] for k in fourth)


def consistent_small(out, seed):
    m = json.loads((out / "manifest.json").read_text())
    assert m["params"]["seed"] == seed
    for k in range(K):
        a = np.load(out / f"o{k}.npy")
        assert a.shape == (64,) and a[0] == a[-1] == seed + k
    return True


def test_kill_9_while_some_files_stay_in_place(tmp_path, write, engine_registry):
    """Issue 25: runs that leave half of --out in place (those outputs do not depend on the
    seed) and are killed at random moments still leave a manifest that describes every file."""
    half = "graphkit: 1\nname: pub\nparams: {seed: 0}\nnodes:\n" \
        f"  base: {{type: Const, params: {{value: \"${{params.seed}}\", size: {N}}}}}\n" \
        f"  zero: {{type: Const, params: {{value: 0, size: {N}}}}}\n" \
        + "".join(f"  o{k}: {{type: Add, inputs: {{a: {'base' if k % 2 else 'zero'}.out}}, params: {{offset: {k}}}}}\n"
                  for k in range(K)) \
        + "outputs: {" + ", ".join(f"o{k}: o{k}.out" for k in range(K)) + "}\n"
    g, cache, out = write("g.yaml", half), tmp_path / "c", tmp_path / "o"

    def check():
        if not (out / "manifest.json").exists():  # only while a complete stage waits to be finished
            assert any(p.name.startswith(".graphkit-publish-") for p in out.iterdir())
            return
        m = json.loads((out / "manifest.json").read_text())
        for k in range(K):
            a = np.load(out / f"o{k}.npy")
            want = (m["params"]["seed"] if k % 2 else 0) + k
            assert a[0] == a[-1] == want, f"manifest of seed {m['params']['seed']}, o{k}.npy holds {a[0]}"

    t0 = time.perf_counter()
    assert os.waitpid(_run_in_child(g, cache, out, 1, engine_registry), 0)[1] == 0
    full = time.perf_counter() - t0
    rng = random.Random(25)
    killed = 0
    for attempt in range(2, 60):
        pid = _run_in_child(g, cache, out, attempt, engine_registry)
        time.sleep(rng.uniform(0.0, full))
        os.kill(pid, signal.SIGKILL)
        killed += os.WIFSIGNALED(os.waitpid(pid, 0)[1])
        check()
        if killed == 10:
            break
    assert killed == 10
    assert os.waitpid(_run_in_child(g, cache, out, 99, engine_registry), 0)[1] == 0
    check()


def test_npy_bytes_are_what_np_save_writes():
    """Outputs are exported with np.save's header made once per (dtype, shape): the same bytes
    as np.save for every kind of array, also the second time a (dtype, shape) is seen."""
    import io

    from graphkit.publish import npy_bytes

    cases = [np.zeros((16, 16)), np.arange(12, dtype=np.uint8).reshape(3, 4), np.zeros((4, 5, 3), np.float32),
             np.asfortranarray(np.ones((3, 4))), np.ones((3, 4))[:, ::2], np.zeros(0), np.array(3.5),
             np.zeros((2, 2), dtype=[("a", "<f4"), ("b", "<i2")]), np.array(["ab", "c"]), np.zeros((2, 3), ">f8"),
             np.zeros((1, 5)), np.zeros((5, 1)), np.array([1 + 2j]), np.zeros((2, 2), bool), np.arange(6.0).reshape(2, 3)]
    for a in cases:
        want = io.BytesIO()
        np.save(want, a, allow_pickle=False)
        assert npy_bytes(a) == want.getvalue() == npy_bytes(a), a
