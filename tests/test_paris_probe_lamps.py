"""ProbeLight with the ball's circle given picks the flash's highlight among several clipped ones
(issue 26 item 7: 8 of the 24 varied Mitsuba probes were refused even with the true circle
given, because another lamp clips on the ball too).  The flash is by the lens (or at
``flash_offset_m``): its highlight is the one seen within the bound ProbeLight._flash_prior
states; a lamp there as well, none there, or a highlight joined with other clipped light is
refused.  Synthetic orthographic probes, the circle given: fast."""
import re

import numpy as np
import pytest

from graphkit import BadInput, Image
from nodes.paris import probe as probe_mod
from nodes.paris.probe import ProbeLight, reflected_directions

H = W = 160
CX, CY, R = 80.0, 80.0, 60.0


def _dir(theta_deg, phi_deg):
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), -np.cos(th)])


FLASH = _dir(8, 40)          # 8° off the lens's direction (−z, orthographic)


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _probe(lamps=(), flash=True, band=0.0, band_deg=25.0) -> Image:
    """An ambient of 0.02, the flash's highlight (4° wide, peak 40, clipped at 1) and other
    lamps' highlights ``(direction, width in degrees)`` as bright; ``band``: a lit wall's
    reflection as bright as the clip, a band 5° wide running from the flash's highlight 25°
    along x (the flash's highlight joined with other clipped light)."""
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    d = reflected_directions(xx, yy, CX, CY, R, W, H, None)
    img = np.full((H, W), 0.02)
    for ldir, width in ([(FLASH, 4.0)] if flash else []) + list(lamps):
        img += 40.0 * np.exp(-(np.degrees(np.arccos(np.clip(d @ ldir, -1, 1))) / width) ** 2)
    along = d[..., 0] - FLASH[0]
    img += band * ((along > 0) & (along < np.sin(np.radians(band_deg))) & (np.abs(d[..., 1] - FLASH[1]) < 0.045))
    img[(xx - CX) ** 2 + (yy - CY) ** 2 > R * R] = 0.0
    return Image(np.repeat(np.clip(img, 0, 1)[..., None], 3, 2).astype(np.float32))


def _light(img, **params):
    return ProbeLight(ProbeLight.Params(centre_x=CX, centre_y=CY, radius=R, **params)).compute(probe=img)["light"]


def test_far_lamp_leaves_the_flash():
    """A lamp 45° off the lens (a larger highlight than the flash's) is not the flash."""
    img = _probe([(_dir(45, 200), 6.0)])
    assert _angle(_light(img).direction, FLASH) <= 1.0


def test_far_lamp_answered_where_the_old_rule_refused(monkeypatch):
    """Before this rule (ProbeLight 7) two clipped highlights were refused whatever their place."""
    img = _probe([(_dir(60, 300), 4.0)])
    assert _angle(_light(img).direction, FLASH) <= 1.0
    monkeypatch.setattr(probe_mod, "FLASH_FROM_LENS_M", 10.0)   # every highlight fits the prior
    with pytest.raises(BadInput, match="2 clipped highlights"):
        _light(img)


def test_lamp_near_the_flash_refused():
    """A lamp 15° off the lens is within the 20.6° a flash by the lens may be seen at: which one
    is the flash is not known, so neither is returned."""
    with pytest.raises(BadInput) as e:
        _light(_probe([(_dir(15, 220), 4.0)]))
    assert e.value.port == "probe"
    msg = e.value.message
    assert "2 clipped highlights" in msg and "2 within 20.6°" in msg and "flash_offset_m" in msg, msg
    assert re.search(r"52 px at 8\.\d° \(\+0\.11, \+0\.09, -0\.99\)", msg) and "at 15.0°" in msg, msg   # what was seen


def test_stated_flash_tells_them_apart():
    """The same probe with the flash's and the ball's positions stated: the flash is predicted
    within max_disagreement_deg (5°), the lamp is 23° from it."""
    ball = np.array([0.0, 0.0, 0.6])
    flash_m = ball + FLASH * (ball[2] / -FLASH[2])               # on the lens's plane, ~8.4 cm off
    light = _light(_probe([(_dir(15, 220), 4.0)]), flash_offset_m=tuple(flash_m), ball_position_m=tuple(ball))
    assert light.kind == "point" and _angle(light.direction, FLASH) <= 1.0


def test_no_highlight_near_the_lens_refused():
    """The flash does not clip, two lamps far from the lens do: refused, not the larger lamp."""
    with pytest.raises(BadInput, match="none within 20.6°"):
        _light(_probe([(_dir(40, 90), 5.0), (_dir(55, 250), 4.0)], flash=False))


