"""ScatterRelit: Jimenez 2010 §6 scattering of the light a relit face receives, the texture
kept sharp (issue 26 item 2, the subsurface pass)."""
from __future__ import annotations

import numpy as np
import pytest

from graphkit import BadInput, Camera, Image, Mask
from nodes.common.sss import sss_blur
from nodes.jimenez.scatter import ScatterRelit

N = 64
CAM = Camera(width=N, height=N, projection="orthographic", pixels_per_m=4000.0, cx=N / 2, cy=N / 2)  # 0.25 mm/px


def _scene(step: bool):
    yy, xx = np.mgrid[0:N, 0:N]
    level = np.where(xx < N // 2, 0.8, 0.1) if step else np.full((N, N), 0.5)
    light = level[..., None] * np.array([0.9, 0.6, 0.5])
    texture = np.random.default_rng(1).uniform(0.6, 1.3, (N, N, 3))  # texture × light stays below 1 (no clamp)
    depth = np.full((N, N, 1), 0.5)  # metres (the camera's unit)
    f32 = lambda a: Image(np.asarray(a, np.float32))  # noqa: E731
    return f32(np.clip(texture * light, 0, 1)), f32(light), f32(depth), texture


def test_texture_sharp_light_scattered():
    image, light, depth, texture = _scene(step=True)
    out = ScatterRelit().compute(image=image, light=light, depth=depth, camera=CAM)["image"].pixels
    L = light.pixels
    scattered = sss_blur(L, np.full((N, N), 0.25), np.full((N, N), 500.0), mask=np.ones((N, N), np.float32))
    # out = texture × scattered light: the texture is not blurred
    assert np.allclose(out, np.clip(texture * scattered, 0, 1), atol=2e-5)
    # the light's step is softened, red (deepest scattering) more than blue
    row = out[N // 2] / texture[N // 2]
    assert row[N // 2 - 2, 0] < 0.8 * 0.9 - 0.01 and row[N // 2 + 1, 0] > 0.1 * 0.9 + 0.01
    spread = lambda c: np.abs(row[:, c] - L[N // 2, :, c]).sum() / L[N // 2, 0, c]  # noqa: E731
    assert spread(0) > spread(2) > 0


def test_uniform_light_and_outside_mask_unchanged():
    image, light, depth, _ = _scene(step=False)
    out = ScatterRelit().compute(image=image, light=light, depth=depth, camera=CAM)["image"].pixels
    assert np.allclose(out, image.pixels, atol=1e-5)
    image, light, depth, _ = _scene(step=True)
    mask = np.zeros((N, N), np.float32)
    mask[:, N // 4: 3 * N // 4] = 1.0
    out = ScatterRelit().compute(image=image, light=light, depth=depth, camera=CAM,
                                 mask=Mask(mask))["image"].pixels
    assert np.array_equal(out[:, : N // 4], image.pixels[:, : N // 4])
    assert not np.array_equal(out[:, N // 4:], image.pixels[:, N // 4:])


def test_no_depth_is_refused():
    image, light, depth, _ = _scene(step=True)
    with pytest.raises(BadInput) as e:
        ScatterRelit().compute(image=image, light=light, depth=Image(np.zeros((N, N, 1), np.float32)), camera=CAM)
    assert e.value.port == "depth"
