"""Every part of a cache key is guarded (issue 10, mutation testing): for each part there is a
pair of nodes that differ only in that part and must get different keys, and the key itself is
checked against the documented recipe, BLAKE2b-128 over the canonical encoding, written out here
byte by byte (not with the engine's encoder).  Dropping or renaming any part fails a test."""
import hashlib

import numpy as np
import pytest
from pydantic import BaseModel

import enginenodes
import graphkit.keys as keys
from graphkit import Backend, Node
from graphkit.graphfile import load_graph
from graphkit.hashing import canonical
from graphkit.registry import discover
from graphkit.runner import Session
from graphkit.store import Store

KEY_PARTS = {"recipe", "node_type", "node_version", "backend", "backend_version", "params", "inputs",
             "files", "recipe_digest"}


class ConstV2(enginenodes.Const):
    """enginenodes.Const with another version (registered as type Const: the registry refuses a
    class whose type_name is not its key)."""

    type_name = "Const"
    version = "2"


class Prov(Node):
    """A node that embeds provenance (its key then holds the recipe digest)."""

    from graphkit import Array

    inputs = {"x": Array}
    outputs = {"out": Array}
    provenance = True

    def compute(self, x):
        return x


class AltConst(Backend):
    node = "Const"
    name = "alt"
    version = "1"

    @classmethod
    def available(cls):
        return True

    def compute(self):
        return np.full(self.params.size, self.params.value, np.float64)


class AltConst2(AltConst):
    version = "2"


def registry(const=enginenodes.Const, alt=AltConst):
    reg = discover()
    reg.add_provider("nodes", "tests", enginenodes)
    if const is not enginenodes.Const:
        reg.nodes.pop("Const")
        reg.add_node("Const", "tests-v2", const)
    reg.add_node("Prov", "tests", Prov)
    reg.add_backend("Const", "alt", "tests", alt)
    import storenodes

    reg.add_provider("nodes", "tests-store", storenodes)
    return reg


def key_of(tmp_path, text, node, reg=None, inputs=None):
    p = tmp_path / "g.yaml"
    p.write_text(text)
    reg = reg or registry()
    s = Session(load_graph(p, reg, {}), reg, Store(tmp_path / "c"))
    return s.key(s.graph.nodes[node], inputs or {})


CONST = "graphkit: 1\nnodes:\n  a: {type: Const, params: {value: 1}}\n"


# -- the canonical encoding, spelled out -----------------------------------------------------

def test_canonical_encoding_is_the_documented_one():
    assert canonical("ab") == b"s2:ab"
    assert canonical("é") == b"s2:\xc3\xa9"  # length in UTF-8 bytes
    assert canonical(12) == b"i12;" and canonical(-3) == b"i-3;"
    assert canonical(1.5) == b"f0x1.8000000000000p+0;"
    assert canonical(True) == b"T" and canonical(False) == b"F" and canonical(None) == b"N"
    assert canonical([1, "x"]) == b"l2[i1;s1:x]" == canonical((1, "x"))
    assert canonical({"b": 1, "a": None}) == b"d2{s1:aNs1:bi1;}"
    assert canonical(b"\x00\x01") == b"b2:\x00\x01"
    assert canonical(np.float32(2.0)) == canonical(2.0) and canonical(np.int64(5)) == b"i5;"

    class P(BaseModel):
        y: int = 2
        x: str = "q"

    name = f"{P.__module__}.{P.__qualname__}".encode()
    assert canonical(P()) == b"s%d:" % len(name) + name + b"d2{s1:xs1:qs1:yi2;}"


def test_key_is_blake2b_128_of_the_documented_parts(tmp_path):
    reg = registry()
    key, parts = key_of(tmp_path, "graphkit: 1\nnodes:\n  a: {type: Const, params: {value: 1}}\n"
                                  "  b: {type: Add, inputs: {a: a.out}, params: {offset: 2}}\n",
                        "b", reg, {"a": "ab" * 16})
    assert set(parts) == {"recipe", "node_type", "node_version", "backend", "backend_version", "params", "inputs"}
    pm = parts["params"]
    name = f"{type(pm).__module__}.{type(pm).__qualname__}".encode()
    params = b"s%d:" % len(name) + name + b"d1{s6:offsetf" + (2.0).hex().encode() + b";}"
    ver = enginenodes.Add.version.encode()
    expect = (b"d7{" + b"s7:backends5:numpy" + b"s15:backend_versions%d:%s" % (len(ver), ver)
              + b"s6:inputsd1{s1:as32:" + b"ab" * 16 + b"}"
              + b"s9:node_types3:Add" + b"s12:node_versions%d:%s" % (len(ver), ver)
              + b"s6:params" + params + b"s6:recipes1:" + keys.RECIPE_VERSION.encode() + b"}")
    assert key == hashlib.blake2b(expect, digest_size=16).hexdigest()


