"""Keep large temporaries in the process's heap instead of mapping them afresh for every frame.

glibc serves an allocation above its mmap threshold (128 KiB at start, adapting up to 32 MiB)
with a fresh ``mmap`` and unmaps it on free, and gives the heap's free top back to the system
above its trim threshold; the next frame's numpy temporaries then fault every page in again.
``tune_malloc`` fixes both thresholds once at process start (the CLI, the studio, each Dask
worker, the benchmarks), so a frame reuses the pages the last one freed.  The cost is memory
held: the heap keeps up to ``TRIM_THRESHOLD`` free at its top.  A no-op elsewhere than glibc
(musl, macOS), and when ``GRAPHKIT_MALLOC_TUNING_DISABLE=1``.
"""

from __future__ import annotations

import ctypes
import logging
import os
import platform

M_TRIM_THRESHOLD = -1  # glibc's <malloc.h>
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20  # glibc's largest on 64-bit (HEAP_MAX_SIZE / 2)
TRIM_THRESHOLD = 256 << 20

_log = logging.getLogger(__name__)


def tune_malloc() -> dict[str, int]:
    """Set glibc's mmap and trim thresholds; returns the settings applied ({} when none was)."""
    if os.environ.get("GRAPHKIT_MALLOC_TUNING_DISABLE") == "1":
        return {}
    if platform.libc_ver()[0] != "glibc":
        _log.debug("malloc tuning skipped: not glibc (%s)", platform.libc_ver()[0] or platform.system())
        return {}
    mallopt = ctypes.CDLL(None).mallopt
    wanted = {"M_MMAP_THRESHOLD": (M_MMAP_THRESHOLD, MMAP_THRESHOLD),
              "M_TRIM_THRESHOLD": (M_TRIM_THRESHOLD, TRIM_THRESHOLD)}
    return {name: value for name, (param, value) in wanted.items() if mallopt(param, value) == 1}
