"""Cache keys: the parts that make a node's key, and the key of those parts.

key = BLAKE2b-128(canonical(parts)), parts = recipe version, node type and version, backend name
and version, params, input value digests, input-file digests and, for nodes that embed
provenance, the recipe digest (see README "How the cache works").  Every part is guarded by a
test that fails when it is dropped (tests/test_engine_keyparts.py).
"""
from __future__ import annotations

import hashlib

from .hashing import RECIPE_VERSION, canonical_items, canonical_merge


def static_parts(node_type: str, node_version: str, backend: str, backend_version: str, params,
                 files: dict[str, str] | None = None, recipe_digest: str | None = None) -> dict:
    """The key parts of a node that do not depend on its input values."""
    parts = {
        "recipe": RECIPE_VERSION,
        "node_type": node_type,
        "node_version": node_version,
        "backend": backend,
        "backend_version": backend_version,
        "params": params,
    }
    if files:
        parts["files"] = files
    if recipe_digest is not None:
        parts["recipe_digest"] = recipe_digest
    return parts


def encode_static(parts: dict) -> dict[str, bytes]:
    """The canonical encoding of each static part (computed once per node)."""
    return canonical_items(parts)


def node_key(static: dict, encoded: dict[str, bytes], input_digests: dict) -> tuple[str, dict]:
    """(key, all parts) given the static parts, their encoding and the input digests."""
    inputs = {"inputs": dict(input_digests)}  # (canonical sorts the ports)
    key = hashlib.blake2b(canonical_merge(encoded, inputs), digest_size=16).hexdigest()
    return key, {**static, **inputs}
