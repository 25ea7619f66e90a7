"""RatioImage: numpy reference vs the opencl backend (plugins/graphkit-opencl), same machine.

2048×2048×3 float32 a, 2048×2048×3 and ×1 b; median of 10 timed runs after 2 warm-up runs
(the warm-up also builds the OpenCL program, which is cached per process).  Times are the
whole backend ``compute`` — input checks, host↔device copies and the kernel — as the engine
calls it.  Usage: ``.venv/bin/python benchmarks/bench_ratio_backends.py [--size N] [--runs R]``
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np


def median_seconds(fn, runs: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args(argv)

    from graphkit import Image
    from graphkit.registry import default_registry

    reg = default_registry()
    node = reg.node_class("RatioImage")
    if "opencl" not in reg.backend_names("RatioImage"):
        print("the opencl backend is not installed (pip install -e plugins/graphkit-opencl)", file=sys.stderr)
        return 1
    backend = reg.backend_class("RatioImage", "opencl")
    if not backend.available():
        print(f"opencl is not available here: {backend.why_unavailable()}", file=sys.stderr)
        return 1
    from graphkit_opencl.runtime import runtime

    n = args.size
    rng = np.random.default_rng(0)
    a = Image(rng.random((n, n, 3), dtype=np.float32))
    params = node.Params(eps=1e-3)
    print(f"RatioImage {n}×{n}×3 float32, median of {args.runs} runs; opencl device: {runtime().describe()}")
    for bc in (3, 1):
        b = Image(rng.random((n, n, bc), dtype=np.float32))
        ref = node(params).compute(a=a, b=b).pixels
        got = backend(params).compute(a=a, b=b).pixels
        np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6)
        t_np = median_seconds(lambda: node(params).compute(a=a, b=b), args.runs)
        t_cl = median_seconds(lambda: backend(params).compute(a=a, b=b), args.runs)
        print(f"  b with {bc} channel{'s' if bc > 1 else ''}:  numpy {t_np * 1e3:8.2f} ms   "
              f"opencl {t_cl * 1e3:8.2f} ms   opencl/numpy {t_cl / t_np:5.2f}×")
    return 0


if __name__ == "__main__":
    sys.exit(main())
