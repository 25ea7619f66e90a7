"""Canonical encoding fails closed; digests see dtype, shape and every byte."""
import enum

import numpy as np
import pytest
from pydantic import BaseModel

from graphkit.errors import CanonicalError
from graphkit.hashing import array_digest, canonical, file_digest, key_digest


def test_canonical_is_order_free_and_type_exact():
    assert canonical({"a": 1, "b": [1.5, "x"]}) == canonical({"b": [1.5, "x"], "a": 1})
    assert canonical(1) != canonical(1.0) != canonical(True)
    assert canonical(0.1) != canonical(float(np.nextafter(0.1, 1.0)))
    assert canonical(float("nan")) == canonical(float("nan"))
    assert canonical((1, 2)) == canonical([1, 2])
    assert canonical("a") != canonical(b"a")


class Color(enum.Enum):
    RED = "red"


class P(BaseModel):
    x: float = 1.0
    c: Color = Color.RED


def test_models_enums_arrays():
    assert canonical(P()) == canonical(P(x=1.0))
    assert canonical(P()) != canonical(P(x=2.0))
    assert canonical(np.float32(1.5)) == canonical(1.5)
    assert canonical(np.arange(3)) != canonical(np.arange(3.0))


@pytest.mark.parametrize("bad", [{1, 2}, object(), lambda: 0, {1: "int key"}, np.array([object()])])
def test_unknown_types_fail_closed(bad):
    with pytest.raises(CanonicalError):
        canonical({"p": bad})


def test_array_digest_sees_dtype_shape_bytes():
    a = np.arange(12, dtype=np.float32)
    assert array_digest(a) == array_digest(a.copy())
    assert array_digest(a) != array_digest(a.reshape(3, 4))
    assert array_digest(a) != array_digest(a.astype(np.float64))
    b = a.copy()
    b[7] = np.nextafter(b[7], 100)
    assert array_digest(a) != array_digest(b)
    assert array_digest(a.reshape(3, 4).T) == array_digest(np.ascontiguousarray(a.reshape(3, 4).T))


def test_file_digest_memo(tmp_path):
    p = tmp_path / "f.bin"
    p.write_bytes(b"x" * 1000)
    memo = tmp_path / "memo.json"
    d1 = file_digest(p, memo)
    assert memo.exists() and file_digest(p, memo) == d1
    p.write_bytes(b"y" * 1001)
    assert file_digest(p, memo) != d1
    assert key_digest({"a": d1}) != key_digest({"a": file_digest(p, memo)})


def test_split_key_equals_plain_key(tmp_path, engine_registry):
    """The per-node pre-encoded key parts give exactly key_digest(all parts)."""
    from graphkit.graphfile import load_graph
    from graphkit.runner import Session
    from graphkit.store import Store

    g = tmp_path / "g.yaml"
    g.write_text("graphkit: 1\nnodes:\n  c: {type: Const, params: {value: 2}}\n  d: {type: Add, inputs: {a: c.out}}\n")
    s = Session(load_graph(g, engine_registry, {}), engine_registry, Store(tmp_path / "c"))
    key, parts = s.key(s.graph.nodes["d"], {"a": "0" * 32})
    assert key == key_digest(parts)
    assert key != s.key(s.graph.nodes["d"], {"a": "1" * 32})[0]
