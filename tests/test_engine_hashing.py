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


def test_errors_name_the_place():
    with pytest.raises(CanonicalError, match=r"^params\.a\.b\[1\]: sets have no canonical order"):
        canonical({"a": {"b": [1, {2}]}})
    with pytest.raises(CanonicalError, match=r"^params\.m\.x: cannot encode a value of type builtins\.object"):
        class M(BaseModel):
            model_config = {"arbitrary_types_allowed": True}
            x: object = None

        canonical({"m": M(x=object())})
    with pytest.raises(CanonicalError, match=r"^params\.d: dict keys must be strings, got int"):
        canonical({"d": {1: 2}})
    with pytest.raises(CanonicalError, match="fail closed"):
        canonical(object())


def test_file_memo_entries(tmp_path):
    import json
    import os

    import graphkit.hashing as h

    p = tmp_path / "f.bin"
    p.write_bytes(b"abc")
    memo = tmp_path / "memo.json"
    h._memo.clear()
    d = file_digest(p, memo)
    import xxhash

    assert d == xxhash.xxh3_128_hexdigest(b"abc")
    st = os.stat(p)
    entry = json.loads(memo.read_text())[str(p)]
    assert entry[0] == [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino] and entry[1] == d
    assert entry[2] == h._memo_check(str(p), entry[0], d)
    assert not list(tmp_path.glob("memo.json.*.tmp"))
    # a memo with one edited, one old-format and one good entry: only the good one is used
    q = tmp_path / "g.bin"
    q.write_bytes(b"q")
    h._memo.clear()
    file_digest(q, memo)
    data = json.loads(memo.read_text())
    data[str(p)][1] = "0" * 32  # edited
    data["/old"] = [[1, 2, 3], "1" * 32]  # written by an older graphkit
    memo.write_text(json.dumps(data))
    h._memo.clear()
    h._load_memo(memo)
    assert str(p) not in h._memo and "/old" not in h._memo and h._memo[str(q)][1] == data[str(q)][1]
    assert file_digest(p, memo) == d
    h._memo.clear()
    memo.write_text("[not a dict")
    h._load_memo(memo)
    assert h._memo == {}


def test_file_memo_hit_does_not_read_the_file(tmp_path, monkeypatch):
    import builtins

    import graphkit.hashing as h

    p = tmp_path / "f.bin"
    p.write_bytes(b"abc" * 1000)
    h._memo.clear()
    d = file_digest(p, tmp_path / "memo.json")
    h._memo.clear()
    real = builtins.open
    monkeypatch.setattr(builtins, "open", lambda f, *a, **k: (_ for _ in ()).throw(AssertionError(f))
                        if str(f) == str(p) else real(f, *a, **k))
    assert file_digest(p, tmp_path / "memo.json") == d  # from the memo file, not the content


def test_subclasses_and_numpy_scalars_encode_as_their_base():
    class I(int):
        pass

    class F(float):
        pass

    class S(str):
        pass

    class D(dict):
        pass

    class L(list):
        pass

    import collections

    T = collections.namedtuple("T", "a b")
    assert canonical(I(3)) == b"i3;" and canonical(F(0.5)) == b"f" + (0.5).hex().encode() + b";"
    assert canonical(S("ab")) == b"s2:ab" and canonical(D(a=1)) == b"d1{s1:ai1;}"
    assert canonical(L([1])) == b"l1[i1;]" and canonical(T(1, 2)) == b"l2[i1;i2;]"
    assert canonical(np.bool_(True)) == b"T" and canonical(np.float64(0.25)) == canonical(0.25)
    assert canonical(Color.RED) == canonical("red")
    assert canonical(np.arange(3)) == b"a" + array_digest(np.arange(3)).encode()
    with pytest.raises(CanonicalError, match="dict keys must be strings"):
        canonical({1: "a", "b": 2})


def test_merge_of_pre_encoded_parts_equals_canonical():
    from graphkit.hashing import canonical_items, canonical_merge

    parts = {"b": "x", "a": [1, 2.5], "c": {"z": None}}
    enc = canonical_items({k: v for k, v in parts.items() if k != "c"})
    assert canonical_merge(enc, {"c": parts["c"]}) == canonical(parts)
    assert canonical_items({"k": "v"}) == {"k": canonical("k") + canonical("v")}