def test_highlight_joined_with_other_light_refused(monkeypatch):
    """The flash's highlight joined with a lit wall's clipped reflection is one blob near the
    lens whose mean is degrees off: refused because it is not round."""
    img = _probe([(_dir(60, 300), 4.0)], band=1.0)
    with pytest.raises(BadInput, match="not round"):
        _light(img)
    monkeypatch.setattr(probe_mod, "MAX_HIGHLIGHT_SPREAD", np.inf)
    monkeypatch.setattr(probe_mod, "MAX_HIGHLIGHT_EXTENT", np.inf)
    assert _angle(_light(img).direction, FLASH) > 2.0            # what the rules keep from coming back


def test_short_joined_light_refused_by_its_reach(monkeypatch):
    """A lit wall's clipped reflection joined to the flash's disc along 15° only (ProbeLight 9):
    the blob's second moment stays under the bound (1.20 × a disc's) but its farthest pixel is
    1.41 disc radii from its mean (a disc's: 1.0; the varied tune probes' flash discs 1.00–1.19,
    tv28's joined one 1.29–1.41, 2.6–3.0° off): refused; without the reach bound it comes back
    about 2° off, the tv28 case (and the only highlight, so no lamp rule applies)."""
    img = _probe(band=1.0, band_deg=15.0)
    with pytest.raises(BadInput, match="reach 1.4"):
        _light(img)
    monkeypatch.setattr(probe_mod, "MAX_HIGHLIGHT_EXTENT", np.inf)
    assert _angle(_light(img).direction, FLASH) > 1.5


