"""Cross-process single-flight on fsspec stores: concurrent runs on a file:// cache compute each
key once; the lease lock used for object stores excludes other processes and breaks stale leases."""
import json
import multiprocessing as mp
import subprocess
import sys
import time

from conftest import engine_env


def _bump(args):
    """Read-modify-write a counter under a Lease, slowly enough that races would lose updates."""
    path, counter, n = args
    import fsspec

    from graphkit.leases import Lease

    fs = fsspec.filesystem("file")
    for _ in range(n):
        with Lease(fs, path, ttl=30):
            v = int(open(counter).read())
            time.sleep(0.002)
            open(counter, "w").write(str(v + 1))
    return n


def test_lease_excludes_other_processes(tmp_path):
    counter = tmp_path / "counter"
    counter.write_text("0")
    with mp.get_context("spawn").Pool(3) as pool:
        done = pool.map(_bump, [(str(tmp_path / "locks" / "k.lock"), str(counter), 15)] * 3)
    assert sum(done) == 45
    assert int(counter.read_text()) == 45  # no update lost
    assert not (tmp_path / "locks" / "k.lock").exists()  # released


def test_stale_lease_is_broken(tmp_path):
    import fsspec

    from graphkit.leases import Lease

    fs = fsspec.filesystem("file")
    lock = tmp_path / "k.lock"
    lock.write_text(json.dumps({"token": "dead", "host": "gone", "pid": 1, "expires": time.time() - 5}))
    t = time.monotonic()
    with Lease(fs, str(lock), ttl=30) as lease:
        assert json.loads(lock.read_text())["token"] == lease.token
    assert time.monotonic() - t < 10  # broken at once, not after a ttl
    lock.write_text(json.dumps({"token": "alive", "host": "h", "pid": 1, "expires": time.time() + 1.0}))
    t = time.monotonic()
    with Lease(fs, str(lock), ttl=5):
        pass
    assert time.monotonic() - t >= 0.9  # a live lease is waited for, until it expires


GRAPH = """\
graphkit: 1
name: shared
sweeps:
  i: {{range: {{stop: 6}}}}
nodes:
  c: {{type: Count, foreach: i, params: {{log: {log}, value: "${{i.value}}", seconds: 0.2}}}}
  s: {{type: Sum, inputs: {{xs: "c[*].out"}}}}
outputs: {{s: s.out}}
"""


def test_concurrent_runs_on_a_file_url_cache_compute_each_key_once(tmp_path):
    log = tmp_path / "count.log"
    g = tmp_path / "g.yaml"
    g.write_text(GRAPH.format(log=log))
    env = engine_env({"GRAPHKIT_PLUGINS": "enginenodes,sweepnodes"})
    url = f"file://{tmp_path / 'cache'}"
    procs = [subprocess.Popen([sys.executable, "-m", "graphkit", "run", str(g), "--cache", url, "--out",
                               str(tmp_path / f"o{i}"), "--jobs", "2", "-q"], env=env, stderr=subprocess.PIPE, text=True)
             for i in range(3)]
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
    keys = [line.split()[0] for line in log.read_text().splitlines()]
    assert len(keys) == 6 and len(set(keys)) == 6, keys
    outs = {(tmp_path / f"o{i}" / "s.npy").read_bytes() for i in range(3)}
    assert len(outs) == 1


def test_a_file_system_without_exclusive_create_falls_back_with_one_warning(capsys):
    """The weaker mode (write, wait, read back) is announced once per process."""
    from fsspec.implementations.memory import MemoryFileSystem

    from graphkit import leases

    class NoExclusive(MemoryFileSystem):
        def open(self, path, mode="rb", **kw):
            if "x" in mode:
                raise ValueError("no exclusive create here")
            return super().open(path, mode, **kw)

    fs = NoExclusive()
    leases._WARNED.discard("NoExclusive")
    for _ in range(2):
        with leases.Lease(fs, "/weak/k.lock", ttl=5) as lease:
            assert json.loads(fs.cat_file("/weak/k.lock"))["token"] == lease.token
    err = capsys.readouterr().err
    assert err.count("no exclusive create") == 1 and "compute a key twice" in err, err
