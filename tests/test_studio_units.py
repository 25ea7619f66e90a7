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


# -- the node editor's edits (yamldoc.EDITS through Studio.edit) ------------------------------------

def _studio(tmp_path, text, name="g.yaml"):
    from graphkit.studio.core import Studio

    p = tmp_path / name
    p.write_text(text)
    return Studio(p, cache=str(tmp_path / "cache"), autorun=False)


def test_structural_edits_keep_the_text_of_untouched_nodes():
    import difflib

    from graphkit.studio.yamldoc import YamlDoc

    text = (ROOT / "graphs" / "quickstart.yaml").read_text()
    new = YamlDoc(text).with_edits([
        {"op": "add_node", "name": "blur2", "type": "Blur", "params": {"sigma_px": 2.0}},
        {"op": "set_input", "node": "blur2", "port": "image", "source": "photo.image"},
        {"op": "rename_node", "name": "smooth", "new": "soft"},
        {"op": "remove_node", "name": "save_photo"}]).text
    data = yaml.safe_load(new)
    assert list(data["nodes"]) == ["photo", "soft", "detail", "sheet", "save_detail", "save_sheet", "blur2"]
    assert data["nodes"]["detail"]["inputs"] == {"a": "photo.image", "b": "soft.image"}
    assert data["nodes"]["sheet"]["inputs"]["images"] == ["photo.image", "soft.image", "detail.ratio"]
    assert data["nodes"]["blur2"] == {"type": "Blur", "params": {"sigma_px": 2.0}, "inputs": {"image": "photo.image"}}
    assert "photo" not in data["outputs"]  # the removed writer's output went with it
    assert "  sigma: 6.0        # blur of the smoothed copy (pixels): --set sigma=12\n" in new
    changed = [x for x in difflib.ndiff(text.splitlines(), new.splitlines()) if x[:1] in "+-"]
    # the renamed node's key and the 2 lines referring to it, the removed node (4 lines) and its output, the added node
    assert len([x for x in changed if x[0] == "-"]) == 3 + 4 + 1, changed
    assert len([x for x in changed if x[0] == "+"]) == 3 + 1, changed


def test_an_edit_that_brings_a_new_error_is_refused_with_the_loaders_message(tmp_path):
    s = _studio(tmp_path, "graphkit: 1\nname: t\n# kept\nnodes: {}\n")
    try:
        assert s.edit([{"op": "add_node", "name": "a", "type": "LoadImage", "params": {"path": "builtin:astronaut"}}])["ok"]
        assert s.edit([{"op": "add_node", "name": "w", "type": "SaveImage"}])["ok"]  # unset path: unfinished, not refused
        assert s.edit([{"op": "add_node", "name": "b", "type": "Blur"}])["ok"]
        text = s.doc.text
        r = s.edit([{"op": "set_input", "node": "b", "port": "image", "source": "w.file"}])
        assert not r["ok"] and r["errors"][0]["message"] == "node 'b', input 'image' takes Image but w.file gives File"
        r = s.edit([{"op": "set_input", "node": "b", "port": "image", "source": "a.nope"}])
        assert not r["ok"] and "has no output port 'nope'" in r["errors"][0]["message"]
        r = s.edit([{"op": "add_node", "name": "c", "type": "Blur", "params": {"sigma_px": -1}}])
        assert not r["ok"] and "sigma_px" in r["errors"][0]["message"]  # out of its declared range
        assert s.doc.text == text  # nothing applied
        assert s.edit([{"op": "set_input", "node": "b", "port": "image", "source": "a.image"}])["ok"]
        s.undo()
        assert s.doc.text == text
        s.undo(redo=True)
        assert "inputs: {image: a.image}" in s.doc.text and "# kept" in s.doc.text
    finally:
        s.close()