# -- each part, on its own, changes the key --------------------------------------------------

def test_recipe_version_is_in_the_key(tmp_path, monkeypatch):
    k1 = key_of(tmp_path, CONST, "a")[0]
    monkeypatch.setattr(keys, "RECIPE_VERSION", keys.RECIPE_VERSION + "x")
    assert key_of(tmp_path, CONST, "a")[0] != k1


def test_node_type_is_in_the_key(tmp_path):
    reg = registry()
    reg.add_node("Konst", "tests", type("Konst", (enginenodes.Const,), {"__doc__": "a Const by another name"}))
    assert key_of(tmp_path, CONST, "a", reg)[0] != key_of(tmp_path, CONST.replace("Const", "Konst"), "a", reg)[0]


def test_node_version_is_in_the_key(tmp_path):
    assert ConstV2.version != enginenodes.Const.version
    assert key_of(tmp_path, CONST, "a", registry())[0] != key_of(tmp_path, CONST, "a", registry(ConstV2))[0]


def test_backend_name_is_in_the_key(tmp_path):
    pinned = CONST.replace("value: 1}}", "value: 1}, backend: alt}")
    k_numpy, p_numpy = key_of(tmp_path, CONST, "a")
    k_alt, p_alt = key_of(tmp_path, pinned, "a")
    assert (p_numpy["backend"], p_alt["backend"]) == ("numpy", "alt") and k_numpy != k_alt


def test_backend_version_is_in_the_key(tmp_path):
    pinned = CONST.replace("value: 1}}", "value: 1}, backend: alt}")
    assert key_of(tmp_path, pinned, "a", registry(alt=AltConst))[0] != key_of(tmp_path, pinned, "a", registry(alt=AltConst2))[0]


def test_params_are_in_the_key(tmp_path):
    assert key_of(tmp_path, CONST, "a")[0] != key_of(tmp_path, CONST.replace("value: 1", "value: 2"), "a")[0]


def test_input_digests_are_in_the_key(tmp_path):
    g = CONST + "  b: {type: Add, inputs: {a: a.out}}\n"
    assert key_of(tmp_path, g, "b", inputs={"a": "0" * 32})[0] != key_of(tmp_path, g, "b", inputs={"a": "1" * 32})[0]


def test_input_file_content_is_in_the_key(tmp_path):
    import graphkit.hashing as hashing

    f = tmp_path / "in.bin"
    g = "graphkit: 1\nnodes:\n  r: {type: ReadBytes, params: {path: in.bin}}\n"
    f.write_bytes(b"one")
    k1, parts = key_of(tmp_path, g, "r")
    assert "files" in parts
    f.write_bytes(b"two")
    hashing._memo.clear()
    assert key_of(tmp_path, g, "r")[0] != k1


def test_recipe_digest_is_in_the_key_of_provenance_nodes(tmp_path):
    """`label` changes a's recipe but not its bytes: Prov's input digest is the same, and only
    the recipe digest can tell the two keys apart."""
    g = "graphkit: 1\nnodes:\n  a: {type: Const, params: {label: one}}\n  p: {type: Prov, inputs: {x: a.out}}\n"
    k1, parts = key_of(tmp_path, g, "p", inputs={"x": "0" * 32})
    k2, _ = key_of(tmp_path, g.replace("one", "two"), "p", inputs={"x": "0" * 32})
    assert "recipe_digest" in parts and k1 != k2


def test_the_parts_above_are_all_there_are(tmp_path):
    """A new key part needs a guard here: the union of parts seen above is KEY_PARTS."""
    (tmp_path / "x").write_bytes(b"x")
    seen = set(key_of(tmp_path, "graphkit: 1\nnodes:\n  r: {type: ReadBytes, params: {path: x}}\n", "r")[1])
    seen |= set(key_of(tmp_path, "graphkit: 1\nnodes:\n  a: {type: Const}\n  p: {type: Prov, inputs: {x: a.out}}\n",
                       "p", inputs={"x": "0" * 32})[1])
    assert seen == KEY_PARTS


@pytest.mark.parametrize("drop", sorted(KEY_PARTS - {"files", "recipe_digest"}))
def test_dropping_a_part_changes_the_key(tmp_path, drop):
    """The key depends on every part it is given (the split, pre-encoded key path included)."""
    from graphkit.hashing import key_digest

    key, parts = key_of(tmp_path, CONST + "  b: {type: Add, inputs: {a: a.out}}\n", "b", inputs={"a": "0" * 32})
    assert key == key_digest(parts)
    assert key_digest({k: v for k, v in parts.items() if k != drop}) != key
