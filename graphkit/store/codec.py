"""The codec: a value ↔ the bytes of one stored object.

An object is ``GKOBJ1\n\0``, the length of a JSON header (port type, meta, array layout and the
value's digest), the header, then each array's raw bytes aligned to 64 bytes, so that a read
maps the arrays without copying.  An object is named by its digest (xxh3-128 of the port type,
meta and arrays: graphkit.hashing), and every read re-hashes it (:func:`check_object`): a
damaged object is never served.
"""
from __future__ import annotations

import json
import re
import struct
from typing import Any, Callable, Iterator

import numpy as np

from ..errors import CacheError
from ..hashing import parts_digest
from ..types import PortType

MAGIC = b"GKOBJ1\n\0"
ALIGN = 64
MiB = 1 << 20
#: the one JSON form of record bodies and object headers (a prebuilt encoder: json.dumps with
#: these arguments builds a new JSONEncoder on every call)
_JSON = json.JSONEncoder(sort_keys=True, separators=(",", ":"))


def _kept_encoder() -> Callable[[Any], str]:
    """_JSON.encode without building a new C encoder per call (JSONEncoder.encode does, which
    was a quarter of a record's encoding): the same C encoder json uses, kept.  It skips the
    circular-reference check (records and headers are trees built here; a value's meta was
    already encoded with the check by hashing.meta_bytes).  A Python without it: _JSON.encode
    (tests/test_engine_store_unit.py compares the two texts)."""
    try:
        from json.encoder import c_make_encoder, encode_basestring_ascii

        enc = c_make_encoder(None, _JSON.default, encode_basestring_ascii, None, ":", ",", True, False, True)
    except (ImportError, TypeError):  # pragma: no cover - CPython has it
        return _JSON.encode

    def encode(o: Any) -> str:
        return "".join(enc(o, 0))

    return encode


json_encode = _kept_encoder()


def object_rel(digest: str) -> str:
    """Where the object named ``digest`` is, below the cache root."""
    return f"objects/{digest[:2]}/{digest}"


def fmt_size(n: int) -> str:
    """Sizes are shown in MiB (2^20 bytes) everywhere: `cache ls`, gc, verify."""
    return f"{n / MiB:.3f} MiB"


def value_parts(ptype: PortType, value: Any) -> tuple[dict, list[np.ndarray], str]:
    meta, arrays = ptype.to_parts(value)
    arrays = [np.ascontiguousarray(a) for a in arrays]
    return meta, arrays, parts_digest(ptype.name, meta, arrays)


def encode_header(ptype_name: str, meta: dict, arrays: list[np.ndarray], digest: str) -> tuple[bytes, list[int]]:
    descs, offsets, off = [], [], 0
    for a in arrays:
        off = (off + ALIGN - 1) // ALIGN * ALIGN
        descs.append({"dtype": a.dtype.str, "shape": list(a.shape), "offset": off, "nbytes": a.nbytes})
        offsets.append(off)
        off += a.nbytes
    header = json_encode({"type": ptype_name, "meta": meta, "arrays": descs, "digest": digest}).encode()
    head = MAGIC + struct.pack("<Q", len(header)) + header
    pad = (-len(head)) % ALIGN
    return head + b"\0" * pad, offsets


def iter_chunks(head: bytes, offsets: list[int], arrays: list[np.ndarray]) -> Iterator[bytes | memoryview]:
    yield head
    pos = 0
    for off, a in zip(offsets, arrays):
        if off > pos:
            yield b"\0" * (off - pos)
        if a.nbytes:
            yield memoryview(a).cast("B")
        pos = off + a.nbytes


def decode_object(buf: bytes | memoryview) -> tuple[str, dict, list[np.ndarray], str]:
    buf = memoryview(buf)
    if bytes(buf[:8]) != MAGIC:
        raise ValueError("not a graphkit object (bad magic)")
    (hlen,) = struct.unpack("<Q", buf[8:16])
    header = json.loads(bytes(buf[16:16 + hlen]))
    base = 16 + hlen
    base += (-base) % ALIGN
    arrays = []
    for d in header["arrays"]:
        dt = np.dtype(d["dtype"])
        n = int(np.prod(d["shape"])) if d["shape"] else 1
        if base + d["offset"] + d["nbytes"] > len(buf):
            raise ValueError("truncated object")
        a = np.frombuffer(buf, dtype=dt, count=n, offset=base + d["offset"]).reshape(d["shape"])
        arrays.append(a)
    return header["type"], header["meta"], arrays, header["digest"]


def check_object(raw: bytes | None, digest: str) -> tuple[str, dict, list[np.ndarray]]:
    """Decode a stored object and check that its content hashes to ``digest``.

    Raises :class:`MissingObject` (``raw`` is None) or :class:`CorruptObject`."""
    if raw is None:
        raise MissingObject(digest, "is missing")
    try:
        tname, meta, arrays, d = decode_object(raw)
        ok = d == digest and parts_digest(tname, meta, arrays) == digest
    except (ValueError, KeyError, TypeError) as e:
        raise CorruptObject(digest, f"cannot be decoded ({e})") from None
    if not ok:
        raise CorruptObject(digest, "does not match its digest")
    return tname, meta, arrays


class DamagedEntry(CacheError):
    """A stored object that is missing or whose bytes do not hash to its name."""

    def __init__(self, digest: str, why: str):
        self.digest, self.why = digest, why
        super().__init__(f"cache object {digest} {why}")


class MissingObject(DamagedEntry):
    pass


class CorruptObject(DamagedEntry):
    pass


#: the one form of a value digest (xxh3-128, lowercase hex): a record's output digest names a
#: file below objects/, so anything else in a record is damage, never a path
DIGEST = re.compile(r"[0-9a-f]{32}")
