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


# --- issue 10: half-float range, masks, scalars, one output-name rule, builtin:, channels -------

def write_float_exr(path, px):
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(px.shape[1], px.shape[0], px.shape[2], "float"))
    out.write_image(np.ascontiguousarray(px, np.float32))
    out.close()


def big_values():
    px = np.full((6, 5, 3), 0.5, np.float32)
    px[1, 2, 0], px[4, 4, 2], px[0, 0, 1] = 1.0e5, 3.0e6, -7.0e4  # finite, beyond half's 65504
    return px


OVER = """\
graphkit: 1
nodes:
  p: {{type: LoadImage, params: {{path: big.exr}}}}
  s: {{type: SaveImage, inputs: {{image: p.image}}, params: {{path: o.exr{extra}}}}}
  back: {{type: LoadImage, params: {{path: {back}}}}}
outputs: [s.file]
"""


def test_half_exr_refuses_values_it_would_turn_into_inf(tmp_path, write):
    write_float_exr(tmp_path / "big.exr", big_values())
    g = write("g.yaml", OVER.format(extra="", back="big.exr"))
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "node 's' (SaveImage), port 'image'" in r.stderr
    assert "3 values exceed the largest half-float EXR (bits: 16) value 65504 (largest 3e+06)" in r.stderr
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.mark.parametrize("mode", ["clamp", "float32", "bits32"])
def test_half_overflow_clamp_or_float_then_load_back(tmp_path, write, engine_registry, mode):
    src = big_values()
    write_float_exr(tmp_path / "big.exr", src)
    extra = {"clamp": ", overflow: clamp", "float32": ", overflow: float32", "bits32": ", bits: 32"}[mode]
    r = run_graph(write("g.yaml", OVER.format(extra=extra, back="big.exr")), cache=tmp_path / "c", out=tmp_path / "o",
                  registry=engine_registry)
    assert r.files
    inp = oiio.ImageInput.open(str(tmp_path / "o" / "o.exr"))
    fmt = str(inp.spec().format)
    inp.close()
    assert fmt == ("half" if mode == "clamp" else "float")
    # LoadImage reads back what was written (before: it refused the file, 3 Inf values)
    g2 = write("back.yaml", "graphkit: 1\nnodes:\n  b: {type: LoadImage, params: {path: o/o.exr}}\n")
    back = run_graph(g2, cache=tmp_path / "c", registry=engine_registry).value("b.image").pixels
    want = np.clip(src, -65504, 65504) if mode == "clamp" else src
    np.testing.assert_array_equal(back[src != 0.5], want[src != 0.5])
    assert np.isfinite(back).all()


def test_mask_saved_as_a_one_channel_image(tmp_path, write, engine_registry):
    import cv2

    g = write("g.yaml", """\
graphkit: 1
nodes:
  mesh: {type: LoadMesh, params: {path: "builtin:sample_capture/mesh.ply"}}
  cam: {type: LoadCameraJson, params: {path: "builtin:sample_capture/camera.json"}}
  m: {type: MeshMask, inputs: {mesh: mesh.mesh, camera: cam.camera}}
  exr: {type: SaveImage, inputs: {mask: m.mask}, params: {path: m.exr, bits: 32}}
  png: {type: SaveImage, inputs: {mask: m.mask}, params: {path: m.png, bits: 16}}
outputs: [exr.file, png.file]
""")
    r = run_graph(g, cache=tmp_path / "c", out=tmp_path / "o", registry=engine_registry)
    alpha = r.value("m.mask").alpha
    exr, _ = read(tmp_path / "o" / "m.exr")
    assert exr.shape == alpha.shape + (1,)
    np.testing.assert_array_equal(exr[:, :, 0], alpha)
    png = cv2.imread(str(tmp_path / "o" / "m.png"), cv2.IMREAD_UNCHANGED)  # an outside reader
    assert png.dtype == np.uint16 and png.shape == alpha.shape  # one channel, linear (no sRGB curve)
    np.testing.assert_array_equal(png, np.round(alpha * 65535).astype(np.uint16))


def test_save_image_needs_exactly_one_input(tmp_path, write):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  s: {type: SaveImage, params: {path: a.exr}}\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    assert r.returncode == 2 and "connect exactly one of 'image' and 'mask'" in r.stderr, r.stderr


def test_scalar_outputs_are_plain_json_numbers(tmp_path, write, engine_registry):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const, params: {value: 1.5}}\n"
                        "  s: {type: Sum, inputs: {xs: [c.out, c.out, c.out]}}\noutputs: {n: s.count, total: s.out}\n")
    run_graph(g, cache=tmp_path / "c", out=tmp_path / "o", registry=engine_registry)
    text = (tmp_path / "o" / "n.json").read_text()
    assert json.loads(text) == 3.0 and isinstance(json.loads(text), float), text  # before: {"value": "0x1.8p+1"}


BAD_NAMES = ["../x.exr", "/abs.exr", "a/../../x.exr", "a\\..\\..\\x.exr", "C:x.exr", "a\0b.exr", "", "dir/",
             "..\\x.exr"]


