"""SkinSegment: a synthetic face whose skin is CIE TCS13 (light skin, colour-science's measured
reflectance under D65), shaded like a sphere, with a flash highlight, hair, lips and eyes; and
the astronaut photo with FaceMesh's regions."""
import numpy as np
import pytest

from graphkit import BadInput, Image, Mask
from graphkit.contract import compute_checked
from nodes.paris.skin import SkinSegment


def _tcs13_linear_srgb():
    import colour
    from colour.quality.datasets import SDS_TCS

    sd = SDS_TCS["CIE 1995"]["TCS13"]
    xyz = colour.sd_to_XYZ(sd, illuminant=colour.SDS_ILLUMINANTS["D65"]) / 100.0
    return np.asarray(colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False))


@pytest.fixture(scope="module")
def scene():
    h, w = 160, 128
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    cx, cy, ax, ay = 64, 84, 46, 62
    e = ((xx - cx) / ax) ** 2 + ((yy - cy) / ay) ** 2
    face = e <= 1
    # sphere-like shading of an ellipsoid lit from the camera, a flash highlight
    nz = np.sqrt(np.clip(1 - e, 0, 1))
    rng = np.random.default_rng(0)
    skin = _tcs13_linear_srgb()
    img = (0.15 + 0.85 * nz)[..., None] * skin * (1 + 0.03 * rng.standard_normal((h, w, 1)))
    hl = np.exp(-(((xx - 70) ** 2 + (yy - 80) ** 2) / (2 * 5.0 ** 2))) * 0.9
    img = img + hl[..., None]  # white (D65) specular
    hair = face & (yy < cy - 0.7 * ay + 8 * np.sin(xx / 9))
    img[hair] = np.array([0.055, 0.032, 0.018]) * (1 + 0.2 * rng.standard_normal((hair.sum(), 1)))
    lips = ((xx - cx) / 16) ** 2 + ((yy - 128) / 6) ** 2 <= 1
    img[lips] = [0.32, 0.05, 0.06]
    eyes = (((xx - 46) / 9) ** 2 + ((yy - 70) / 4) ** 2 <= 1) | (((xx - 82) / 9) ** 2 + ((yy - 70) / 4) ** 2 <= 1)
    img[eyes] = [0.6, 0.6, 0.6]
    img[eyes & ((np.abs(xx - 46) < 3.5) | (np.abs(xx - 82) < 3.5))] = [0.05, 0.08, 0.12]
    bg = ~face
    img[bg] = [0.2, 0.3, 0.5]
    truth = face & ~hair & ~lips & ~eyes
    return dict(image=Image(np.clip(img, 0, None).astype(np.float32)), face=Mask(face), lips=Mask(lips),
                eyes=Mask(eyes), hair=hair, truth=truth, highlight=hl > 0.3)


def test_synthetic_face(scene):
    m = SkinSegment(SkinSegment.Params(exclude_margin=0.0)).compute(
        image=scene["image"], face=scene["face"], exclude=[scene["eyes"], scene["lips"]]).alpha > 0.5
    t = scene["truth"]
    iou = (m & t).sum() / (m | t).sum()
    assert iou > 0.95, iou
    assert not (m & scene["hair"]).any()           # hair is rejected by colour, not told
    assert m[scene["highlight"]].mean() > 0.95     # the flash highlight is skin (dichromatic)
    assert not (m & ~scene["face"].alpha.astype(bool)).any()


def test_single_exclude_mask_and_margin(scene):
    m = SkinSegment().compute(image=scene["image"], face=scene["face"], exclude=scene["lips"]).alpha
    assert m[scene["lips"].alpha > 0].max() == 0


def test_painted_overrides(scene):
    painted = np.zeros(scene["truth"].shape, np.float32)
    painted[10:20, 10:30] = 1.0
    m = SkinSegment().compute(image=scene["image"], painted=Mask(painted), face=scene["face"]).alpha
    np.testing.assert_array_equal(m, painted)


