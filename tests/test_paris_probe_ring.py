"""A ring, disc or band drawn on the backdrop around the mirror ball is not taken for the ball
(issue 26 item 7).

find_ball takes the outermost closed circle around the flash's highlight for the ball; a ring
printed on the backdrop around a ball whose silhouette is faint (its rim reflects the backdrop
behind it) is such a circle, and ProbeLight 4 returned its flash direction 2.6-10° off with exit 0.
A silhouette is a step across the outline; a printed line rises and falls back to the backdrop's
level (ballfind._line_profile): such an outline now makes the node refuse (exit 2, naming the
params to give).  A disc or wide band printed around the ball has a step at its edge like a
silhouette, but a mirror ball's rim reflects the backdrop beyond its outline (the grazing rays),
so it is never brighter than what lies outside nor darker than half of it; a print's inside is
its own level (ballfind._unreflected): refused too; ProbeLight 6 answered 2.4-5.1° off with
exit 0.  Synthetic orthographic probes (3×3 supersampled, a little noise): fast.
"""
import numpy as np
import pytest

from graphkit import BadInput, Image
from nodes.paris import ballfind
from nodes.paris.probe import ProbeLight, reflected_directions

H, W = 240, 320
CX, CY, R = 150.3, 118.7, 40.2
BACKDROP = 0.05


def _flash(theta_deg: float, phi_deg: float = 200.0) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), -np.cos(t)])


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _probe(flash, ring_r=0.0, ring_off=(0.0, 0.0), ring_level=0.0, ring_w=3.0) -> Image:
    """A mirror ball: sky 0.15 above, ground 0.07 below, the flash's clipped highlight, and
    behind the ball (its rim) the backdrop × 0.8, so the silhouette is a faint step; the
    backdrop (0.05) carries a ring ``ring_w`` px wide (``ring_level`` brighter) of radius
    ``ring_r`` (0: none) centred ``ring_off`` px from the ball's centre (a disc: ``ring_w`` =
    2 ``ring_r``).  The rim shows the backdrop beyond the ring: the ring's reflection is
    squeezed into the outline's last fraction of a pixel (see ballfind._unreflected)."""
    acc = np.zeros((H, W))
    for oy in (np.arange(3) + 0.5) / 3 - 0.5:
        for ox in (np.arange(3) + 0.5) / 3 - 0.5:
            yy, xx = np.mgrid[0:H, 0:W] + 0.5
            xx, yy = xx + ox, yy + oy
            d = reflected_directions(xx, yy, CX, CY, R, W, H, None)
            ang = np.degrees(np.arccos(np.clip(d @ flash, -1, 1)))
            ball = np.where(d[..., 1] < 0, 0.15, 0.07) + 40.0 * np.exp(-(ang / 3.0) ** 2)
            ball = np.where(d[..., 2] > 0.3, 0.8 * BACKDROP, ball)
            rr = np.hypot(xx - CX - ring_off[0], yy - CY - ring_off[1])
            backdrop = BACKDROP + ring_level * (np.abs(rr - ring_r) <= ring_w / 2)
            acc += np.where((xx - CX) ** 2 + (yy - CY) ** 2 <= R * R, ball, backdrop) / 9
    img = np.clip(acc + np.random.default_rng(0).normal(0, 0.002, acc.shape), 0, 1)
    return Image(np.repeat(img[..., None], 3, 2).astype(np.float32))


def _auto(img):
    try:
        return ProbeLight().compute(probe=img)["light"].direction, None
    except BadInput as e:
        return None, e


@pytest.mark.parametrize("ring", [(56.0, (2.0, -1.5), 0.3), (70.0, (6.0, -4.0), 0.5), (70.0, (0.0, 0.0), 0.5)])
def test_ring_on_the_backdrop_is_not_taken_for_the_ball(ring, monkeypatch):
    """A flash 6° off the lens: the ring is the outermost closed circle; refused."""
    flash = _flash(6.0)
    img = _probe(flash, *ring)
    _refused(img, flash, "a ring on the backdrop, not the ball's edge")
    # without the rule the rim test (a disc's, below) refuses it too: a ring's inside is not a mirror's
    monkeypatch.setattr(ballfind, "LINE_RATIO", 1e9)
    direction, refusal = _auto(img)
    assert direction is None and "a disc or band on the backdrop" in refusal.message
    # without both the ring is taken: 4.2, 10.2 and 2.6° off with exit 0
    _taken_without(img, flash, monkeypatch)


def _refused(img, flash, why):
    """``img`` refused on ``probe`` for ``why``, asking for the ball's circle."""
    direction, refusal = _auto(img)
    assert direction is None, f"a direction {_angle(direction, flash):.2f}° off came back with exit 0"
    assert refusal.port == "probe" and why in refusal.message
    assert "centre_x, centre_y and radius" in refusal.message


def _taken_without(img, flash, monkeypatch):
    """With the mirror-rim rule off, ``img``'s outline is taken and answered more than 1° off
    (and with the cast-shadow veto off: a dark disc's rim, darker all round, is refused by it
    too once NOT_MIRROR no longer takes it, ProbeLight 13)."""
    monkeypatch.setattr(ballfind, "NOT_MIRROR", 2.0)
    monkeypatch.setattr(ballfind, "MAX_DARKER_SHARE", 2.0)
    direction, _ = _auto(img)
    assert direction is not None and _angle(direction, flash) > 1.0


