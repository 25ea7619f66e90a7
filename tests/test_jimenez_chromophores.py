"""SkinChromophores (Tsumura 1999 ICA; Jimenez 2010 §2.1) on synthetic Beer–Lambert images."""
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from graphkit import BadInput, Image, Mask
from graphkit.contract import compute_checked
from nodes.jimenez.chromophores import ApplyHemoglobin, SkinChromophores, model_density, model_jacobian


def _synthetic(seed, shading=True, noise=0.0, size=160):
    """Photo = exp(−(density of the spectral model at (C_m0, C_hd0) + ΔC·q)) · shading."""
    rng = np.random.default_rng(seed)
    H = W = size
    yy, xx = np.mgrid[0:H, 0:W]
    cm = 0.004 + 0.006 * (np.sin(xx / 13.0) * np.cos(yy / 19.0)) ** 2        # smooth blotches
    vessels = gaussian_filter(rng.random((H, W)), 2.0)
    ch = 0.03 + 0.05 * np.clip((vessels - 0.5) * 12, 0, 1)                    # sparse "capillaries"
    c0 = (0.006, 0.04)
    J = model_jacobian(*c0)
    d0 = model_density(*c0)
    dens = d0 + (cm - c0[0])[..., None] * J[:, 0] + (ch - c0[1])[..., None] * J[:, 1]
    rgb = np.exp(-dens)
    if shading:
        rgb = rgb * (0.35 + 0.65 * (xx / W))[..., None] * (0.8 + 0.2 * np.cos(yy / 30.0))[..., None]
    if noise:
        rgb = rgb * np.exp(rng.normal(0, noise, rgb.shape))
    return rgb.astype(np.float32), cm, ch


@pytest.mark.parametrize("shading,noise", [(False, 0.0), (True, 0.0), (True, 0.001)])
def test_recovers_known_density_maps(shading, noise):
    rgb, cm, ch = _synthetic(1, shading, noise)
    node = SkinChromophores(SkinChromophores.Params(colour_check=False))  # synthetic colours
    out = node.compute(image=Image(rgb), mask=Mask(np.ones(cm.shape, np.float32)))
    m = out["melanin"].pixels[..., 0].ravel()
    h = out["hemoglobin"].pixels[..., 0].ravel()
    r_m = np.corrcoef(m, cm.ravel())[0, 1]
    r_h = np.corrcoef(h, ch.ravel())[0, 1]
    print(f"shading={shading} noise={noise}: corr melanin {r_m:.4f}, hemoglobin {r_h:.4f}")
    assert r_m >= 0.98 and r_h >= 0.98
    # hemoglobin's density vector peaks in green/blue, not red
    q = out["pigments"][1]
    assert q[1] > q[0] and q[2] > q[0]


def test_apply_hemoglobin_inverts_beer_lambert():
    rgb, cm, ch = _synthetic(2, True)
    out = SkinChromophores(SkinChromophores.Params(colour_check=False)).compute(image=Image(rgb), mask=Mask(np.ones(cm.shape, np.float32)))
    h = out["hemoglobin"]
    same = ApplyHemoglobin().compute(image=Image(rgb), pigments=out["pigments"], hemoglobin=h, new_hemoglobin=h)
    np.testing.assert_allclose(same.pixels, rgb, atol=1e-6)
    more = Image(h.pixels + 0.02)
    red = ApplyHemoglobin().compute(image=Image(rgb), pigments=out["pigments"], hemoglobin=h, new_hemoglobin=more)
    ratio = (red.pixels / rgb).reshape(-1, 3).mean(0)
    assert ratio[0] > ratio[1] and ratio[0] > ratio[2]  # more blood: green and blue absorbed more


def test_photo_with_no_skin_is_bad_input():
    rng = np.random.default_rng(0)
    blue = np.zeros((64, 64, 3), np.float32)
    blue[..., 2] = 0.5 + 0.1 * rng.random((64, 64))
    with pytest.raises(BadInput, match="no skin"):
        SkinChromophores().compute(image=Image(blue))
    with pytest.raises(BadInput, match="no skin"):
        SkinChromophores().compute(image=Image(blue + 0.2), mask=Mask(np.zeros((64, 64), np.float32)))
    with pytest.raises(BadInput) as e:  # as the engine runs it: the declared constraints first
        compute_checked(SkinChromophores(), image=Image(blue), mask=Mask(np.ones((32, 64), np.float32)))
    assert e.value.port == "mask" and "sizes differ: image is 64×64×3, mask is 64×32" in e.value.message


def test_astronaut_skin_found():
    from skimage import data

    from nodes.common.color import srgb_to_linear

    photo = srgb_to_linear(data.astronaut()[::2, ::2] / 255.0)
    out = SkinChromophores().compute(image=Image(photo))
    skin = out["skin"].alpha > 0.5
    assert skin[40:110, 90:150].mean() > 0.5  # the face
    h = out["hemoglobin"].pixels[..., 0]
    assert h[skin].std() > 0 and np.all(h >= 0)
