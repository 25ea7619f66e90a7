"""Studio pieces without a browser: graph text edits, preview tone mapping, schema controls."""
from __future__ import annotations

import io

import numpy as np
import pytest
import yaml

from conftest import ROOT


def test_edits_change_only_the_value_and_keep_comments():
    from graphkit.studio.yamldoc import YamlDoc

    text = (ROOT / "graphs" / "face_relight.yaml").read_text()
    d = YamlDoc(text).with_params([(None, "flash_azimuth", 20.0), ("l_left60", "azimuth_deg", -50.0),
                                    ("face", "min_score", 0.3), ("sheet", "labels", ["a", "b: c"]),
                                    ("save_over", "bits", 32)])
    new = d.text
    assert "  flash_azimuth: 20.0     # degrees, + = towards the image's right\n" in new  # comment column kept
    assert "l_left60: {type: MakeLight, inputs: {camera: face.camera}, params: {azimuth_deg: -50.0, elevation_deg: 10.0}}" in new
    assert "    inputs: {image: photo.image}\n    params: {min_score: 0.3}\n" in new  # a new params mapping
    assert "params: {path: relit/overexposed.exr, bits: 32}}" in new  # a key added to a flow mapping
    data = yaml.safe_load(new)
    assert data["nodes"]["sheet"]["params"]["labels"] == ["a", "b: c"]
    assert data["params"]["flash_azimuth"] == 20.0
    # everything else is the same text, line for line
    import difflib

    diff = [x for x in difflib.ndiff(text.splitlines(), new.splitlines()) if x[:1] in "+-"]
    assert len([x for x in diff if x[0] == "-"]) == 5 and len([x for x in diff if x[0] == "+"]) == 5, diff


def test_block_values_and_block_mappings():
    from graphkit.studio.yamldoc import YamlDoc

    t = "nodes:\n  a:\n    type: X\n    params:\n      labels:\n        - a\n        - b   # c\n      columns: 4\n  b:\n    type: Y\n"
    d = YamlDoc(t).with_params([("a", "labels", [1, 2]), ("b", "k", 1), ("a", "new", True)])
    assert yaml.safe_load(d.text) == {"nodes": {"a": {"type": "X", "params": {"labels": [1, 2], "columns": 4, "new": True}},
                                                "b": {"type": "Y", "params": {"k": 1}}}}
    with pytest.raises(KeyError):
        YamlDoc(t).with_params([("zzz", "k", 1)])


@pytest.mark.parametrize("exposure", [0.0, 1.0, -2.0])
def test_preview_is_srgb_of_the_exposed_linear_value(exposure):
    """Against colour-science's sRGB encoding (IEC 61966-2-1)."""
    import colour

    from graphkit.studio.imaging import display_rgb

    lin = np.linspace(0, 1.2, 1000, dtype=np.float32).reshape(10, 100, 1).repeat(3, 2)
    got = display_rgb(lin, exposure).astype(int)
    ref = np.round(np.clip(colour.cctf_encoding(np.clip(lin.astype(np.float64) * 2 ** exposure, 0, 1),
                                                function="sRGB"), 0, 1) * 255).astype(int)
    assert np.abs(got - ref).max() <= 1
    assert (got == ref).mean() > 0.97


@pytest.mark.parametrize("level", [0, 1])
def test_preview_png_decodes_to_the_display_pixels(level):
    """Both PNG settings (0: uncompressed, for the loopback; 1: compressed) decode (Pillow)
    to the same 8-bit sRGB pixels; NaN and -inf show black, +inf white."""
    from PIL import Image as PILImage

    from graphkit import Image
    from graphkit.studio.imaging import display_rgb, preview_png

    px = np.random.default_rng(3).uniform(-0.1, 1.3, (37, 53, 3)).astype(np.float32)
    px[0, 0], px[0, 1] = [np.nan, -np.inf, np.inf], [0.0, 1.0, 0.5]
    data = preview_png("Image", Image(px), 0.0, 0, level)
    got = np.asarray(PILImage.open(io.BytesIO(data)).convert("RGB"))
    assert np.array_equal(got, display_rgb(px))
    assert got[0, 0].tolist() == [0, 0, 255] and got[0, 1].tolist() == [0, 255, 188]


def test_graph_param_takes_the_schema_of_the_node_param_it_feeds():
    from graphkit.registry import default_registry
    from graphkit.studio.core import Studio

    st = Studio(ROOT / "graphs" / "face_relight.yaml", cache="memory://studio-units", out=None,
                registry=default_registry(), autorun=False)
    try:
        s = st.state()
        az = s["graph_param_schema"]["flash_azimuth"]
        assert az["used_by"] == "flash.azimuth_deg"
        inner = az["schema"]["anyOf"][0]
        assert (inner["minimum"], inner["maximum"]) == (-180, 180)
        assert s["preview"] == ["sheet", "image"]
        assert not s["errors"] and s["graph"]["valid"]
    finally:
        st.close()


def test_layout_of_a_graph_deeper_than_the_recursion_limit():
    """The layered layout walks the graph with an explicit stack: a 5000-node chain listed last
    node first (each node's source not laid out yet) opens; a cycle is broken as before."""
    from graphkit.studio.state import _layout

    n = 5000
    deps = {f"n{i}": [f"n{i - 1}"] if i else [] for i in reversed(range(n))}
    pos = _layout(deps)
    assert pos["n0"] == (0, 0) and pos[f"n{n - 1}"] == (n - 1, 0)
    assert _layout({"a": ["b"], "b": ["a"], "c": ["c", "x"]}) == {"a": (2, 0), "b": (1, 0), "c": (1, 1)}
