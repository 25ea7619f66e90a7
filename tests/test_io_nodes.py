"""LoadImage / SaveImage / LoadMesh / SaveMesh against OpenImageIO, colour-science, trimesh."""
import json

import numpy as np
import OpenImageIO as oiio
import pytest

from conftest import graphkit
from graphkit import run_graph


def read(path):
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    px = inp.read_image(0, 0, 0, spec.nchannels, "float")
    attrs = {a.name: a.value for a in spec.extra_attribs}
    inp.close()
    return np.asarray(px), attrs


def test_astronaut_is_decoded_to_linear(tmp_path, write, engine_registry):
    import colour
    import skimage.data

    g = write("g.yaml", 'graphkit: 1\nnodes:\n  p: {type: LoadImage, params: {path: "builtin:astronaut"}}\n')
    img = run_graph(g, cache=tmp_path / "c", registry=engine_registry).value("p.image")
    ref = colour.models.eotf_sRGB(skimage.data.astronaut() / 255.0)
    assert img.pixels.shape == (512, 512, 3) and img.colorspace == "lin_srgb"
    np.testing.assert_allclose(img.pixels, ref, atol=1e-6)


SAVE = """\
graphkit: 1
name: save
nodes:
  p: {type: LoadImage, params: {path: "builtin:astronaut"}}
  exr: {type: SaveImage, inputs: {image: p.image}, params: {path: sub/a.exr, bits: 32}}
  png: {type: SaveImage, inputs: {image: p.image}, params: {path: a.png, bits: 8}}
  half: {type: SaveImage, inputs: {image: p.image}, params: {path: h.exr}}
outputs: [exr.file, png.file, half.file]
"""


def test_save_round_trip_provenance_and_same_bytes(tmp_path, write):
    import skimage.data

    g = write("g.yaml", SAVE)
    for i in (1, 2):
        r = graphkit("run", g, "--cache", tmp_path / f"c{i}", "--out", tmp_path / f"o{i}")
        assert r.returncode == 0, r.stderr
    for f in ("sub/a.exr", "a.png", "h.exr"):
        assert (tmp_path / "o1" / f).read_bytes() == (tmp_path / "o2" / f).read_bytes(), f
    px, attrs = read(tmp_path / "o1" / "sub" / "a.exr")
    lin, _ = read(tmp_path / "o1" / "h.exr")
    png, _ = read(tmp_path / "o1" / "a.png")
    np.testing.assert_array_equal(np.round(png * 255), skimage.data.astronaut())  # sRGB 8-bit round trip
    np.testing.assert_allclose(lin, px, rtol=1e-3, atol=1e-4)  # half floats
    manifest = json.loads((tmp_path / "o1" / "manifest.json").read_text())
    assert attrs["graphkit:key"] == manifest["nodes"]["exr"]["key"]
    assert attrs["graphkit:graph"] == "save" and len(attrs["graphkit:recipe"]) == 32


def test_mesh_round_trip(tmp_path, write, engine_registry):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=2)
    m.export(tmp_path / "ball.ply")
    g = write("g.yaml", "graphkit: 1\nnodes:\n  m: {type: LoadMesh, params: {path: ball.ply}}\n"
                        "  s: {type: SaveMesh, inputs: {mesh: m.mesh}, params: {path: out.obj}}\n")
    r = run_graph(g, cache=tmp_path / "c", out=tmp_path / "o", registry=engine_registry)
    back = trimesh.load(tmp_path / "o" / "out.obj", force="mesh", process=False)
    np.testing.assert_allclose(back.vertices, m.vertices, atol=1e-6)
    np.testing.assert_array_equal(back.faces, m.faces)
    assert r.value("m.mesh").faces.shape == (320, 3)


def test_bad_mesh_file(tmp_path, write):
    (tmp_path / "bad.ply").write_text("ply\nformat nonsense\n")
    g = write("g.yaml", "graphkit: 1\nnodes:\n  m: {type: LoadMesh, params: {path: bad.ply}}\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    assert r.returncode == 2 and "node 'm' (LoadMesh), port 'path'" in r.stderr and "Traceback" not in r.stderr


def test_contact_sheet(tmp_path, write, engine_registry):
    g = write("g.yaml", """\
graphkit: 1
nodes:
  p: {type: LoadImage, params: {path: "builtin:astronaut"}}
  s: {type: ContactSheet, inputs: {images: [p.image, p.image, p.image]}, params: {labels: [a, b, c], columns: 2, cell_width: 64, gap: 2}}
""")
    sheet = run_graph(g, cache=tmp_path / "c", registry=engine_registry).value("s.image")
    assert sheet.pixels.shape == (2 + 2 * (64 + 22 + 2), 2 + 2 * (64 + 2), 3)
    g2 = write("g2.yaml", g.read_text().replace("labels: [a, b, c]", "labels: [a]"))
    with pytest.raises(Exception, match="1 labels for 3 images"):
        run_graph(g2, cache=tmp_path / "c", registry=engine_registry)
