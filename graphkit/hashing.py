"""Canonical encoding and digests.

* :func:`canonical` encodes params (and key parts) to bytes in one way only; a value of a type it
  does not know raises :class:`CanonicalError` — a cache key never silently ignores a value.
* :func:`digest_value` hashes a port value by its type, meta and array contents (dtype, shape,
  raw bytes) at memory speed (xxh3-128, no copies of contiguous arrays).
* :func:`file_digest` hashes a file by content, memoised on (path, size, mtime_ns, ctime_ns, inode).

Array and file digests use xxh3-128: a non-cryptographic 128-bit hash, chosen for speed
(≈20 GB/s); the cache is a trusted store, not a defence against crafted collisions.  Cache keys
are BLAKE2b-128 over the canonical encoding of their parts.
"""
from __future__ import annotations

import enum
import functools
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
    try:
        _enc(value, out)
    except CanonicalError:
        _find_bad(value, "params")  # re-walk to name the offending place
        raise
    return b"".join(out)


def _enc(v: Any, out: list[bytes]) -> None:
    enc = _EXACT.get(type(v))  # the common types, by exact type (fast); then their subclasses
    if enc is None:
        enc = next((e for base, e in _SUBCLASSES if isinstance(v, base)), None)
        if enc is None:
            raise CanonicalError(_cannot(v))
    enc(v, out)


def _enc_str(v: str, out: list[bytes]) -> None:
    b = str(v).encode("utf-8")
    out.append(b"s%d:" % len(b))
    out.append(b)


def _enc_float(v: float, out: list[bytes]) -> None:
    out.append(b"f" + float(v).hex().encode() + b";")


def _enc_bool(v: bool, out: list[bytes]) -> None:
    out.append(b"T" if v else b"F")


def _enc_int(v: int, out: list[bytes]) -> None:
    out.append(b"i%d;" % v)


def _enc_none(v: None, out: list[bytes]) -> None:
    out.append(b"N")


def _enc_dict(v: dict, out: list[bytes]) -> None:
    out.append(b"d%d{" % len(v))
    try:
        keys = sorted(v)
    except TypeError:
        raise CanonicalError("dict keys must be strings") from None
    for k in keys:
        if type(k) is not str:
            raise CanonicalError("dict keys must be strings")
        _enc_str(k, out)
        x = v[k]
        _EXACT.get(type(x), _enc)(x, out)  # = _enc(x, out), a call fewer for the common types
    out.append(b"}")


def _enc_list(v: list | tuple, out: list[bytes]) -> None:
    out.append(b"l%d[" % len(v))
    for x in v:
        _EXACT.get(type(x), _enc)(x, out)  # = _enc(x, out), a call fewer for the common types
    out.append(b"]")


def _enc_model(v: BaseModel, out: list[bytes]) -> None:
    """= _enc(class name) + _enc({field: value}), laid out once per class."""
    head, fields = _model_layout(type(v))
    out.append(head)
    for name, kb in fields:
        out.append(kb)
        _enc(getattr(v, name), out)
    out.append(b"}")


def _enc_bytes(v: bytes, out: list[bytes]) -> None:
    out.append(b"b%d:" % len(v) + bytes(v))


def _enc_array(v: np.ndarray, out: list[bytes]) -> None:
    out.append(b"a" + array_digest(v).encode())


_EXACT = {str: _enc_str, float: _enc_float, bool: _enc_bool, int: _enc_int, type(None): _enc_none,
          dict: _enc_dict, list: _enc_list, tuple: _enc_list}
# in this order: an IntEnum is an enum before it is an int, a numpy float64 a float (bool
# cannot be subclassed: its exact type took it); a subclass encodes as its base type
_SUBCLASSES = (
    (BaseModel, _enc_model),
    (enum.Enum, lambda v, out: _enc(v.value, out)),
    (int, _enc_int),
    (float, _enc_float),
    (str, _enc_str),
    (bytes, _enc_bytes),
    (np.ndarray, _enc_array),
    (np.generic, lambda v, out: _enc(v.item(), out)),
    ((list, tuple), lambda v, out: _enc_list(list(v), out)),
    (dict, lambda v, out: _enc_dict(dict(v), out)),
)


@functools.lru_cache(maxsize=1024)
def _model_layout(t: type) -> tuple[bytes, tuple[tuple[str, bytes], ...]]:
    """A pydantic model class's encoding without its values: the class name and the dict header,
    then each field name (sorted, as _enc sorts a dict's keys) with its encoding."""
    names = sorted(t.model_fields)
    return canonical(f"{t.__module__}.{t.__qualname__}") + b"d%d{" % len(names), tuple((n, canonical(n)) for n in names)