def test_the_balls_silhouette_is_a_step_not_a_line():
    """No ring: the ball's faint silhouette is a step (ridge about half the step), found ≤ 1°
    off; the rings are lines (ridge over 100 times the step).  LINE_RATIO (3) lies between."""
    flash = _flash(6.0)
    img = _probe(flash)
    direction, refusal = _auto(img)
    assert refusal is None, refusal.message
    assert _angle(direction, flash) <= 1.0
    for im, lo, hi in ((img, 0.0, 1.0), (_probe(flash, 56.0, (2.0, -1.5), 0.3), 100.0, np.inf)):
        px = im.pixels
        fit = ballfind.find_ball(px)
        ridge, step = ballfind._line_profile(ballfind.stabilise(ballfind.luminance(px)), fit)
        assert lo <= ridge / step <= hi, (ridge, step)
    assert 1.0 < ballfind.LINE_RATIO < 100.0


# (outer radius, width, offset from the ball's centre, level over the backdrop's 0.05)
DISCS = [(56.0, 56.0, (2.0, -1.5), 0.3), (56.0, 56.0, (2.0, -1.5), 0.05), (60.0, 60.0, (2.0, 1.0), -0.03),
         (60.0, 16.0, (3.0, 2.0), 0.1)]


def _disc_probe(flash, outer, width, off, level):
    return _probe(flash, outer - width / 2, off, level, ring_w=width)


@pytest.mark.parametrize("disc", DISCS, ids=["bright disc", "faint disc", "dark disc", "band"])
def test_disc_or_band_on_the_backdrop_is_not_taken_for_the_ball(disc, monkeypatch):
    """A disc or band around the ball: its edge is the outermost closed circle, a step like a
    silhouette; refused because its inside is no mirror's rim."""
    flash = _flash(6.0)
    img = _disc_probe(flash, *disc)
    _refused(img, flash, "a disc or band on the backdrop, not the ball's edge")
    # without the rule the disc's edge is taken: 4.3, 4.3, 2.4 and 5.1° off with exit 0
    _taken_without(img, flash, monkeypatch)


def test_the_balls_rim_is_a_mirrors():
    """The ball's own rim (the backdrop × 0.8) breaks the mirror's bounds on no sector; each
    disc's rim on every sector, brighter or darker as printed.  NOT_MIRROR (0.7) lies between
    (true rims of the Mitsuba probes: up to 38 %)."""
    flash = _flash(6.0)
    lum = ballfind.luminance(_probe(flash).pixels)
    assert ballfind._unreflected(lum, ballfind.BallFit(CX, CY, R, True))[0] == 0.0
    for disc in DISCS:
        px = _disc_probe(flash, *disc).pixels
        fit = ballfind.find_ball(px)
        assert abs(fit.r - disc[0]) < 1.0, fit.summary()      # the disc's edge was the outline found
        share, way = ballfind._unreflected(ballfind.luminance(px), fit)
        assert share == 1.0 and way == ("darker" if disc[3] < 0 else "brighter"), (disc, share, way)
    assert 0.38 < ballfind.NOT_MIRROR < 1.0


def test_highlight_blobs_and_noise_bins_are_scipys_numbers():
    """ballfind._highlights reads each clipped blob's centroid in its own box and counts blobs by
    bincount, noise_bins takes its two percentiles in one call: the same numbers, bit for bit,
    as scipy's center_of_mass/sum over the whole image and two np.percentile calls (a photo of
    blobs of every size, ties in size included, touching the frame's edges, on noise)."""
    from scipy import ndimage

    rng = np.random.default_rng(5)
    h, w = 480, 640
    lum = rng.uniform(0, 0.5, (h, w))
    yy, xx = np.mgrid[:h, :w]
    for cx, cy, r in [(0, 0, 9), (639, 200, 14), (320, 240, 30), (100, 400, 5), (500, 60, 5), (250, 479, 3),
                      *[(x, y, rng.uniform(1, 12)) for x, y in rng.uniform([0, 0], [w, h], (12, 2))]]:
        lum[np.hypot(xx - cx, yy - cy) <= r] = 1.0
    for max_blobs in (1, 8, 40):
        m = lum >= 0.98
        lab, n = ndimage.label(m)
        idx = np.arange(1, n + 1)
        top = idx[np.argsort(-ndimage.sum(m, lab, index=idx))[:max_blobs]]
        ref = [(float(x) + 0.5, float(y) + 0.5) for y, x in ndimage.center_of_mass(m, lab, top)]
        assert ballfind._highlights(lum, max_blobs=max_blobs) == ref
    lev = ndimage.uniform_filter(lum, 2)[1:, 1:]
    lev = lev[lev < 0.98]
    x, _, _ = ballfind.noise_bins(lum)
    lo = max(float(np.percentile(lev, 0.5)), 1e-4 * max(float(np.percentile(lev, 99.5)), 1e-12), 1e-12)
    edges = np.geomspace(lo, max(float(lev.max()), lo * 1.001), 25)
    idx = np.clip(np.searchsorted(edges, lev, side="right") - 1, 0, 23)
    first = np.flatnonzero(np.bincount(idx, minlength=24) >= 30)[0]
    assert x[0] == float(np.median(lev[idx == first]))