def _turn_y(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def test_perspective_prior_is_towards_the_lens():
    """A perspective probe with the ball 21.5° off the camera's axis: the flash is looked for
    around the direction from the ball to the lens, not around −z (where the lamp is here)."""
    w, h, fov, cx, cy, r = 640, 480, 40.0, 580.0, 240.0, 50.0
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    d = reflected_directions(xx, yy, cx, cy, r, w, h, fov)
    f = 0.5 * h / np.tan(np.radians(fov / 2))
    lens = -np.array([(cx - w / 2) / f, 0.0, 1.0]) / np.hypot((cx - w / 2) / f, 1.0)
    flash, lamp = _turn_y(8) @ lens, _turn_y(-40) @ lens           # 8° further out, 40° towards the axis
    assert _angle(flash, [0, 0, -1]) > 25 and _angle(lamp, [0, 0, -1]) < 20
    img = 0.02 + sum(40.0 * np.exp(-(np.degrees(np.arccos(np.clip(d @ v, -1, 1))) / 6.0) ** 2) for v in (flash, lamp))
    img[(xx - cx) ** 2 + (yy - cy) ** 2 > r * r] = 0.0
    probe = Image(np.repeat(np.clip(img, 0, 1)[..., None], 3, 2).astype(np.float32))
    light = ProbeLight(ProbeLight.Params(centre_x=cx, centre_y=cy, radius=r, fov_deg=fov)).compute(probe=probe)["light"]
    assert _angle(light.direction, flash) <= 1.0


def _with_specks(img: Image, n=4, seed=3) -> Image:
    """Clipped specks of 2×2 px (other clipped light's crumbs: a high-resolution probe's lit
    backdrop reflection breaks into them) 12–18° from the flash, within the lens's bound."""
    px = img.pixels.copy()
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    d = reflected_directions(xx, yy, CX, CY, R, W, H, None)
    off = np.degrees(np.arccos(np.clip(d @ FLASH, -1, 1)))
    ring = np.argwhere((off > 12) & (off < 18) & ((xx - CX) ** 2 + (yy - CY) ** 2 < (0.9 * R) ** 2))
    for y, x in ring[np.random.default_rng(seed).choice(len(ring), n, replace=False)]:
        px[y:y + 2, x:x + 2] = 1.0
    return Image(px)


def test_specks_near_the_flash_leave_it(monkeypatch):
    """Specks of clipped light near the flash's highlight (each under OTHER_HIGHLIGHT of it) do
    not make the flash unclear (ProbeLight 8; the varied tune probe tv04 at 3× its size, true
    circle given, was refused for 97 such highlights, 3 within the bound); without the rule the
    same probe is refused, which shows the specks are in the bound."""
    img = _with_specks(_probe([(_dir(60, 300), 4.0)]))
    assert _angle(_light(img).direction, FLASH) <= 1.0
    monkeypatch.setattr(probe_mod, "OTHER_HIGHLIGHT", 0.0)
    with pytest.raises(BadInput, match="within 20.6°"):
        _light(img)


def test_overexposed_probe_refused_with_the_circle_given():
    """A probe with over 5 % of its pixels clipped (a backdrop or wall clipping, its reflection
    round the flash clipped too) is refused with the circle given as well, not only by the
    finder (the varied tune probe tv14, 8 % clipped, came back 5.9° off with the true circle)."""
    img = _probe([(_dir(60, 300), 4.0)])
    px = img.pixels.copy()
    px[:, :16] = 1.0                                  # 10 % of the frame, outside the ball
    with pytest.raises(BadInput, match="over-exposed: 10%") as e:
        _light(Image(px))
    assert e.value.port == "probe"
    px[:, 4:16] = 0.5                                 # 2.5 %: answered
    assert _angle(_light(Image(px)).direction, FLASH) <= 1.0


@pytest.mark.parametrize("fov", [None, 40.0])
@pytest.mark.parametrize("clip", [True, False])
def test_the_ball_box_gives_the_whole_photo_answer(monkeypatch, fov, clip):
    """ProbeLight reads only the box round the ball (a 20-megapixel probe's ball is a few
    megapixels of it): the light and the classes image are the whole photo's, bit for bit — the
    circle given and found, orthographic and pinhole, a clipped and an HDR highlight, a white
    ball's photo for the flash's intensity, the ball near a corner of a larger frame, a noisy
    backdrop."""
    h, w, cx, cy, r = 300, 420, 300.5, 95.25, 61.0
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    d = reflected_directions(xx, yy, cx, cy, r, w, h, fov)
    rng = np.random.default_rng(4)
    ball = 0.03 + 40.0 * np.exp(-(np.degrees(np.arccos(np.clip(d @ FLASH, -1, 1))) / 4.0) ** 2)
    back = 0.01 + 0.004 * xx / w + rng.normal(0, 0.0005, (h, w))
    img = np.where((xx - cx) ** 2 + (yy - cy) ** 2 <= r * r, ball, back)
    img = np.clip(img, 0, 1) if clip else img
    img = Image(np.repeat(img[..., None], 3, 2).astype(np.float32))
    on = (xx - cx) ** 2 + (yy - cy) ** 2 <= (0.999 * r) ** 2
    shade = np.full((h, w), 0.02)
    shade[on] = 0.05 + 0.6 * np.clip(probe_mod.ball_normals(xx[on], yy[on], cx, cy, r, w, h, fov) @ FLASH, 0, None)
    white = Image(np.repeat(shade[..., None], 3, 2).astype(np.float32))   # a white ball's photo

    from nodes.paris import ballfind

    # "found": the finder's answer stood in by a confident fit at the circle (the finder's own
    # search is not what this is about), so that its doubt is weighed on the highlight: within
    # the bounds (residual 0.2 px), and refused by the bias bound (0.35 px: the same refusal)
    residual = [0.2]
    monkeypatch.setattr(ballfind, "find_ball", lambda *a, **k: ballfind.BallFit(
        cx + 0.1, cy - 0.05, r, True, support=1.0, max_gap_deg=0.0, residual_px=residual[0], in_frame=1.0,
        sigma_px=0.05))

    def outputs(res, **given):
        residual[0] = res
        try:
            o = ProbeLight(ProbeLight.Params(fov_deg=fov, **given)).compute(probe=img, white=white)
        except BadInput as e:
            return e.message, None
        return o["light"].model_dump(), o["classes"].pixels

    boxes = []
    real = probe_mod._ball_box
    monkeypatch.setattr(probe_mod, "_ball_box", lambda *a: boxes.append(real(*a)) or real(*a))
    cases = [(0.2, {"centre_x": cx, "centre_y": cy, "radius": r}), (0.2, {}), (0.35, {})]
    got = [outputs(res, **c) for res, c in cases]
    assert all((b[0].stop - b[0].start) * (b[1].stop - b[1].start) < 0.3 * h * w for b in boxes)
    assert isinstance(got[1][0], dict) and "2.5 × its residual" in got[2][0]
    monkeypatch.setattr(probe_mod, "_ball_box", lambda cx, cy, r, w, h: (slice(0, h), slice(0, w)))
    for (res, c), (light, cls) in zip(cases, got):
        whole_light, whole_cls = outputs(res, **c)
        assert light == whole_light and (cls is None and whole_cls is None or np.array_equal(cls, whole_cls)), c
        if cls is not None:
            assert _angle(light["direction"], FLASH) < 1.0