@pytest.mark.parametrize("edit", [
    {"op": "add_node", "name": "x", "type": "!!python/object/apply:os.system"},
    {"op": "add_node", "name": "x: !!python/name:os.system\n  y", "type": "Blur"},
    {"op": "rename_node", "name": "a", "new": "!!python/object/apply:os.system ['true']"},
    {"op": "set_input", "node": "a", "port": "image", "source": "!!python/name:os.system"},
    {"op": "add_node", "name": "x", "type": "Blur", "params": {"sigma_px": "!!python/object/apply:os.system ['true']"}},
])
def test_nothing_typed_puts_code_into_the_graph_file(tmp_path, edit):
    from graphkit.graphfile import parse_yaml

    s = _studio(tmp_path, "graphkit: 1\nname: t\nnodes:\n  a: {type: LoadImage, params: {path: 'builtin:astronaut'}}\n")
    try:
        r = s.edit([edit])
        assert not r["ok"]
        assert "!!" not in s.doc.text
        assert not parse_yaml(s.doc.text, "g").diags
    finally:
        s.close()
    # and the loader refuses a tag however it got into a file
    from graphkit.errors import GraphError
    from graphkit.graphfile import load_graph
    from graphkit.registry import default_registry

    p = tmp_path / "tagged.yaml"
    p.write_text("graphkit: 1\nname: t\nnodes:\n  a: !!python/object/apply:os.system ['true']\n")
    with pytest.raises(GraphError):
        load_graph(p, default_registry())


def test_a_missing_node_type_is_kept_on_save_and_saves_stay_in_the_graphs_folder(tmp_path):
    from graphkit.errors import UsageError

    text = ("graphkit: 1\nname: t\nnodes:\n  a: {type: LoadImage, params: {path: 'builtin:astronaut'}}\n"
            "  p: {type: FromAnUninstalledPlugin, inputs: {image: a.image}, params: {strength: 0.5, mode: [1, 2]}}\n")
    s = _studio(tmp_path, text)
    try:
        st = s.state()
        p = next(n for n in st["nodes"] if n["name"] == "p")
        assert p["missing"] and p["raw_params"] == {"strength": 0.5, "mode": [1, 2]} and p["inputs"] == [["image", "a", "image"]]
        assert s.edit([{"op": "add_node", "name": "b", "type": "Blur", "params": {"sigma_px": 2.0}}])["ok"]
        assert s.edit([{"op": "set_input", "node": "b", "port": "image", "source": "a.image"}])["ok"]
        s.save_as("saved.yaml")
        saved = yaml.safe_load((tmp_path / "saved.yaml").read_text())
        assert saved["nodes"]["p"] == {"type": "FromAnUninstalledPlugin", "inputs": {"image": "a.image"},
                                       "params": {"strength": 0.5, "mode": [1, 2]}}
        for outside in ["../out.yaml", str(tmp_path.parent / "out.yaml"), "sub/../../out.yaml"]:
            with pytest.raises(UsageError, match="only into the graph's folder"):
                s.save_as(outside)
        assert not (tmp_path.parent / "out.yaml").exists()
    finally:
        s.close()


def test_vendored_editor_libraries_match_their_checksums():
    """static/vendor/ holds what SHA256SUMS lists (`make vendor-studio` writes both), each with
    its licence, and the page loads those versions (ELK from its layout worker)."""
    import hashlib

    vendor = ROOT / "graphkit" / "studio" / "static" / "vendor"
    sums = dict(reversed(line.split("  ", 1)) for line in (vendor / "SHA256SUMS").read_text().splitlines())
    files = sorted(str(p.relative_to(vendor)) for p in vendor.rglob("*") if p.is_file() and p.name != "SHA256SUMS")
    assert sorted(k.removeprefix("./") for k in sums if k.startswith("./")) == files
    for f in files:
        assert hashlib.sha256((vendor / f).read_bytes()).hexdigest() == sums["./" + f], f
    for d in {f.split("/")[0] for f in files}:
        assert any((vendor / d / n).exists() for n in ("LICENSE", "LICENSE.md")), d
        static = ROOT / "graphkit" / "studio" / "static"
        assert any(f"/static/vendor/{d}/" in (static / page).read_text() for page in ("index.html", "elk_worker.js")), d
