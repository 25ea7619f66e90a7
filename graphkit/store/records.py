"""The record and journal formats: what a cache key maps to, and how a run's records are kept.

A **record** is ``GKREC1 <xxh3-128 of the body>[ <HMAC>]\n<body>``, its body the JSON of the
key, the key parts (for explain) and each output's value digest.  The check line catches damage
and edits; the body names its own key, so a record copied under another key is caught; an output
digest that is not the exact hex form is damage, never a path.  With ``GRAPHKIT_CACHE_KEY`` set,
a record must also carry an HMAC-SHA256 only a run holding that key can make.

A **journal** holds the records one run wrote, one after another: a header line
``GKJRN1 <32-hex id>\n``, then frames ``\0GKJF <key> <length>\n<record>``.  On a folder,
``keys/12/1234….json`` is then a hard link to the journal (see graphkit.store.localfs).
"""
from __future__ import annotations

import hashlib
import hmac
import json
import os
import re

import xxhash

from .codec import DIGEST, json_encode

RECORD_MAGIC = b"GKREC1 "


def record_rel(key: str) -> str:
    """Where the record of ``key`` is, below the cache root."""
    return f"keys/{key[:2]}/{key}.json"


def key_of(rel: str) -> str:
    """The key whose record is at ``rel`` (see record_rel)."""
    return rel.rsplit("/", 1)[-1].removesuffix(".json")
#: GRAPHKIT_CACHE_KEY: a secret shared by the runs allowed to write records (see ``record_mac``)
KEY_ENV = "GRAPHKIT_CACHE_KEY"


def cache_key() -> bytes | None:
    """The keyed check's secret (GRAPHKIT_CACHE_KEY), or None when records carry no MAC."""
    k = os.environ.get(KEY_ENV)
    return k.encode() if k else None


def record_mac(body: bytes, secret: bytes) -> bytes:
    """The keyed check of a record body: HMAC-SHA256 with the cache key, in hex."""
    return hmac.new(secret, body, hashlib.sha256).hexdigest().encode()


def encode_record(record: dict, secret: bytes | None = None) -> bytes:
    """``GKREC1 <xxh3-128 of the body>[ <HMAC of the body>]\n<body>``: the MAC only with a key."""
    body = json_encode(record).encode()
    mac = b" " + record_mac(body, secret) if secret else b""
    return RECORD_MAGIC + xxhash.xxh3_128_hexdigest(body).encode() + mac + b"\n" + body


UNSIGNED = f"is not signed with this run's {KEY_ENV} (written by a run without the key, or forged)"


def decode_record(raw: bytes, key: str, secret: bytes | None = None) -> tuple[dict | None, str | None]:
    """(record, None) or (None, why it cannot be trusted).  With ``secret`` (the cache key) a
    record must also carry the MAC only a run holding that key can make."""
    if not raw.startswith(RECORD_MAGIC):
        return None, "has no integrity line (damaged)"
    nl = raw.find(b"\n")
    check, body = raw[len(RECORD_MAGIC):nl], raw[nl + 1:]
    check, _, mac = check.partition(b" ")
    if nl < 0 or xxhash.xxh3_128_hexdigest(body).encode() != check:
        return None, "does not match its check line (damaged or edited)"
    if secret and not hmac.compare_digest(mac, record_mac(body, secret)):
        return None, UNSIGNED
    try:
        rec = json.loads(body)
        outs = rec["outputs"]
        if rec["key"] != key:
            return None, f"belongs to key {str(rec['key'])[:16]} (a record moved or copied)"
        for o in outs.values():
            if type(o["digest"]) is not str or not DIGEST.fullmatch(o["digest"]):
                return None, f"names an output digest that is not one ({str(o['digest'])[:40]!r}: damaged or forged)"
    except (ValueError, KeyError, TypeError, AttributeError):
        return None, "is not a valid record"
    return rec, None


# ---------------------------------------------------------------------------------------------
# journals: the records of one run in one file

JOURNAL_MAGIC = b"GKJRN1 "
JOURNAL_HEAD = len(JOURNAL_MAGIC) + 32 + 1  # the magic, a 32-hex id, a newline
FRAME = b"\0GKJF "
NOT_IN_JOURNAL = "is not in the journal it links to (damaged)"


def is_journal(head: bytes | memoryview) -> bool:
    """Whether a file starting with ``head`` is a journal (its header: magic, id, newline)."""
    return len(head) >= JOURNAL_HEAD and bytes(head[:len(JOURNAL_MAGIC)]) == JOURNAL_MAGIC \
        and head[JOURNAL_HEAD - 1] == 10


_FRAME_HEAD = re.compile(rb"\0GKJF ([0-9A-Za-z]{1,64}) ([0-9]{1,12})\n")


def parse_frames(buf: bytes | bytearray, pos: int, frames: dict[str, tuple[int, int]]) -> int:
    """Index the whole frames of a journal from ``pos`` (key -> (start, end) of its record; a
    later frame of a key replaces an earlier one); returns the end of the last whole frame, where
    the next call starts.  A record never holds a NUL byte (its JSON is ASCII with escapes), so
    every NUL + "GKJF " starts a frame: a damaged stretch is skipped, and the frames after it are
    still found (a false start inside damage only names a record that then fails its checks)."""
    n = len(buf)
    for m in _FRAME_HEAD.finditer(buf, pos):
        start = m.end()
        end = start + int(m.group(2))
        if end > n:  # torn (a killed run) or still being written
            break
        frames[m.group(1).decode()] = (start, end)
        pos = end
    return pos


def journal_record(buf: bytes, key: str) -> bytes | None:
    """The record of ``key`` in a whole journal read as bytes (None: not in it)."""
    frames: dict[str, tuple[int, int]] = {}
    parse_frames(buf, JOURNAL_HEAD, frames)
    span = frames.get(key)
    return None if span is None else bytes(buf[span[0]:span[1]])


def record_bytes(raw: bytes | None, key: str) -> tuple[bytes | None, str | None]:
    """(the record of ``key`` in ``raw``, what its key's file holds: the file itself, or its frame
    when the file is a journal; why it is not there, when it is a journal without it)."""
    if raw is not None and is_journal(raw[:JOURNAL_HEAD]):
        raw = journal_record(raw, key)
        return raw, (NOT_IN_JOURNAL if raw is None else None)
    return raw, None


class JournalView:
    """What one process has read of one journal: its bytes so far and where each key's frame is."""

    __slots__ = ("head", "buf", "parsed", "frames")

    def __init__(self, head: bytes):
        self.head = head
        self.buf = bytearray(head)
        self.parsed = JOURNAL_HEAD
        self.frames: dict[str, tuple[int, int]] = {}

    def extend(self, data: bytes) -> None:
        self.buf += data
        self.parsed = parse_frames(self.buf, self.parsed, self.frames)

    def record(self, key: str) -> bytearray | None:
        span = self.frames.get(key)
        return None if span is None else self.buf[span[0]:span[1]]


def encode_frame(key: str, raw: bytes) -> bytes:
    """The frame that holds record ``raw`` of ``key`` in a journal."""
    return b"%s%s %d\n" % (FRAME, key.encode(), len(raw)) + raw


def output_digests(rec: dict) -> set[str]:
    """The value digests a record's outputs name."""
    return {o["digest"] for o in rec.get("outputs", {}).values()}


def record_inputs(rec: dict) -> list[str]:
    """The input value digests a record was computed from."""
    out = []
    for v in (rec.get("parts") or {}).get("inputs", {}).values():
        out.extend(v if isinstance(v, list) else [v])
    return [d for d in out if isinstance(d, str)]
