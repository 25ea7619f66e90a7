"""The cache store: content-addressed value objects plus key records, in a folder or at an
fsspec URL (``s3://…``).  docs/store.md describes the layout, records, journals, leases and the
trust model.

Modules: :mod:`~graphkit.store.codec` (a value ↔ the bytes of an object),
:mod:`~graphkit.store.records` (the record and journal formats), :mod:`~graphkit.store.fs` (the
file-system interface and its capabilities) with :mod:`~graphkit.store.localfs` (a folder) and
:mod:`~graphkit.store.objectfs` (fsspec), :mod:`~graphkit.store.core` (:class:`Store`: get, put,
locks, commits) and :mod:`~graphkit.store.maintenance` (ls, usage, gc, verify).
"""
from .codec import (ALIGN, MAGIC, CorruptObject, DamagedEntry, MissingObject, check_object, decode_object,
                    encode_header, fmt_size, iter_chunks, object_rel, value_parts)
from .core import Store, check_out_folder
from .localfs import LocalFS
from .objectfs import OPTIONS_ENV, FsspecFS, cache_options, merged_options, parse_cache_option
from .records import KEY_ENV, UNSIGNED, decode_record, encode_record, record_inputs, record_rel

__all__ = ["ALIGN", "MAGIC", "CorruptObject", "DamagedEntry", "MissingObject", "check_object", "decode_object",
           "encode_header", "fmt_size", "iter_chunks", "object_rel", "value_parts", "Store", "check_out_folder",
           "LocalFS", "OPTIONS_ENV", "FsspecFS", "cache_options", "merged_options", "parse_cache_option",
           "KEY_ENV", "UNSIGNED", "decode_record", "encode_record", "record_inputs", "record_rel"]
