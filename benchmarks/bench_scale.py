"""Cost per node as a graph grows (issue 25): 1k to 20k nodes.

The graph: one 16×16 source (``Const``, 256 values) read by N - 1 no-op nodes, each of them a
graph output (so a run publishes N - 1 files into ``--out``).  For each size, in this process:

* validate — load the YAML and check it (``graphkit validate``);
* dry-run  — validate + per node cached or would run, on an empty cache (``graphkit status``);
* cold run — validate + run every node into an empty cache + publish into an empty ``--out``;
* warm run — the same again: every node cached, every file already in ``--out``;
* dask.get — the same task graph (a source, N - 1 no-op tasks reading it) through Dask's
  synchronous scheduler: the peer, a lower bound with no cache, no checks and no files.

Each is the cost per node (µs); flat rows mean the cost grows linearly with the graph.  Also:
the warm run of the 10k graph through the command line, wall time including interpreter
start-up (issue 25's goal: ≤ 3 s).

Run:  .venv/bin/python benchmarks/bench_scale.py [--sizes 1000,2000,5000,10000,20000] [--plot scale.png]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SUPPORT = ROOT / "tests" / "support"
sys.path.insert(0, str(SUPPORT))
PHASES = ("validate", "dry-run", "cold run", "warm run", "dask.get")


def fan_yaml(n: int) -> str:
    lines = ["graphkit: 1", "name: scale", "nodes:", "  src: {type: Const, params: {size: 256}}"]
    lines += [f"  n{i}: {{type: Noop, inputs: {{x: src.out}}, params: {{i: {i}}}}}" for i in range(1, n)]
    lines.append("outputs:")
    lines += [f"  o{i}: n{i}.out" for i in range(1, n)]
    return "\n".join(lines) + "\n"


def _src():
    return np.zeros(256)


def _noop(x):
    return x


def dask_graph(n: int) -> tuple[dict, list[str]]:
    dsk = {"src": (_src,)}
    dsk.update({f"n{i}": (_noop, "src") for i in range(1, n)})
    return dsk, [f"n{i}" for i in range(1, n)]


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def measure(n: int, d: Path, reg) -> dict[str, float]:
    """Seconds of each phase for the n-node graph (one run each: large graphs are slow)."""
    import dask

    from graphkit import run_graph
    from graphkit.dryrun import status
    from graphkit.graphfile import load_graph

    g = d / f"scale-{n}.yaml"
    g.write_text(fan_yaml(n))
    cache, out = d / f"cache-{n}", d / f"out-{n}"
    dsk, keys = dask_graph(n)
    return {
        "validate": timed(lambda: load_graph(g, reg, {})),
        "dry-run": timed(lambda: status(g, cache, registry=reg)),
        "cold run": timed(lambda: run_graph(g, cache=cache, out=out, registry=reg)),
        "warm run": timed(lambda: run_graph(g, cache=cache, out=out, registry=reg)),
        "dask.get": timed(lambda: dask.get(dsk, keys)),
    }


def cli_warm(n: int, d: Path) -> float:
    """Wall time of `graphkit run` of the n-node graph, all cached, including start-up."""
    env = dict(os.environ, PYTHONPATH=str(SUPPORT), GRAPHKIT_PLUGINS="enginenodes")
    cmd = [sys.executable, "-m", "graphkit", "run", str(d / f"scale-{n}.yaml"), "--cache", str(d / f"cache-{n}"),
           "--out", str(d / f"out-{n}"), "-q"]
    subprocess.run(cmd, env=env, check=True)  # cached, and in --out (when n was not measured)
    return timed(lambda: subprocess.run(cmd, env=env, check=True))


def plot(rows: dict[int, dict[str, float]], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = sorted(rows)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for phase in PHASES:
        ax.plot(sizes, [rows[n][phase] / n * 1e6 for n in sizes], marker="o", label=phase)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("nodes in the graph")
    ax.set_ylabel("µs per node")
    ax.set_title("graphkit cost per node (flat = linear in the graph's size)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"plot: {path}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000,5000,10000,20000", help="node counts, comma-separated")
    ap.add_argument("--plot", help="write a PNG of µs per node against the size here")
    ap.add_argument("--cli-warm", type=int, default=10_000, help="size of the command-line warm run (0: skip)")
    args = ap.parse_args(argv)
    import enginenodes

    from graphkit.registry import discover

    reg = discover()
    reg.add_provider("nodes", "bench", enginenodes)
    sizes = [int(s) for s in args.sizes.split(",")]
    rows: dict[int, dict[str, float]] = {}
    print(f"{'nodes':>6} " + " ".join(f"{p:>18}" for p in PHASES) + "   (µs per node; total s)")
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as d:
        d = Path(d)
        for n in sizes:
            rows[n] = measure(n, d, reg)
            print(f"{n:>6} " + " ".join(f"{rows[n][p] / n * 1e6:8.1f} ({rows[n][p]:6.2f})" for p in PHASES), flush=True)
        if args.cli_warm:
            n = args.cli_warm
            if n not in rows:
                (d / f"scale-{n}.yaml").write_text(fan_yaml(n))
            print(f"warm `graphkit run` of the {n}-node graph, wall time with start-up: {cli_warm(n, d):.2f} s")
    if args.plot:
        plot(rows, args.plot)


if __name__ == "__main__":
    main()
