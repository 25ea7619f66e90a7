"""Engine overhead, all-cached re-run and hashing throughput (issues 2 and 10).

(a) a 1000-node no-op chain and a 1000-node wide graph through graphkit vs ``dask.get`` (the
    synchronous scheduler) in the same process: per-node overhead and the ratio, cold with
    durability (group commit), cold without sync, and all cached (with the read checks);
(b) an all-cached re-run of the demo graph, wall time including interpreter start;
(c) array hashing throughput (GB/s).

Run:  .venv/bin/python benchmarks/bench_engine.py [hashing] [demo] [overhead]   (default: all three)
"""
from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "support"))
N = 1000
REPS = int(os.environ.get("BENCH_REPS", "7"))  # interleaved repetitions of (a)


def chain_yaml(n, salt=0):
    """A chain of n no-op nodes; another ``salt``: the same graph with other params (all keys new)."""
    lines = ["graphkit: 1", "name: chain", "nodes:", "  n0: {type: Noop" + (f", params: {{i: {salt}}}}}" if salt else "}")]
    lines += [f"  n{i}: {{type: Noop, inputs: {{x: n{i-1}.out}}, params: {{i: {i + salt}}}}}" for i in range(1, n)]
    lines.append(f"outputs: [n{n-1}.out]")
    return "\n".join(lines) + "\n"


def wide_yaml(n, salt=0):
    lines = ["graphkit: 1", "name: wide", "nodes:", "  src: {type: Noop" + (f", params: {{i: {salt}}}}}" if salt else "}")]
    lines += [f"  n{i}: {{type: Noop, inputs: {{x: src.out}}, params: {{i: {i + salt}}}}}" for i in range(1, n - 1)]
    lines.append("  sink: {type: Sum, inputs: {xs: [" + ", ".join(f"n{i}.out" for i in range(1, n - 1)) + "]}}")
    lines.append("outputs: [sink.out]")
    return "\n".join(lines) + "\n"


def noop(x=None):
    return x if x is not None else np.zeros(1)


def total(*xs):
    return np.sum(xs, axis=0)


def dask_graphs(n):
    chain = {"n0": (noop,)}
    chain.update({f"n{i}": (noop, f"n{i-1}") for i in range(1, n)})
    wide = {"src": (noop,)}
    wide.update({f"n{i}": (noop, "src") for i in range(1, n - 1)})
    wide["sink"] = (total, *[f"n{i}" for i in range(1, n - 1)])
    return (chain, f"n{n-1}"), (wide, "sink")