def test_value_digests():
    from graphkit.hashing import meta_bytes, parts_digest

    a = [np.arange(3.0)]
    base = parts_digest("Array", {}, a)
    assert base != parts_digest("Vector", {}, a)
    assert base != parts_digest("Array", {"x": 1}, a)
    assert base != parts_digest("Array", {}, a + [np.zeros(0)])
    assert base != parts_digest("Array", {}, [np.arange(3.0).reshape(3, 1)])
    assert meta_bytes({"b": 1, "a": "é"}) == b'{"a":"\\u00e9","b":1}'
    with pytest.raises(ValueError):
        meta_bytes({"x": float("nan")})
    with pytest.raises(CanonicalError):
        array_digest(np.array([object()]))
    import xxhash

    h = xxhash.xxh3_128()
    h.update(b"Array\0")
    h.update(b"{}\0")
    h.update(b"1;")
    h.update(b"<f8(3,);")
    h.update(np.arange(3.0).tobytes())
    assert base == h.hexdigest()  # the documented layout: type, meta, count, then dtype+shape+bytes


def test_a_model_is_encoded_as_its_class_name_then_its_fields_as_a_dict():
    """The per-class layout _enc keeps for pydantic models gives the bytes of the plain rule,
    written out here: canonical(class name) + canonical({field: value}) (fields sorted by name,
    whatever their declaration order; nested models the same)."""
    from pydantic import BaseModel

    class Inner(BaseModel):
        zeta: int = 2
        alpha: str = "é"

    class Outer(BaseModel):
        b: float = 0.5
        a: Inner = Inner()
        c: list = [1, "x"]

    def plain(m):
        t = type(m)
        return canonical(f"{t.__module__}.{t.__qualname__}") + canonical({k: getattr(m, k) for k in t.model_fields})

    inner = Inner(zeta=7)
    assert canonical(inner) == plain(inner)
    assert canonical(inner).endswith(b"d2{s5:alphas2:\xc3\xa9s4:zetai7;}")
    o = Outer(a=inner)
    want = (canonical(f"{Outer.__module__}.{Outer.__qualname__}") + b"d3{" + canonical("a") + plain(inner)
            + canonical("b") + canonical(0.5) + canonical("c") + canonical([1, "x"]) + b"}")
    assert canonical(o) == want


class _Tone(str, enum.Enum):
    WARM = "warm"


class _Level(enum.IntEnum):
    HIGH = 7


class _Spot(BaseModel):
    x: float = 0.5
    tags: list = []


# Canonical bytes written out by hand from the encoding's grammar (s<utf-8 length>:text,
# f<float.hex()>;, i<int>;, T / F, N, b<length>:bytes, l<n>[...], d<n>{key value ...} with sorted
# string keys, an enum as its value, a model as its class name then its fields as a dict), so
# anyone can check them without graphkit.  A change here changes every cache key.
KNOWN = [
    ("", b"s0:"),
    ("h\u00e9\U0001f600", b"s7:h\xc3\xa9\xf0\x9f\x98\x80"),
    (0, b"i0;"),
    (-12345678901234567890, b"i-12345678901234567890;"),
    (True, b"T"),
    (False, b"F"),
    (None, b"N"),
    (0.1, b"f0x1.999999999999ap-4;"),
    (-0.0, b"f-0x0.0p+0;"),
    (float("inf"), b"finf;"),
    (float("nan"), b"fnan;"),
    (b"\x00ab", b"b3:\x00ab"),
    ([], b"l0[]"),
    ((1, "a"), b"l2[i1;s1:a]"),
    ({"b": 1, "a": [None]}, b"d2{s1:al1[N]s1:bi1;}"),
    (_Tone.WARM, b"s4:warm"),
    (_Level.HIGH, b"i7;"),
    (np.float32(1.5), b"f0x1.8000000000000p+0;"),
    (np.int64(-3), b"i-3;"),
    (_Spot(tags=[1]),
     b"s%d:%s.%sd2{s4:tagsl1[i1;]s1:xf0x1.0000000000000p-1;}"
     % (len(f"{__name__}._Spot"), __name__.encode(), b"_Spot")),
]


def test_canonical_bytes_are_the_written_grammar():
    for value, want in KNOWN:
        assert canonical(value) == want, value


def test_known_key_digests():
    """key_digest is BLAKE2b-128 of the canonical bytes: these digests were recorded before
    the encoder was restructured (issue 25) and stay as they are."""
    import hashlib

    parts = {"node": "Blur", "version": "3", "params": {"sigma": 1.5, "mode": "reflect", "taps": [1, 2, 1]},
             "inputs": {"image": "0" * 32}, "flags": [True, False, None]}
    want = (b"d5{s5:flagsl3[TFN]s6:inputsd1{s5:images32:" + b"0" * 32 + b"}s4:nodes4:Blur"
            b"s6:paramsd3{s4:modes7:reflects5:sigmaf0x1.8000000000000p+0;s4:tapsl3[i1;i2;i1;]}"
            b"s7:versions1:3}")
    assert canonical(parts) == want
    assert key_digest(parts) == hashlib.blake2b(want, digest_size=16).hexdigest() == "b5f2359db09744fa0cb6e064d30f7a94"