@pytest.mark.parametrize("name", BAD_NAMES)
def test_one_output_name_rule_everywhere(name):
    """The executor, SaveImage and SaveMesh refuse the same names (before, SaveMesh let
    backslashes and ':' through, and the executor let NUL bytes reach the OS)."""
    from pydantic import ValidationError

    import graphkit.executor
    from graphkit import GraphkitError, safe_relpath
    from nodes.io.images import SaveImage
    from nodes.io.meshes import SaveMesh

    assert graphkit.executor.safe_relpath is safe_relpath
    with pytest.raises(GraphkitError):
        safe_relpath(name)
    with pytest.raises(ValidationError, match="output folder"):
        SaveImage.Params(path=name)
    with pytest.raises(ValidationError, match="output folder"):
        SaveMesh.Params(path=name.replace(".exr", ".ply"))


def test_output_names_are_normalised_the_same_way():
    from graphkit import safe_relpath
    from nodes.io.images import SaveImage
    from nodes.io.meshes import SaveMesh

    assert safe_relpath("./a//b\\c.exr") == "a/b/c.exr"
    assert SaveImage.Params(path="./a//b\\c.exr").path == "a/b/c.exr"
    assert SaveMesh.Params(path="./a//b\\c.ply").path == "a/b/c.ply"


def test_builtin_files_one_resolver(tmp_path, write):
    from graphkit import BadInput
    from nodes.io.builtin import builtin_path
    from nodes.loscos.scene import LoadScene

    p = builtin_path("builtin:sample_capture/mesh.ply")
    assert p.endswith("nodes/paris/data/sample_capture/mesh.ply")
    with pytest.raises(BadInput, match="cannot leave builtin:sample_capture"):
        builtin_path("builtin:sample_capture/../../io/images.py")
    with pytest.raises(BadInput, match="is a folder: name a file in it, e.g. builtin:sample_capture/camera.json"):
        builtin_path("builtin:sample_capture")
    assert LoadScene.resolve_file("path", "builtin:cornell2", str(tmp_path)).endswith("nodes/loscos/data/cornell2.yaml")
    with pytest.raises(BadInput, match=r"unknown builtin scene 'builtin:moon' \(known: builtin:cornell2"):
        LoadScene.resolve_file("path", "builtin:moon", str(tmp_path))
    g = write("g.yaml", 'graphkit: 1\nnodes:\n  m: {type: LoadMesh, params: {path: "builtin:sample_capture/mesh.ply"}}\n'
                        '  c: {type: LoadCameraJson, params: {path: "builtin:sample_capture/camera.json"}}\n')
    assert graphkit("validate", g).returncode == 0


def write_u8(path, px):
    """A PNG holding exactly ``px`` (OIIO would otherwise divide colour by alpha on writing)."""
    import cv2

    spec = oiio.ImageSpec(px.shape[1], px.shape[0], px.shape[2], "uint8")
    spec.attribute("oiio:UnassociatedAlpha", 1)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(px)
    out.close()
    stored = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # an outside reader (grey + alpha → BGRA)
    want = px[:, :, [0, 0, 0, 1]] if px.shape[2] == 2 else px[:, :, [2, 1, 0, 3]]
    np.testing.assert_array_equal(stored, want)


def test_grey_alpha_and_two_channel_images(tmp_path, write, engine_registry):
    import colour

    rng = np.random.default_rng(5)
    ya = rng.integers(0, 256, (9, 7, 2), dtype=np.uint8)
    write_u8(tmp_path / "ya.png", ya)  # PNG grey + alpha: OIIO names the channels Y, A
    g = write("g.yaml", "graphkit: 1\nnodes:\n  p: {type: LoadImage, params: {path: ya.png}}\n"
                        "  k: {type: LoadImage, params: {path: ya.png, drop_alpha: false}}\n")
    r = run_graph(g, cache=tmp_path / "c", registry=engine_registry)
    grey = r.value("p.image").pixels
    assert grey.shape == (9, 7, 1)
    np.testing.assert_allclose(grey[:, :, 0], colour.models.eotf_sRGB(ya[:, :, 0] / 255.0), atol=1e-6)
    kept = r.value("k.image").pixels
    np.testing.assert_allclose(kept[:, :, 1], ya[:, :, 1] / 255.0, atol=1e-7)  # alpha is not sRGB-decoded
    rgba = rng.integers(0, 256, (4, 4, 4), dtype=np.uint8)
    write_u8(tmp_path / "rgba.png", rgba)
    g = write("g2.yaml", "graphkit: 1\nnodes:\n  k: {type: LoadImage, params: {path: rgba.png, drop_alpha: false}}\n")
    kept = run_graph(g, cache=tmp_path / "c", registry=engine_registry).value("k.image").pixels
    np.testing.assert_allclose(kept[:, :, 3], rgba[:, :, 3] / 255.0, atol=1e-7)
    np.testing.assert_allclose(kept[:, :, :3], colour.models.eotf_sRGB(rgba[:, :, :3] / 255.0), atol=1e-6)
    write_float_exr(tmp_path / "rg.exr", rng.random((4, 4, 2)))  # two colour channels (R, G)
    g = write("g3.yaml", "graphkit: 1\nnodes:\n  p: {type: LoadImage, params: {path: rg.exr}}\n")
    r = graphkit("run", g, "--cache", tmp_path / "c", "--out", tmp_path / "o")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "node 'p' (LoadImage), port 'path'" in r.stderr and "has two colour channels (R, G)" in r.stderr
