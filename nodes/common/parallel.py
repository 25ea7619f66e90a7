"""Row bands on the cores: one persistent thread pool for the per-pixel node maths.

numpy and cv2 release the GIL in their loops, so independent bands of rows run in parallel on
threads; the bands are independent, so results do not depend on the threading.
"""
from __future__ import annotations

import contextvars
import functools
import os
import threading

_POOL = None
_PREFIX = "nodes-bands"


def pool():
    """The persistent thread pool (one thread per core, at most 8), or None on one core."""
    global _POOL
    ncpu = os.cpu_count() or 1
    if ncpu < 2:
        return None
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(min(ncpu, 8), thread_name_prefix=_PREFIX)
    return _POOL


def run_tasks(tasks) -> list:
    """Run the callables, inline on one core or for one task, else on :func:`pool`, and return
    their results in order.  One run of consecutive tasks per thread, the caller's thread
    taking the first: few hand-offs, and neighbouring bands stay on one core.  Each run sees
    the caller's context variables (as the ray-casting backend of ``rays.using``)."""
    tasks = list(tasks)
    ncpu = os.cpu_count() or 1
    if ncpu < 2 or len(tasks) < 2 or threading.current_thread().name.startswith(_PREFIX):
        return [fn() for fn in tasks]  # (inside a pool thread: inline, never waiting on the pool)
    per = -(-len(tasks) // min(ncpu, len(tasks)))
    runs = [tasks[i:i + per] for i in range(0, len(tasks), per)]

    def run(chunk):
        return [fn() for fn in chunk]

    futs = [pool().submit(contextvars.copy_context().run, run, c) for c in runs[1:]]
    out = run(runs[0])
    for fut in futs:
        out += fut.result()
    return out


def run_bands(fn, h: int, rows: int) -> list:
    """fn(r0, r1) for bands of ``rows`` rows covering [0, h), with :func:`run_tasks`."""
    return run_tasks([functools.partial(fn, r, min(h, r + rows)) for r in range(0, h, max(1, rows))])


def run_balanced(jobs, costs) -> list:
    """run_tasks(jobs) with the jobs dealt to the cores by cost (largest first, each to the least
    loaded core), the results in the jobs' order."""
    n = max(1, min(os.cpu_count() or 1, len(jobs)))
    loads, groups = [0] * n, [[] for _ in range(n)]
    for i in sorted(range(len(jobs)), key=lambda i: -costs[i]):
        k = loads.index(min(loads))
        loads[k] += costs[i]
        groups[k].append(i)
    done = run_tasks([functools.partial(lambda g: [jobs[i]() for i in g], g) for g in groups])
    res = [None] * len(jobs)
    for g, rs in zip(groups, done):
        for i, r in zip(g, rs):
            res[i] = r
    return res
