"""Canonical encoding and digests.

* :func:`canonical` encodes params (and key parts) to bytes in one way only; a value of a type it
  does not know raises :class:`CanonicalError` — a cache key never silently ignores a value.
* :func:`digest_value` hashes a port value by its type, meta and array contents (dtype, shape,
  raw bytes) at memory speed (xxh3-128, no copies of contiguous arrays).
* :func:`file_digest` hashes a file by content, memoised on (path, size, mtime_ns, inode).

Array and file digests use xxh3-128: a non-cryptographic 128-bit hash, chosen for speed
(≈20 GB/s); the cache is a trusted store, not a defence against crafted collisions.  Cache keys
are BLAKE2b-128 over the canonical encoding of their parts.
"""
from __future__ import annotations

import enum
import hashlib
import json
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import xxhash
from pydantic import BaseModel

from .errors import CanonicalError

RECIPE_VERSION = "1"  # bump when the key recipe changes: every key changes with it


def canonical(value: Any) -> bytes:
    """Encode ``value`` canonically (same value → same bytes on any machine)."""
    out: list[bytes] = []
    _enc(value, out, "params")
    return b"".join(out)


def _enc(v: Any, out: list[bytes], path: str) -> None:
    if v is None:
        out.append(b"N")
    elif v is True:
        out.append(b"T")
    elif v is False:
        out.append(b"F")
    elif isinstance(v, enum.Enum):
        _enc(v.value, out, path)
    elif isinstance(v, int):
        out.append(b"i%d;" % v)
    elif isinstance(v, float):
        out.append(b"f" + float(v).hex().encode() + b";")
    elif isinstance(v, str):
        b = v.encode("utf-8")
        out.append(b"s%d:" % len(b) + b)
    elif isinstance(v, bytes):
        out.append(b"b%d:" % len(v) + v)
    elif isinstance(v, (list, tuple)):
        out.append(b"l%d[" % len(v))
        for i, x in enumerate(v):
            _enc(x, out, f"{path}[{i}]")
        out.append(b"]")
    elif isinstance(v, dict):
        for k in v:
            if not isinstance(k, str):
                raise CanonicalError(f"{path}: dict keys must be strings, got {type(k).__name__}")
        out.append(b"d%d{" % len(v))
        for k in sorted(v):
            _enc(k, out, path)
            _enc(v[k], out, f"{path}.{k}")
        out.append(b"}")
    elif isinstance(v, BaseModel):
        cls = type(v)
        _enc(f"{cls.__module__}.{cls.__qualname__}", out, path)
        _enc({k: getattr(v, k) for k in type(v).model_fields}, out, path)
    elif isinstance(v, np.ndarray):
        out.append(b"a" + array_digest(v).encode())
    elif isinstance(v, np.generic):
        _enc(v.item(), out, path)
    elif isinstance(v, (set, frozenset)):
        raise CanonicalError(f"{path}: sets have no canonical order; use a sorted list")
    else:
        raise CanonicalError(
            f"{path}: cannot encode a value of type {type(v).__module__}.{type(v).__qualname__} "
            "canonically (cache keys fail closed on unknown types)"
        )


def key_digest(parts: dict) -> str:
    """Cache key: BLAKE2b-128 of the canonical encoding of the key parts."""
    return hashlib.blake2b(canonical(parts), digest_size=16).hexdigest()


def _update_array(h, a: np.ndarray) -> None:
    a = np.ascontiguousarray(a)
    h.update(f"{a.dtype.str}{a.shape};".encode())
    if a.dtype.hasobject:
        raise CanonicalError("object arrays cannot be hashed")
    h.update(memoryview(a).cast("B") if a.size else b"")


def array_digest(a: np.ndarray) -> str:
    """xxh3-128 over dtype, shape and the raw bytes of ``a``."""
    h = xxhash.xxh3_128()
    _update_array(h, a)
    return h.hexdigest()


def meta_bytes(meta: dict) -> bytes:
    return json.dumps(meta, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False).encode()


def parts_digest(type_name: str, meta: dict, arrays: list[np.ndarray]) -> str:
    """Digest of a value given as (port type name, meta, arrays)."""
    h = xxhash.xxh3_128()
    h.update(type_name.encode() + b"\0")
    h.update(meta_bytes(meta) + b"\0")
    h.update(b"%d;" % len(arrays))
    for a in arrays:
        _update_array(h, a)
    return h.hexdigest()


# --------------------------------------------------------------------------------------------
# files

_memo_lock = threading.Lock()
_memo: dict[str, tuple[tuple, str]] = {}


def file_digest(path: str | os.PathLike, memo_file: Path | None = None) -> str:
    """Content digest of a file, memoised on (size, mtime_ns, inode).

    ``memo_file`` (a JSON file, usually inside the cache folder) keeps the memo across runs so a
    re-run does not re-read large unchanged inputs.
    """
    p = os.path.abspath(path)
    st = os.stat(p)
    sig = (st.st_size, st.st_mtime_ns, st.st_ino)
    with _memo_lock:
        if not _memo and memo_file is not None:
            _load_memo(memo_file)
        hit = _memo.get(p)
        if hit and tuple(hit[0]) == sig:
            return hit[1]
    h = xxhash.xxh3_128()
    with open(p, "rb") as f:
        while chunk := f.read(1 << 22):
            h.update(chunk)
    d = h.hexdigest()
    with _memo_lock:
        _memo[p] = (sig, d)
        if memo_file is not None:
            _save_memo(memo_file)
    return d


def _load_memo(memo_file: Path) -> None:
    try:
        data = json.loads(Path(memo_file).read_text())
        for k, (sig, d) in data.items():
            _memo[k] = (tuple(sig), d)
    except (OSError, ValueError, TypeError):
        pass


def _save_memo(memo_file: Path) -> None:
    try:
        tmp = Path(f"{memo_file}.{os.getpid()}.{threading.get_ident()}.tmp")
        tmp.write_text(json.dumps({k: [list(s), d] for k, (s, d) in _memo.items()}))
        os.replace(tmp, memo_file)
    except OSError:
        pass  # the memo is only an optimisation