def test_bad_inputs(scene):
    def run(**inputs):  # as the engine runs it: declared constraints first
        return compute_checked(SkinSegment(), **inputs)

    size = scene["image"].size_str()
    with pytest.raises(BadInput) as e:
        run(image=scene["image"], painted=Mask(np.zeros((160, 128))))
    assert e.value.port == "painted"
    with pytest.raises(BadInput) as e:  # declared: same_size_as="image"
        run(image=scene["image"], painted=Mask(np.ones((10, 10))))
    assert e.value.port == "painted" and e.value.message == f"sizes differ: image is {size}, painted is 10×10"
    with pytest.raises(BadInput) as e:
        run(image=scene["image"], face=Mask(np.ones((10, 10))))
    assert e.value.port == "face" and e.value.message == f"sizes differ: image is {size}, face is 10×10"
    with pytest.raises(BadInput) as e:
        run(image=scene["image"])
    assert e.value.port == "face"
    with pytest.raises(BadInput) as e:  # nothing left to learn skin from
        run(image=scene["image"], face=scene["face"], exclude=[scene["face"]])
    assert e.value.port == "exclude"
    with pytest.raises(BadInput) as e:
        run(image=scene["image"], face=scene["face"], exclude=[scene["face"], Mask(np.zeros((5, 5)))])
    assert e.value.port == "exclude" and e.value.message == f"item 1: sizes differ: image is {size}, exclude is 5×5"


def test_astronaut_with_facemesh():
    pytest.importorskip("graphkit_mediapipe", reason="plugin graphkit-mediapipe not installed (make installs it)")
    pytest.importorskip("mediapipe", reason="mediapipe not installed (pip install --no-deps mediapipe==0.10.14)")
    import skimage.data
    from graphkit_mediapipe.facemesh import FaceMesh

    from nodes.common.color import srgb_to_linear

    photo = skimage.data.astronaut()
    img = Image(srgb_to_linear(photo / 255.0))
    fm = FaceMesh().compute(image=img)
    m = SkinSegment().compute(image=img, face=fm["face"],
                              exclude=[fm[k] for k in ("eyes", "brows", "lips", "nostrils")]).alpha
    face = fm["face"].alpha
    assert 0.55 < m.sum() / face.sum() < 0.9
    for k in ("eyes", "brows", "lips", "nostrils"):
        assert (m * fm[k].alpha).sum() == 0, k
    assert (m * fm["cheeks"].alpha).sum() > 0.9 * fm["cheeks"].alpha.sum()
    # the hair over the forehead (dark, inside the face oval, above the brows) is rejected
    ys, _ = np.nonzero(fm["brows"].alpha)
    forehead = face.copy()
    forehead[ys.min() - 5:] = 0
    dark = forehead.astype(bool) & (photo.mean(-1) < 90)
    assert dark.sum() > 50 and m[dark].mean() < 0.1


def test_the_face_box_gives_the_whole_photo_answer():
    """SkinSegment looks only at the face's box (a face is a few per cent of a phone photo):
    the exclusions dilated there and the skin found there are the whole photo's, bit for bit —
    an exclusion outside the face still reaching into it, a face at the photo's border."""
    from scipy import ndimage

    from nodes.paris.skin import _segment, excluded_region, segment

    rng = np.random.default_rng(2)
    h, w = 120, 160
    for k in range(6):
        face = np.zeros((h, w), bool)
        y0, x0 = (0, 0) if k == 0 else (rng.integers(0, 60), rng.integers(0, 90))
        face[y0:y0 + 50, x0:x0 + 60] = True
        ex = np.zeros((h, w), bool)
        ex[y0 + 52:y0 + 56, x0 + 10:x0 + 30] = True          # just below the face: reaches in
        ex[y0 + 20:y0 + 25, x0 + 20:x0 + 40] = True          # inside
        ex[rng.random((h, w)) > 0.995] = True                # clipped specks anywhere
        margin = 0.1
        got = excluded_region([Mask(ex.astype(np.float32))], face, h, w, margin)
        r = int(round(margin * 60))
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        whole = ndimage.binary_dilation(ndimage.binary_fill_holes(ex), structure=(yy ** 2 + xx ** 2) <= r * r)
        assert np.array_equal(got & face, whole & face) and not (got & ~face).any(), k
        assert (got & face).any()
        rgb = rng.uniform(0.05, 0.6, (h, w, 3)) * np.array([1.0, 0.7, 0.55])
        learn = face & ~whole
        want = _segment(rgb, learn, learn, 3.0, 3.0, 50)
        assert np.array_equal(segment(rgb, learn, learn, 3.0, 3.0, 50), want) and want.any()