def timings(fn, repeat=5):
    """(best, median) wall time of ``fn`` over ``repeat`` calls."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times), statistics.median(times)


def best(fn, repeat=5):
    return timings(fn, repeat)


def bench_overhead():
    """Per-node overhead of graphkit vs dask.get in the same process.

    cold, durable: a fresh store with the default group commit (writes renamed into place, one
    syncfs per second and one at the end: what `graphkit run` does); cold, no sync: the same
    without the syncfs; all cached: every node a hit (records read and checked; objects are not
    read, as in a real all-cached run that loads only what it exports); the file system's own
    floor (see fs_floor) for what a cold node writes (a hard link to the run's journal and one
    append to it: a cold run cannot cost less than it per node), beside the floor of a new file
    per node (what a record file of its own, the layout before journals, costs on the same disk
    at the same moment); and the cold durable run minus the link floor (what the engine itself
    adds).  "in a used cache": the same cold durable run
    into a cache that earlier runs have used (so its 256 key shard folders exist, as in any cache
    but a brand-new one), each repetition with other params (every node new), beside the floor of
    a file per node into existing folders; a fresh folder per run, above, also pays for making
    those folders (a few hundred mkdirs, the first run of a cache's life).  Each ratio divides by dask.get measured
    within the same repetition (REPS of them, interleaved; ``BENCH_REPS`` sets how many)."""
    import dask

    import enginenodes
    from graphkit.executor import run_local
    from graphkit.graphfile import load_graph
    from graphkit.registry import discover
    from graphkit.runner import Session
    from graphkit.store import Store

    reg = discover()
    reg.add_provider("nodes", "bench", enginenodes)
    print(f"(a) engine overhead per node, {N}-node no-op graphs, same process (best and median)")
    rows = {}
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as d:
        d = Path(d)
        (chain_dsk, chain_key), (wide_dsk, wide_key) = dask_graphs(N)
        for name, text, (dsk, key) in (("chain", chain_yaml(N), (chain_dsk, chain_key)),
                                       ("wide", wide_yaml(N), (wide_dsk, wide_key))):
            g = d / f"{name}.yaml"
            g.write_text(text)
            t_dask = timings(lambda: dask.get(dsk, key), 7)
            t_load = timings(lambda: load_graph(g, reg, {}))
            graph = load_graph(g, reg, {})
            target = [chain_key if name == "chain" else "sink"]
            counter = iter(range(10**6))

            def cold(kind):
                loc = d / f"{kind}-{name}-{next(counter)}"
                store = Store(loc, sync=(kind == "durable")).open()
                settle()
                t = time.perf_counter()
                run_local(Session(graph, reg, store), target)
                return time.perf_counter() - t

            def floor(existing=False, link=True):
                settle()
                return fs_floor(d / f"floor-{name}-{next(counter)}", N, existing, link)

            # cold nodes in a cache that is in use (its shard folders made by earlier runs, as for
            # any cache but a brand-new one): each repetition runs the graph with other params
            used = Store(d / f"used-{name}").open()
            maker = chain_yaml if name == "chain" else wide_yaml
            salted = []
            for r in range(REPS + 1):
                gs = d / f"{name}-{r}.yaml"
                gs.write_text(maker(N, salt=(r + 1) * 10**6))
                salted.append(load_graph(gs, reg, {}))
            run_local(Session(salted.pop(), reg, used), target)

            def cold_used():
                session = Session(salted.pop(), reg, used)
                settle()
                t = time.perf_counter()
                run_local(session, target)
                return time.perf_counter() - t

            # one repetition = dask.get (median of 3, just before), then each graphkit variant and
            # the file-system floor: ratios are taken within a repetition, so a disk that slows
            # down between repetitions moves both sides of a ratio (these machines are shared)
            warm = Store(d / f"warm-{name}").open()
            run_local(Session(graph, reg, warm), target)

            def hit():
                t = time.perf_counter()
                run_local(Session(graph, reg, warm), target)
                return time.perf_counter() - t

            kinds = {"graphkit run, all cached (checked)": hit,
                     "graphkit run, cold, no sync": lambda: cold("nosync"),
                     "graphkit run, cold, durable (group commit)": lambda: cold("durable"),
                     "file system floor: 1 link + 1 append per node": floor,
                     "(a new file per node instead)": lambda: floor(link=False),
                     "graphkit run, cold, durable, in a used cache": cold_used,
                     "file system floor, in existing folders": lambda: floor(True),
                     "(a new file per node instead, existing folders)": lambda: floor(True, link=False)}

            per = {k: [] for k in kinds}
            above, above_used = [], []
            for _ in range(REPS):
                base = statistics.median(timings(lambda: dask.get(dsk, key), 3))
                got = {k: fn() for k, fn in kinds.items()}
                for k, t in got.items():
                    per[k].append((t, t / base))
                above.append((got["graphkit run, cold, durable (group commit)"]
                              - got["file system floor: 1 link + 1 append per node"]) / base)
                above_used.append((got["graphkit run, cold, durable, in a used cache"]
                                   - got["file system floor, in existing folders"]) / base)
            print(f"  {name:5} {'dask.get, synchronous scheduler':44} best {t_dask[0] / N * 1e6:7.1f} µs/node"
                  f"   median {t_dask[1] / N * 1e6:7.1f} µs/node")
            print(f"  {name:5} {'graphkit load + validate (YAML)':44} best {t_load[0] / N * 1e6:7.1f} µs/node"
                  f" ×{t_load[0] / t_dask[0]:6.2f} dask   median {t_load[1] / N * 1e6:7.1f} µs/node"
                  f" ×{t_load[1] / t_dask[1]:6.2f} dask")
            for label, v in per.items():
                ts, rs = [x[0] for x in v], [x[1] for x in v]
                rows[(name, label)] = (min(rs), statistics.median(rs))
                print(f"  {name:5} {label:44} best {min(ts) / N * 1e6:7.1f} µs/node ×{min(rs):6.2f} dask"
                      f"   median {statistics.median(ts) / N * 1e6:7.1f} µs/node ×{statistics.median(rs):6.2f} dask")
            for label, xs in (("cold durable minus the floor (engine alone)", above),
                              ("the same, in a used cache", above_used)):
                rows[(name, label)] = (min(xs), statistics.median(xs))
                print(f"  {name:5} {label:44} best ×{min(xs):6.2f} dask"
                      f"                 median ×{statistics.median(xs):6.2f} dask")
    return rows


def settle() -> None:
    """Before each timed variant (not timed): write back what this benchmark's earlier variants
    left dirty.  Without it a durable run's syncfs also writes back the 1000 files of the no-sync
    run (or the floor) just before it, and charges them to the durable run."""
    os.sync()


def fs_floor(root: Path, n: int, existing: bool = False, link: bool = True) -> float:
    """Seconds the file system alone charges a cold run for one record per node, into 256 shard
    folders made on the way (a new cache) or, ``existing``, beforehand (a cache in use), measured
    on the same folder in the same run.  ``link``: what graphkit does, append 300 bytes to one
    journal file and make a hard link to it per node (a directory entry each, no new inode);
    else create, write and rename a file per node (a new inode each: ~10-20 µs on a quiet ext4,
    200-300 µs of kernel time on a busy shared machine)."""
    (root / "tmp").mkdir(parents=True)
    if existing:
        for i in range(256):
            (root / f"{i:02x}").mkdir()
        os.sync()
    body = b"x" * 300
    t = time.perf_counter()
    if link:
        journal = f"{root}/journal"
        jfd = os.open(journal, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o666)
        for i in range(n):
            os.write(jfd, body)
            dest = f"{root}/{i % 256:02x}/{i}"
            try:
                os.link(journal, dest)
            except FileNotFoundError:
                os.mkdir(os.path.dirname(dest))
                os.link(journal, dest)
        os.close(jfd)
        return time.perf_counter() - t
    for i in range(n):
        tmp, dest = f"{root}/tmp/{i}", f"{root}/{i % 256:02x}/{i}"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        os.write(fd, body)
        os.close(fd)
        try:
            os.replace(tmp, dest)
        except FileNotFoundError:
            os.mkdir(os.path.dirname(dest))
            os.replace(tmp, dest)
    return time.perf_counter() - t


def bench_cached_demo():
    print("(b) all-cached re-run of the demo graphs/face_relight.yaml, wall time incl. interpreter start")
    exe = ROOT / ".venv" / "bin" / "graphkit"
    with tempfile.TemporaryDirectory() as d:
        cmd = [str(exe), "run", str(ROOT / "graphs" / "face_relight.yaml"), "--cache", f"{d}/c", "--out", f"{d}/o", "-q"]
        subprocess.run(cmd, check=True)
        times = []
        for _ in range(7):
            t = time.perf_counter()
            subprocess.run(cmd, check=True)
            times.append(time.perf_counter() - t)
        bare = []
        for _ in range(5):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-c", "pass"], check=True)
            bare.append(time.perf_counter() - t)
    print(f"  median {statistics.median(times):.3f} s, best {min(times):.3f} s (goal < 0.6 s); "
          f"bare interpreter {statistics.median(bare):.3f} s")
    return statistics.median(times)


def bench_hashing():
    from graphkit.hashing import array_digest

    print("(c) array hashing throughput (xxh3-128 over dtype, shape, bytes)")
    out = {}
    for mb in (16, 256):
        a = np.random.default_rng(0).random(mb * (1 << 20) // 8)
        array_digest(a)
        t, med = best(lambda: array_digest(a), repeat=7)
        copy_t, _ = best(lambda: a.copy(), repeat=7)
        out[mb] = a.nbytes / t / 1e9
        print(f"  {mb:4d} MB: {a.nbytes / t / 1e9:6.1f} GB/s best, {a.nbytes / med / 1e9:6.1f} GB/s median "
              f"(goal ≥ 5); memcpy of the same array {a.nbytes / copy_t / 1e9:5.1f} GB/s")
    return out


if __name__ == "__main__":
    os.environ.setdefault("GRAPHKIT_PLUGINS", "")
    import argparse

    ap = argparse.ArgumentParser(description="Engine overhead, all-cached re-run and hashing throughput "
                                 "(BENCH_REPS sets the repetitions of overhead).")
    sections = ["hashing", "demo", "overhead"]
    # no choices=: Python 3.11's argparse checks an empty nargs="*" list against them and refuses it
    ap.add_argument("which", nargs="*", metavar="{" + ",".join(sections) + "}",
                    help="the sections to run (default: all three)")
    which = ap.parse_args().which or sections
    if set(which) - set(sections):
        ap.error(f"unknown section(s) {sorted(set(which) - set(sections))}; choose from {sections}")
    if "hashing" in which:
        bench_hashing()
    if "demo" in which:
        bench_cached_demo()
    if "overhead" in which:
        bench_overhead()