def _cannot(v: Any) -> str:
    if isinstance(v, (set, frozenset)):
        return "sets have no canonical order; use a sorted list"
    return (f"cannot encode a value of type {type(v).__module__}.{type(v).__qualname__} "
            "canonically (cache keys fail closed on unknown types)")


def _find_bad(v: Any, path: str) -> None:
    """Raise CanonicalError naming the path of the first value that cannot be encoded."""
    if isinstance(v, dict):
        for k, x in v.items():
            if not isinstance(k, str):
                raise CanonicalError(f"{path}: dict keys must be strings, got {type(k).__name__}")
            _find_bad(x, f"{path}.{k}")
    elif isinstance(v, (list, tuple)):
        for i, x in enumerate(v):
            _find_bad(x, f"{path}[{i}]")
    elif isinstance(v, BaseModel):
        for k in type(v).model_fields:
            _find_bad(getattr(v, k), f"{path}.{k}")
    else:
        try:
            _enc(v, [])
        except CanonicalError as e:
            raise CanonicalError(f"{path}: {e}") from None


def key_digest(parts: dict) -> str:
    """Cache key: BLAKE2b-128 of the canonical encoding of the key parts."""
    return hashlib.blake2b(canonical(parts), digest_size=16).hexdigest()


def canonical_items(parts: dict) -> dict[str, bytes]:
    """Encode each entry of a dict on its own (for :func:`canonical_merge`)."""
    out = {}
    for k, v in parts.items():
        out[k] = _str_item(k, v) if type(v) is str else _key_bytes(k) + canonical(v)
    return out


@functools.lru_cache(maxsize=256)
def _key_bytes(k: str) -> bytes:
    return canonical(k)


@functools.lru_cache(maxsize=4096)
def _str_item(k: str, v: str) -> bytes:
    """Encoded (key, value) for string values (node type, versions, backend: they repeat)."""
    return canonical(k) + canonical(v)


def canonical_merge(static: dict[str, bytes], varying: dict) -> bytes:
    """Canonical encoding of a dict whose entries are partly pre-encoded (see canonical_items)."""
    items = dict(static)
    items.update(canonical_items(varying))
    return b"d%d{" % len(items) + b"".join([items[k] for k in sorted(items)]) + b"}"


@functools.lru_cache(maxsize=1024)
def _array_head(dtype: np.dtype, shape: tuple) -> bytes:
    """What an array's digest starts with: dtype and shape (the same few repeat in a run)."""
    if dtype.hasobject:
        raise CanonicalError("object arrays cannot be hashed")
    return f"{dtype.str}{shape};".encode()


def _update_array(h, a: np.ndarray) -> None:
    a = np.ascontiguousarray(a)
    h.update(_array_head(a.dtype, a.shape))
    h.update(memoryview(a).cast("B") if a.size else b"")


def array_digest(a: np.ndarray) -> str:
    """xxh3-128 over dtype, shape and the raw bytes of ``a``."""
    h = xxhash.xxh3_128()
    _update_array(h, a)
    return h.hexdigest()


_META_JSON = json.JSONEncoder(sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def meta_bytes(meta: dict) -> bytes:
    """Canonical JSON of a value's meta (sorted keys, ASCII, no NaN/Inf)."""
    if type(meta) is dict and not meta:  # most arrays and images: no meta
        return b"{}"
    return _META_JSON.encode(meta).encode()


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
    """Content digest of a file, memoised on (size, mtime_ns, ctime_ns, inode).

    ``memo_file`` (a JSON file, usually inside the cache folder) keeps the memo across runs so a
    re-run does not re-read large unchanged inputs.  The ctime is part of the memo because an
    edit in place can restore size, inode and mtime (``touch -r``), but not the ctime.  Each
    memo entry carries a check over (path, stat signature, digest): an edited entry is dropped
    and the file hashed again.
    """
    p = os.path.abspath(path)
    st = os.stat(p)
    sig = (st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
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


def _memo_check(path: str, sig, digest: str) -> str:
    return xxhash.xxh3_64_hexdigest(json.dumps([path, list(sig), digest]).encode())


def _load_memo(memo_file: Path) -> None:
    try:
        data = json.loads(Path(memo_file).read_text())
        for k, entry in data.items():
            try:
                sig, d, check = entry
                if len(sig) == 4 and check == _memo_check(k, sig, d):
                    _memo[k] = (tuple(sig), d)
            except (ValueError, TypeError):
                continue  # an old or edited entry: the file is hashed again
    except (OSError, ValueError, TypeError, AttributeError):
        pass


def _save_memo(memo_file: Path) -> None:
    try:
        tmp = Path(f"{memo_file}.{os.getpid()}.{threading.get_ident()}.tmp")
        tmp.write_text(json.dumps({k: [list(s), d, _memo_check(k, s, d)] for k, (s, d) in _memo.items()}))
        os.replace(tmp, memo_file)
    except OSError:
        pass  # the memo is only an optimisation
