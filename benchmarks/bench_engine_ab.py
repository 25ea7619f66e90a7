"""Cold-run overhead of two graphkit trees, interleaved (issue 10): before/after on a noisy machine.

The cost of a cold node moves with the shared disk (creating an inode takes 20 µs to 300 µs here
from one minute to the next), so two benchmark runs a minute apart do not compare.  This runs two
worker processes, one importing graphkit from this checkout and one from another tree (``BASE``,
e.g. ``git archive main graphkit | tar -x -C /tmp/base``), and alternates single cold runs between
them (the order flips every repetition); each ratio divides a cold 1000-node run by ``dask.get``
on the same graph in the same worker just before it.

Run:  .venv/bin/python benchmarks/bench_engine_ab.py /tmp/base [repetitions]
"""
from __future__ import annotations

import collections
import itertools
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def worker() -> None:
    if os.environ.get("BASE"):  # import graphkit from BASE, not from this checkout's editable install
        sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f).lower()
                            and "editable" not in type(f).__module__.lower()]
        sys.path.insert(0, os.environ["BASE"])
    sys.path.insert(0, str(ROOT / "tests" / "support"))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    os.environ.setdefault("GRAPHKIT_PLUGINS", "")
    import dask

    import bench_engine as B
    import enginenodes
    import graphkit
    from graphkit.executor import run_local
    from graphkit.graphfile import load_graph
    from graphkit.registry import discover
    from graphkit.runner import Session
    from graphkit.store import Store

    reg = discover()
    reg.add_provider("nodes", "bench", enginenodes)
    d = Path(tempfile.mkdtemp(dir=os.environ.get("BENCH_TMP")))
    (chain_dsk, chain_key), (wide_dsk, wide_key) = B.dask_graphs(B.N)
    dsk = {"chain": (chain_dsk, chain_key), "wide": (wide_dsk, wide_key)}
    target = {"chain": [chain_key], "wide": ["sink"]}
    graphs = {}
    for name, text in (("chain", B.chain_yaml(B.N)), ("wide", B.wide_yaml(B.N))):
        (d / f"{name}.yaml").write_text(text)
        graphs[name] = load_graph(d / f"{name}.yaml", reg, {})
    counter = itertools.count()
    print("ready", Path(graphkit.__file__).parent, flush=True)
    for line in sys.stdin:
        kind, name = line.split()
        if kind == "dask":
            t = time.perf_counter()
            dask.get(*dsk[name])
        else:
            store = Store(d / f"{name}-{next(counter)}", sync=(kind == "durable")).open()
            B.settle()  # nothing of the earlier runs left to write back (bench_engine.settle)
            t = time.perf_counter()
            run_local(Session(graphs[name], reg, store), target[name])
        print(time.perf_counter() - t, flush=True)


def main(base: str, reps: int) -> None:
    me = [sys.executable, __file__, "--worker"]
    workers = {w: subprocess.Popen(me, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
               for w, env in (("base", dict(os.environ, BASE=base)), ("this", dict(os.environ, BASE="")))}
    for w, p in workers.items():
        print(f"{w}: graphkit from {p.stdout.readline().split(maxsplit=1)[1].strip()}")

    def ask(w: str, cmd: str) -> float:
        workers[w].stdin.write(cmd + "\n")
        workers[w].stdin.flush()
        return float(workers[w].stdout.readline())

    res = collections.defaultdict(list)
    for r in range(reps):
        for name in ("chain", "wide"):
            for w in (("base", "this") if r % 2 == 0 else ("this", "base")):
                t_dask = min(ask(w, f"dask {name}") for _ in range(2))
                for kind in ("durable", "nosync"):
                    res[(name, kind, w)].append((ask(w, f"{kind} {name}"), t_dask))
    print(f"cold 1000-node runs, {reps} interleaved repetitions (ratio: the run / dask.get just before it)")
    for (name, kind, w), xs in sorted(res.items()):
        ratios = [t / k for t, k in xs]
        us = [t / 1000 * 1e6 for t, _ in xs]
        print(f"  {name:5} {kind:8} {w:4}  best ×{min(ratios):5.2f}  median ×{statistics.median(ratios):5.2f}"
              f"   µs/node best {min(us):6.1f}  median {statistics.median(us):6.1f}")
    for p in workers.values():
        p.stdin.close()
        p.wait()


if __name__ == "__main__":
    if sys.argv[1:2] == ["--worker"]:
        worker()
    elif len(sys.argv) >= 2:
        main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 12)
    else:
        sys.exit(__doc__)
