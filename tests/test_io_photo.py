"""LoadPhoto (issue 26 item 5): an 8-bit phone photo in, linear out, explicitly; EXIF
orientation honoured; clipped pixels found and counted; CMYK / 16-bit files refused (exit 2)."""
from __future__ import annotations

import numpy as np
import pytest

from graphkit import BadInput
from graphkit.node import Context
from nodes.io.photo import LoadPhoto


def _write(path, codes, fmt="uint8", **attrs):
    import OpenImageIO as oiio

    h, w, c = codes.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    for k, v in attrs.items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(codes)
    out.close()
    return str(path)


def _load(path, **params):
    told = []
    node = LoadPhoto(LoadPhoto.Params(path=path, **params), Context(tell=told.append))
    return node.compute(), told


@pytest.fixture
def codes():
    """A 4×6 photo with a distinct code in each pixel (PNG: lossless) and one clipped pixel."""
    c = (np.arange(4 * 6 * 3).reshape(4, 6, 3) * 3 % 250).astype(np.uint8)
    c[1, 2, 0] = 255
    return c


def test_codes_are_linearised_by_the_srgb_eotf(tmp_path, codes):
    import colour

    out, told = _load(_write(tmp_path / "p.png", codes))
    want = colour.models.eotf_sRGB(codes / 255.0)
    np.testing.assert_allclose(out["image"].pixels, want, atol=1e-6)
    assert out["clipped"].alpha.sum() == 1 and out["clipped"].alpha[1, 2] == 1
    assert len(told) == 1 and "1 pixels" in told[0] and "left out of the skin" in told[0]


def test_a_response_curve_replaces_the_eotf(tmp_path, codes):
    curve = list(np.linspace(0, 1, 256) ** 2.0)
    out, _ = _load(_write(tmp_path / "p.png", codes), response=curve)
    np.testing.assert_allclose(out["image"].pixels, (codes / 255.0) ** 2.0, atol=1e-6)
    with pytest.raises(ValueError):
        LoadPhoto.Params(path="p.png", response=curve[::-1])  # decreasing: refused before running


def test_exif_orientation_turns_the_photo_upright(tmp_path, codes):
    import OpenImageIO as oiio

    path = _write(tmp_path / "p.png", codes)
    plain, _ = _load(path)
    turned_path = _write(tmp_path / "t.png", codes, Orientation=6)  # 6: the camera turned 90° clockwise
    if oiio.ImageInput.open(turned_path).spec().get_int_attribute("Orientation", 1) != 6:
        pytest.fail("OpenImageIO did not write the Orientation attribute in PNG")
    turned, told = _load(turned_path)
    np.testing.assert_array_equal(turned["image"].pixels, np.rot90(plain["image"].pixels, -1))
    assert any("orientation 6" in t for t in told)


def test_cmyk_and_16_bit_files_are_refused_naming_the_port(tmp_path, codes):
    from PIL import Image as PILImage

    cmyk = tmp_path / "cmyk.jpg"
    PILImage.new("CMYK", (8, 8), (10, 20, 30, 40)).save(cmyk)
    with pytest.raises(BadInput) as e:
        _load(str(cmyk))
    assert e.value.port == "path" and "CMYK" in e.value.message and "sRGB" in e.value.message
    deep = _write(tmp_path / "deep.png", codes.astype(np.uint16) * 257, fmt="uint16")
    with pytest.raises(BadInput) as e:
        _load(deep)
    assert e.value.port == "path" and "uint16" in e.value.message and "LoadImage" in e.value.message


GRAPH = """graphkit: 1
name: photo_io
nodes:
  photo: {type: LoadPhoto, params: {path: PHOTO}}
  jpg: {type: SaveImage, inputs: {image: photo.image}, params: {path: back.jpg, bits: 8}}
  png: {type: SaveImage, inputs: {image: photo.image}, params: {path: back.png, bits: 8}}
  exr: {type: SaveImage, inputs: {image: photo.image}, params: {path: linear.exr, bits: 32}}
outputs: {jpg: jpg.file, png: png.file, exr: exr.file}
"""


def test_a_run_says_it_once_writes_srgb_and_linear_back_and_refuses_cmyk(tmp_path, codes):
    """Through the CLI: the clipped count is a notice of the run (once: a cached run does not
    repeat it); the photo comes back as the same 8-bit codes (PNG) and as linear EXR; a CMYK
    JPEG exits 2 naming node and port, leaving no output folder."""
    from conftest import graphkit, read_exr
    from PIL import Image as PILImage

    import colour

    _write(tmp_path / "p.png", codes)
    (tmp_path / "g.yaml").write_text(GRAPH.replace("PHOTO", "p.png"))
    cache, out = tmp_path / "cache", tmp_path / "out"
    r = graphkit("run", tmp_path / "g.yaml", "--cache", cache, "--out", out, "-q")
    assert r.returncode == 0, r.stderr
    said = (r.stdout + r.stderr).count("notice: photo (LoadPhoto): 1 pixels (")
    assert said == 1, r.stdout + r.stderr
    again = graphkit("run", tmp_path / "g.yaml", "--cache", cache, "--out", tmp_path / "out2", "-q")
    assert again.returncode == 0 and "notice: photo" not in again.stdout + again.stderr
    back = np.asarray(PILImage.open(out / "back.png"))
    np.testing.assert_array_equal(back, codes)
    np.testing.assert_allclose(read_exr(out / "linear.exr"), colour.models.eotf_sRGB(codes / 255.0), atol=1e-6)
    assert (out / "back.jpg").stat().st_size > 0

    PILImage.new("CMYK", (8, 8), (10, 20, 30, 40)).save(tmp_path / "c.jpg")
    (tmp_path / "c.yaml").write_text(GRAPH.replace("PHOTO", "c.jpg"))
    bad = graphkit("run", tmp_path / "c.yaml", "--cache", cache, "--out", tmp_path / "out3")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert "node 'photo' (LoadPhoto), port 'path'" in bad.stderr and "CMYK" in bad.stderr
    assert not (tmp_path / "out3").exists()
