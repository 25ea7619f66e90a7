"""Find the ball in a light-probe photo: centre and radius in pixels (Paris 2003 §4.1, Fig. 7).

A mirror ball in front of a dark backdrop is hard to see by its outline: its rim reflects
what is behind the ball (the backdrop, often in the ball's own shadow), so the silhouette is a
faint step between two dark regions, while the environment's reflection inside the ball and the
ball's cast shadow on the backdrop make strong circular edges of the wrong size or centre.
:func:`find_ball` therefore does not take the strongest circle.  It uses what only the
silhouette has:

0. **Noise-normalised image**: the pixel noise is measured against brightness (2×2 second
   differences, robust spread per brightness bin) and the luminance is transformed so that
   the noise has unit σ everywhere (a generalised Anscombe transform): a step's height is then
   its significance, in dark and bright regions alike.
1. **Candidates**: OpenCV's Hough transforms (``HOUGH_GRADIENT_ALT``, then ``HOUGH_GRADIENT``)
   on that image brought to ``SEED_PX`` and smoothed give circles of any origin (silhouette,
   environment edge, shadow, backdrop pattern).
2. **Edges on rays**: from each candidate's centre, profiles along 180 rays (each averaged
   over a short arc), and every significant local maximum of their radial step → edge points;
   RANSAC circles through edge points of different rays, refined by least squares.
3. **Sub-pixel fit**: rays are grouped in sectors of 4 (8°) and averaged (a silhouette is at
   the same radius on neighbouring rays, the noise is not); in each sector the significant
   step nearest to the circle (not the strongest: the rim often holds a stronger edge of the
   reflection a few pixels inside) is located at the parabolic peak of the linear luminance
   gradient; the points are fitted with outlier rejection — a circle (orthographic) or, given
   the vertical field of view, the cone of rays tangent to the sphere (its axis gives the
   projected centre, its half-angle the radius in ProbeLight's convention).  Iterated.
   Where that fit does not close, the outline is **polished** (:class:`_Outline`): the circle
   (cone) along which the radial gradient of the stabilised image, averaged over each sector, is
   strongest is searched from the candidate and from the fit — the rim's step, summed round the
   whole outline, stands out where no single sector's does, and the nearest edge a sector fit
   takes may be one of the reflection just inside.  Its support and residual are read from the
   edges about it; ProbeLight then bounds its direction by the residual as for a scattered fit
   (``probe.BIAS_PER_RMS``).  An outline (polished or not) whose rim is darker than a mirror's
   can be on ``MAX_DARKER_SHARE`` of it (the edge of the ball's cast shadow along a side) is not
   taken.
4. **Support**: the fraction of sectors (inside the frame) with a significant step on the
   fitted outline (within ``SNAP_PX``), and the largest gap.  A silhouette is a closed edge:
   a step in every sector.  A cast shadow shows only the crescent the ball does not hide; an
   environment edge is closed but concentric and inside.
5. **Choice**: among the closed circles (support ≥ ``MIN_SUPPORT``, gap ≤ ``MAX_GAP_DEG``,
   radius ≥ ``MIN_RADIUS_PX``; or partly closed but *tight*: edges within ``TIGHT_RMS_PX`` RMS
   of the circle on ≥ ``TIGHT_SUPPORT`` of it, no gap over ``TIGHT_GAP_DEG`` — where the rim
   reflects a backdrop as bright as beyond it, there is no step to see, while elsewhere the
   silhouette is a sharp circle; on a high-resolution probe a wrong circle's edges scatter
   more) that hold one of the clipped blobs (the flash's highlight), the
   outermost of each family (circles concentric with it or wholly inside it: edges of its own
   reflection, the flash's halo) is a ball; the family with the best support wins, and among
   families as well supported (within ``AMBIGUITY``) the one centred nearest the highlight
   (nearer by ``CENTRED_MARGIN`` radii): a flash by the lens lights the ball near its middle,
   while the ball's shadow on the backdrop is centred elsewhere.  The others are its
   ``rivals`` (ProbeLight weighs them by the flash directions they give).

The result says how sure it is (:class:`BallFit`); ``confident`` is False (with ``reason``)
when no closed circle is found, when two unrelated closed circles compete (``rivals``), when a fainter concentric circle surrounds the one found (looked for on the image stabilised by :func:`noise_curve`'s ``isotonic`` noise level), when the outline found is a thin
line with the same level on both sides (a ring drawn on the backdrop, :func:`_line_profile`), when its rim is
brighter or darker than a mirror's rim can be (a disc or band printed on the backdrop, :func:`_unreflected`), when
a better supported closed outline off its centre and nearer the highlight lies inside it (the ball inside
its cast shadow's soft outline, :func:`_shadow_around`), when the pixels just
outside it are clipped (the silhouette may be lost in them), when the fit is poor, or when
the ball is mostly outside the frame.  Tuned on the TUNING probes of
``nodes/paris/data/make_probes.py`` and the tune half of ``varied_probes.py``; checked on their
CHECK probes (tests/oracles/test_paris_probe_mitsuba.py, test_paris_probe_varied.py).  Units: pixels (pixel centres at +0.5).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nodes.common.color import channel_max

#: linear sRGB → luminance Y
_Y = np.array([0.2126, 0.7152, 0.0722])
N_RAYS = 180
RAYS_PER_SECTOR = 4      # rays averaged into one sector (8°) for the support and the sub-pixel fit
MIN_SUPPORT = 0.8        # fraction of in-frame sectors with an edge on a closed circle
MAX_GAP_DEG = 60.0       # largest run of sectors without an edge on a closed circle (degrees)
TOL_PX = 1.5             # an edge point is on a circle within this distance
MIN_IN_FRAME = 0.6       # fraction of the silhouette inside the image
LOOSE_SUPPORT = 0.5      # circles considered at all
OUTER_SUPPORT = 0.6      # a concentric edge around the ball found on this much of a circle: doubt
AMBIGUITY = 0.1          # two balls whose supports are closer than this: refuse
EDGE_SNR = 4.0           # an edge: a 2-pixel step this many noise σ high
PEAKS_PER_RAY = 5        # edge points kept per ray (the strongest)
MIN_RADIUS_PX = 12.0     # smaller circles are not taken for a ball (1 px off is ~10° of direction)
SNAP_PX = 0.6            # after the sub-pixel fit, an edge is on the outline within this
MAX_RMS_PX = 0.75        # a fit whose edges scatter more is not a circle
TIGHT_RMS_PX = 0.5       # an outline not closed is still a ball when its edges lie this close to the circle …
TIGHT_SUPPORT = 0.45     # … on at least this fraction of the sectors …
TIGHT_GAP_DEG = 120.0    # … with no larger gap (its direction's doubt then decides: ProbeLight's bias bound)
CENTRED_MARGIN = 0.15    # a ball whose centre is nearer the highlight by this (in radii) beats an equal rival
LINE_RATIO = 3.0         # an outline whose cross-profile rises and falls back this many times more than it
                         # steps is a line on the backdrop (a printed ring), not a silhouette (see _line_profile)
MIN_REFLECTANCE = 0.5    # a mirror ball's reflectance at grazing incidence is at least this (chrome ~0.55 head-on,
                         # a metal's rises towards 1 at grazing)
NOT_MIRROR = 0.7         # an outline whose rim a mirror could not show on this fraction of its sectors is not a
                         # mirror ball's (see _unreflected)
HIGHLIGHT_SEED_SIZES = (0.07, 0.11, 0.17, 0.26)   # radii (of the frame's smaller side) tried around the highlight
SEED_PX = 320           # the Hough transforms run on the image brought to this size
_NOISE = 1.0             # the pixel noise σ of the stabilised image (stabilise: unit by construction)


@dataclass
class BallFit:
    """Where the ball is and how sure :func:`find_ball` is about it.

    ``cx``, ``cy``, ``r``: pixels (continuous coordinates, pixel centres at +0.5; with
    ``fov_deg`` the projected centre of the sphere and ProbeLight's radius).  ``support``:
    fraction of 8° sectors with a silhouette step on the outline; ``max_gap_deg``: the largest
    angular run without one; ``residual_px``: RMS distance of the kept edge points;
    ``in_frame``: fraction of the outline inside the image; ``sigma_px``: standard error of
    the centre (``residual_px`` over the kept edge points); ``candidates``: the circles
    weighed, after their sub-pixel fit (cx, cy, r, support); ``rivals``: (cx, cy, r) of other
    closed outlines that may as well be the ball, when only they speak against it; ``start``:
    where not confident, (cx, cy, r) of a circle likelier to be the ball than this one, for a
    person to start from (the ball's own outline inside its cast shadow's: :func:`_shadow_around`).
    """

    cx: float
    cy: float
    r: float
    confident: bool
    reason: str = ""
    support: float = 0.0
    max_gap_deg: float = 360.0
    residual_px: float = float("inf")
    in_frame: float = 0.0
    sigma_px: float = float("inf")
    candidates: list = field(default_factory=list)
    rivals: list = field(default_factory=list)
    polished: bool = False
    start: tuple | None = None

    def __iter__(self):  # cx, cy, r, fit = find_ball(...)
        return iter((self.cx, self.cy, self.r, self))

    def summary(self) -> str:
        return (f"centre ({self.cx:.1f}, {self.cy:.1f}) px, radius {self.r:.1f} px, edge on "
                f"{100 * self.support:.0f}% of the outline (largest gap {self.max_gap_deg:.0f}°), "
                f"fit residual {self.residual_px:.2f} px")


def luminance(px: np.ndarray) -> np.ndarray:
    px = np.asarray(px, np.float64)
    if px.ndim == 2:
        return px
    if px.shape[2] == 1:
        return px[..., 0]
    return px[..., :3] @ _Y


def find_ball(px: np.ndarray, fov_deg: float | None = None, highlight: bool = True) -> BallFit:
    """Find the ball (see the module docstring) in a linear RGB (H×W×3) or luminance image.

    ``fov_deg``: the photo's vertical field of view (pinhole, principal point at the image
    centre), None for an orthographic view.  ``highlight``: the ball shows a clipped highlight
    (a mirror ball under the flash); a circle must hold it.  → :class:`BallFit`.
    """
    lum = luminance(px)
    h, w = lum.shape
    # (the channels' maximum in the photo's own type, then float64: the same values as the
    # maximum of a float64 copy, without a copy of a many-megapixel photo)
    chmax = np.asarray(channel_max(px), np.float64) if np.ndim(px) == 3 else lum
    clipped = chmax >= (1 - 1e-3) * max(float(chmax.max()), 1e-12)
    if h < 16 or w < 16:
        return BallFit(0, 0, 0, False, f"the image is {w}×{h} px: too small to find a ball in")
    binned = noise_bins(lum)
    curve = noise_curve(lum, binned=binned)
    g = stabilise(lum, curve=curve)
    spots = _highlights(lum) if highlight else []
    seeds = _seeds(g, spots)
    if spots:
        # a flash by the lens lights the ball near its middle: circles of several sizes around
        # the highlight too (the rim is often too faint for the Hough transforms)
        m = min(h, w)
        seeds += [(spots[0][0], spots[0][1], f * m) for f in HIGHLIGHT_SEED_SIZES if f * m >= MIN_RADIUS_PX]
    if not seeds:
        return BallFit(0, 0, 0, False, "no ball: no circular edge in the image")
    fits = _fits(lum, g, _candidates(g, seeds, spots), fov_deg, curve, mirror=highlight)
    return _choose(fits, lum if highlight else None, g, clipped, spots[0] if spots else None, curve, binned)


#: :func:`snap` looks for the outline within this share of the radius of the circle marked …
SNAP_REACH = 0.1
#: … and this many pixels more (a circle dragged by hand at the photo's full view is a few px off)
SNAP_REACH_PX = 4.0
#: the snap's starts: the circle marked, then its radius changed by these shares of the reach
SNAP_RADII = (0.0, -0.5, 0.5)


def snap(px: np.ndarray, circle, fov_deg: float | None = None) -> BallFit:
    """The mirror ball's outline near a circle marked by hand (``circle``: cx, cy, r in pixels,
    ProbeLight's convention): step 3 of :func:`find_ball` (:func:`_subpixel`, the sector fit and
    where it does not close the polished outline) started from that circle, with its verdict —
    ``confident`` when the outline closes (step 4's support and gap, or tight) and is a mirror's
    rim (not a line nor a disc on the backdrop, :func:`_not_a_rim`), ``reason`` otherwise.  A
    person has said which circle is the ball, so the finder's choice among candidates (step 5)
    is not made.  The fit starts from the circle marked and from it a little smaller and larger
    (``SNAP_RADII``) and must end within ``SNAP_REACH`` × r + ``SNAP_REACH_PX`` of it (farther,
    it followed another edge: not taken; none within: the circle marked comes back, not
    confident, its ``residual_px`` infinite, saying so).

    Only the circle's neighbourhood is read (its noise measured there): a camera's 21-megapixel
    probe snaps in about a second.  benchmarks/bench_paris_snap.py: circles 3 px off on the
    varied probes at 3× (1.4–6.4° off), the snapped direction's error and how often it is sure."""
    cx, cy, r = (float(v) for v in circle)
    px = np.asarray(px)
    h, w = px.shape[:2]
    if not (np.all(np.isfinite((cx, cy, r))) and r >= MIN_RADIUS_PX):
        return BallFit(cx, cy, r, False, f"the circle marked (radius {r:.1f} px) is too small to snap to "
                                         f"(at least {MIN_RADIUS_PX:.0f} px)")
    reach = SNAP_REACH * r + SNAP_REACH_PX

    def around(m):
        return (slice(min(max(int(np.floor(cy - m)), 0), h), min(max(int(np.ceil(cy + m)) + 1, 0), h)),
                slice(min(max(int(np.floor(cx - m)), 0), w), min(max(int(np.ceil(cx + m)) + 1, 0), w)))

    # the sector profiles and the polish reach 4 px past the outline, the gradients 5 px more;
    # the mirror-rim checks read the backdrop out to a radius beyond it (_unreflected)
    box, wide = around(r + reach + 12.0), around(2 * (r + reach) + 4.0)
    if min(px[box].shape[:2]) < 16:
        return BallFit(cx, cy, r, False, "the circle marked is not on the photo")
    # the photo's size for the geometry (the cone's principal point, what is in the frame), its
    # pixels only round the circle (np.zeros: the rest of a large photo is never touched)
    lum, g = np.zeros((h, w)), np.zeros((h, w))
    lum[wide] = luminance(px[wide])
    curve = noise_curve(lum[box])
    g[box] = stabilise(lum[box], curve=curve)
    outline = _Outline(g, fov_deg, curve, mirror=True, box=box)
    # from the circle marked and from circles a little smaller and larger (a circle dragged off
    # centre crosses the outline: part of it lies inside, on the reflection's edges)
    fits = []
    for dr in SNAP_RADII:
        f = _subpixel(lum, g, _NOISE, {"cx": cx, "cy": cy, "r": r + dr * reach}, fov_deg, outline)
        if np.all(np.isfinite((f.cx, f.cy, f.r))) and np.hypot(f.cx - cx, f.cy - cy) + abs(f.r - r) <= reach:
            fits.append(f)
            if f.confident:
                break
    if not fits:
        # every fit ended on another edge: the circle marked is kept, with no outline
        return BallFit(cx, cy, r, False, f"no outline within {reach:.1f} px of the circle marked (the fit went "
                                         f"to another edge: {f.summary()})")
    fit = max(fits, key=lambda f: (f.confident, f.support, -f.residual_px))
    not_rim = _not_a_rim(fit, lum, g, curve) if fit.confident else ""
    if not_rim:
        fit.confident, fit.reason = False, not_rim
    elif not fit.confident and not fit.reason:
        fit.reason = f"the outline near the circle marked is not closed ({fit.summary()})"
    return fit


def _candidates(g, seeds, spots) -> list[dict]:
    """Steps 1–2: the distinct circles near the seeds with loose support (holding one of the
    highlight ``spots`` when there are any)."""
    circles = []
    for x0, y0, r0 in seeds:
        for c in _circles_near(g, _NOISE, x0, y0, r0):
            if not any(_same(c, d) for d in circles):
                circles.append(c)
    loose = [c for c in circles if c["support"] >= LOOSE_SUPPORT and c["r"] >= MIN_RADIUS_PX]
    if spots:
        loose = [c for c in loose if _holds(c, spots)]
    return loose


def _fits(lum, g, circles, fov_deg, curve=None, mirror=True) -> list[BallFit]:
    """Steps 3–4: the circles fitted sub-pixel, the best supported of twins kept."""
    fits: list[BallFit] = []
    outline = _Outline(g, fov_deg, curve, mirror)
    for c in circles:
        f = _subpixel(lum, g, _NOISE, c, fov_deg, outline)
        if not np.isfinite(f.residual_px):
            continue
        twin = [i for i, o in enumerate(fits) if _same(f, o)]
        if not twin:
            fits.append(f)
        elif f.support > fits[twin[0]].support:
            fits[twin[0]] = f
    return fits


def _choose(fits: list[BallFit], lum, g, clipped, spot, curve=None, binned=None) -> BallFit:
    """Step 5: the ball among the fitted circles, with why it may not be (``spot``: the
    flash's highlight (x, y), the largest clipped blob, or None; ``lum``: the linear
    luminance of a mirror-ball photo, None for a white ball)."""
    where = " around the highlight" if spot is not None else ""
    cand = [(round(f.cx, 1), round(f.cy, 1), round(f.r, 1), round(f.support, 2)) for f in fits]
    closed = [f for f in fits if (f.support >= MIN_SUPPORT and f.max_gap_deg <= MAX_GAP_DEG
                                  or _tight(f.support, f.max_gap_deg, f.residual_px)) and f.r >= MIN_RADIUS_PX]
    if not closed:
        best = max(fits, key=lambda f: f.support, default=None)
        if best is None:
            return BallFit(0, 0, 0, False, f"no ball: no closed circular outline{where}")
        best.confident = False
        best.reason = f"no ball: no closed circular outline{where} (best: {best.summary()})"
        best.candidates = cand
        return best
    # families of circles (a ball and the edges of its own reflection inside it): the
    # outermost closed circle is the ball
    closed.sort(key=lambda f: -f.r)
    balls = []
    for f in closed:
        if not any(_contains(b, f) for b in balls):
            balls.append(f)
    best, rivals = _rank(balls, spot)
    best.candidates = cand
    doubt = _doubt(best, fits, lum, g, clipped, curve, binned)
    if not doubt:
        doubt, inner = _shadow_around(best, closed, spot)
        if inner is not None:
            best.start = (inner.cx, inner.cy, inner.r)
    if rivals and not doubt:
        # only rivals speak against it: a caller may still weigh them (ProbeLight: by the
        # directions they give)
        best.rivals = [(f.cx, f.cy, f.r) for f in rivals] if best.confident else []
        o = rivals[0]
        doubt = (f"two closed outlines that are not one ball: radius {best.r:.1f} px at ({best.cx:.1f}, "
                 f"{best.cy:.1f}) and radius {o.r:.1f} px at ({o.cx:.1f}, {o.cy:.1f})")
    if doubt:
        best.confident, best.reason = False, doubt
    return best


def _shadow_around(best: BallFit, closed: list[BallFit], spot) -> tuple[str, BallFit | None]:
    """Why ``best``, the outermost closed outline, may be the ball's cast shadow around it ('' if
    nothing says so), and the outline inside it that may be the ball (else None): inside it, off
    its centre by over ``SHADOW_OFFSET`` of its radius, a closed outline better supported by
    ``AMBIGUITY`` whose centre is nearer the flash's highlight (a flash beside the lens casts the
    ball's shadow on the backdrop a little aside: a larger disc whose soft edge closes round the
    ball, tv37 at 6×, 9° off with exit 0 without this)."""
    if not best.confident or spot is None:
        return "", None
    for f in closed:
        if (f.r < best.r and _contains(best, f)
                and np.hypot(f.cx - best.cx, f.cy - best.cy) > SHADOW_OFFSET * best.r
                and f.support >= best.support + AMBIGUITY and _off_centre(f, spot) < _off_centre(best, spot)):
            return (f"a closed outline inside the one found ({best.summary()}), better supported and off its "
                    f"centre (radius {f.r:.1f} px at ({f.cx:.1f}, {f.cy:.1f}), edge on {100 * f.support:.0f}%): "
                    "the outer one may be the ball's cast shadow round it"), f
    return "", None


#: an outline inside the outermost closed one, off its centre by more than this share of its
#: radius, is not an edge of the ball's own reflection but may be the ball (``_shadow_around``)
SHADOW_OFFSET = 0.05


def _rank(balls: list[BallFit], spot) -> tuple[BallFit, list[BallFit]]:
    """The ball and its rivals: the best supported, or among those as well supported (within
    AMBIGUITY) the one whose centre is nearest the flash's highlight (in radii); rivals are
    those not beaten by CENTRED_MARGIN in that (a flash by the lens lights the ball near its
    middle, while the ball's shadow on the backdrop, or a round outline of the backdrop, is
    centred elsewhere)."""
    balls = sorted(balls, key=lambda f: -f.support)
    top = [f for f in balls if f.support >= balls[0].support - AMBIGUITY]
    if spot is None or len(top) < 2:
        return top[0], top[1:]
    top.sort(key=lambda f: _off_centre(f, spot))
    return top[0], [f for f in top[1:] if _off_centre(f, spot) - _off_centre(top[0], spot) < CENTRED_MARGIN]


def _off_centre(f: BallFit, spot) -> float:
    return float(np.hypot(spot[0] - f.cx, spot[1] - f.cy) / max(f.r, 1e-9))


def _doubt(best: BallFit, fits: list[BallFit], lum, g, clipped, curve=None, binned=None) -> str:
    """Why ``best``, while its own fit is confident, may not be the ball ('' if nothing speaks
    against it): clipped pixels just outside it, a rim that is not a mirror's (``lum``: the
    linear luminance of a mirror-ball photo, :func:`_unreflected`), or a fainter circle around it (among the
    ``fits``, or a concentric edge on the stabilised image ``g`` up to 1.4 radii out: a
    mirror ball's rim, reflecting the backdrop behind it, can be too faint to be a candidate
    while an edge of its reflection inside is closed)."""
    if not best.confident:
        return ""
    ring = _ring_fraction(clipped, best, 1.0, 0.25)
    if ring > 0.2:
        return (f"{100 * ring:.0f}% of the pixels just outside the outline found ({best.summary()}) "
                "are clipped: the ball's silhouette may be lost in them (over-exposed)")
    not_rim = _not_a_rim(best, lum, g, curve)
    if not_rim:
        return not_rim
    around = [f for f in fits if f.r > best.r + 2 and _concentric(f, best)]
    if lum is not None:
        # on the image stabilised by the honest noise level (noise_curve's isotonic fit): with
        # the lower envelope, a render's smooth bright reflections can set the noise of its
        # backdrop several times too low, and every circle round the ball then has "edges"
        # (tv24x3: on 70–90 % of every circle 5 px to 1.4 radii out; 4–13 % with the honest level)
        g = stabilise(lum, curve=noise_curve(lum, isotonic=True, binned=binned))
        around = [(f.r, _support(g, _NOISE, f.cx, f.cy, f.r)[0]) for f in around]
    else:
        around = [(f.r, f.support) for f in around]
    outer = [(r, sup) for r, sup in around if sup >= LOOSE_SUPPORT] + _outer_edges(g, best)
    if not outer:
        return ""
    r, sup = max(outer, key=lambda o: o[1])
    return (f"a fainter circle of radius {r:.1f} px (edge on {100 * sup:.0f}%) surrounds "
            f"the outline found (radius {best.r:.1f} px): which one is the ball is unclear")


def _not_a_rim(f: BallFit, lum, g, curve=None) -> str:
    """Why the outline ``f`` is not a mirror ball's silhouette ('' if nothing says so): a thin
    line with the same level on both sides (:func:`_line_profile`), or just inside it an image
    brighter or darker than a mirror's rim can be (:func:`_unreflected`; ``lum`` None: not asked)."""
    ridge, step = _line_profile(g, f)
    if ridge >= EDGE_SNR and ridge > LINE_RATIO * step:
        return (f"the outline found ({f.summary()}) is a thin line with the same level on both sides "
                f"(it rises {ridge:.0f} noise σ and steps {step:.1f}): a ring on the backdrop, not the ball's edge")
    if lum is not None:
        share, way = _unreflected(lum, f, curve=curve)
        if share >= NOT_MIRROR:
            return (f"just inside the outline found ({f.summary()}) the image is {way} than a mirror ball's rim "
                    f"can be on {100 * share:.0f}% of it (a mirror's rim reflects the backdrop beyond its outline): "
                    "a disc or band on the backdrop, not the ball's edge")
    return ""


def _line_profile(g, f: BallFit) -> tuple[float, float]:
    """(ridge, step) across the outline ``f`` on the stabilised image ``g`` (pixel noise σ;
    medians over the 8° sectors inside the frame): ``step``, the difference between the levels
    4–6 px outside and 4–6 px inside; ``ridge``, the most the band within 2 px of the outline
    departs from their mean.  A silhouette is a step (ridge about half the step, at most the
    step: 0.5-1.0 on make_probes' TUNING probes); a line drawn on the backdrop around the ball
    (a printed ring) rises and falls back to the same level (ridge/step 100-200 on the
    synthetic rings of tests/test_paris_probe_ring.py)."""
    ts = np.arange(f.r - 6, f.r + 6 + 1e-9, 0.5)
    prof, _, valid = _polar(g, f.cx, f.cy, ts)
    prof, valid = _sectors(prof, valid)
    ok = valid.all(1)
    if not ok.any():
        return 0.0, 0.0
    inn, out = prof[ok][:, ts <= f.r - 4].mean(1), prof[ok][:, ts >= f.r + 4].mean(1)
    ridge = np.abs(prof[ok][:, np.abs(ts - f.r) <= 2] - 0.5 * (inn + out)[:, None]).max(1)
    return float(np.median(ridge)), float(np.median(np.abs(out - inn)))


def _unreflected(lum, f: BallFit, both=False, curve=None) -> tuple:
    """(fraction, "brighter" or "darker"): the share of the 8° sectors of the outline ``f``
    (inside the frame) whose rim — the band 1–2 px inside — a mirror ball could not show.  At
    its silhouette a mirror ball's reflected rays graze it: the rim shows the backdrop *beyond*
    the outline (radially squeezed: t px inside shows the backdrop about c·√t px outside, c set
    by the backdrop's distance), times the ball's reflectance (``MIN_REFLECTANCE`` … 1).  So in
    a sector the rim is neither brighter than the brightest of the backdrop 1 px to one radius
    outside along its rays, nor darker than ``MIN_REFLECTANCE`` × its darkest, each by over 3
    noise σ (linear luminance; σ from :func:`noise_curve`).  A disc or wide band printed on the
    backdrop around the ball has a step at its edge like a silhouette, but inside it the
    print's own level, no reflection: on the synthetic discs of tests/test_paris_probe_ring.py
    every sector breaks the bound.  A true rim may reflect backdrop from further out, brighter
    or darker (a checked backdrop's squares, another lamp's light): up to 33 % of the sectors
    on the tune probes (make_probes' TUNING, found; varied_probes' tune half, true circle), 38 %
    on the CHECK probes (found; read after choosing ``NOT_MIRROR``).  ``both``: (brighter
    share, darker share) instead; ``curve``: :func:`noise_curve` of ``lum``, if known."""
    x, sg = curve if curve is not None else noise_curve(lum)
    ts = np.arange(f.r - 2, 2 * f.r + 1 + 1e-9, 0.5)
    prof, _, valid = _polar(lum, f.cx, f.cy, ts)
    prof, valid = _sectors(prof, valid)
    rim, out = ts <= f.r - 1, ts >= f.r + 1
    ok = valid[:, rim].all(1) & (valid[:, out].sum(1) >= 4)
    if not ok.any():
        return (0.0, 0.0) if both else (0.0, "")
    a = prof[ok][:, rim].mean(1)
    beyond = np.where(valid[ok][:, out], prof[ok][:, out], np.nan)
    # the rim band's noise: one pixel's σ over the ~0.14 r pixels of an 8° arc
    tol = 3.0 * np.interp(a, x, sg) / np.sqrt(max(0.14 * f.r, 1.0))
    brighter = float(np.mean(a > np.nanmax(beyond, 1) + tol))
    darker = float(np.mean(a < MIN_REFLECTANCE * np.nanmin(beyond, 1) - tol))
    if both:
        return brighter, darker
    return max((brighter, "brighter"), (darker, "darker"))


def _darker_share(lum, f, curve=None) -> float:
    """The share of ``f``'s sectors whose rim is darker than a mirror's can be
    (:func:`_unreflected`)."""
    return _unreflected(lum, f, both=True, curve=curve)[1] if f.r > 2 else 0.0


def _outer_edges(g, best: BallFit) -> list[tuple[float, float]]:
    """(radius, support) of circles concentric with ``best``, from 5 px (clear of its own
    edge: the 2-px step and TOL_PX) to 1.4 radii out, on which an edge runs over OUTER_SUPPORT
    of the outline."""
    out = []
    for r in np.arange(best.r + 5, 1.4 * best.r, TOL_PX):
        sup, gap, _ = _support(g, _NOISE, best.cx, best.cy, r)
        if sup >= OUTER_SUPPORT and gap <= MAX_GAP_DEG:
            out.append((float(r), sup))
    return out


# ---------------------------------------------------------------------------------------------

def noise_curve(lum, bins=24, min_count=30, isotonic=False, binned=None):
    """(levels, σ) of the pixel noise of a linear image against brightness: the robust spread
    (MAD) of 2×2 second differences in brightness bins spaced evenly in log, made non-
    decreasing by its lower envelope (the noise of a camera grows with the signal; texture only
    inflates a bin).  The clipped plateau is left out.

    ``isotonic``: made non-decreasing instead by the nearest non-decreasing curve weighted by the
    bins' pixel counts.  The lower envelope lets a few smooth bright pixels set the noise of every
    darker level: on a render, whose Monte Carlo noise does not grow with the signal, a mirror
    ball's smooth bright reflections (0.1 % of tv42x3's pixels) set its backdrop's noise 7 × too
    low.  The finder's thresholds (``EDGE_SNR``, the supports) were set with the envelope, so it
    stays the default; :func:`_doubt` looks for circles round the ball with the isotonic one.
    ``binned``: :func:`noise_bins` of ``lum`` with these ``bins`` and ``min_count``, if known
    (both curves come from the same bins)."""
    x, sg, n = binned if binned is not None else noise_bins(lum, bins, min_count)
    if n is None:
        return x, sg
    if isotonic:
        from scipy.optimize import isotonic_regression

        sg = isotonic_regression(sg, weights=n).x            # nearest non-decreasing, by pixel count
    else:
        sg = np.minimum.accumulate(sg[::-1])[::-1]                 # lower non-decreasing envelope
    sg = np.maximum(sg, 1e-4 * max(float(np.percentile(lum, 99.5)), 1e-12))
    return x, sg


def noise_bins(lum, bins=24, min_count=30):
    """The binned noise of :func:`noise_curve` before it is made non-decreasing: (median level,
    robust σ, pixel count) per brightness bin with ``min_count`` pixels or more — or (levels,
    σ, None), a flat curve, when there are too few pixels.  The pixels are grouped by bin in one
    stable sort (each bin's values in the image's order, as a mask per bin would take them: the
    same medians), not one pass over the image per bin (a 20-megapixel probe's 24 passes took 4 s)."""
    from scipy import ndimage

    d = (lum[1:, 1:] - lum[1:, :-1] - lum[:-1, 1:] + lum[:-1, :-1]) / 2.0   # σ of one pixel
    lev = ndimage.uniform_filter(lum, 2)[1:, 1:]
    top = float(lum.max())
    flat = lev < 0.98 * top
    d, lev = d[flat], lev[flat]
    if d.size < min_count:
        return np.array([0.0, max(top, 1e-12)]), np.full(2, max(1e-4 * top, 1e-12)), None
    p_lo, p_hi = np.percentile(lev, [0.5, 99.5])  # one partition for both (the same values as two calls)
    lo = max(float(p_lo), 1e-4 * max(float(p_hi), 1e-12), 1e-12)
    hi = max(float(lev.max()), lo * 1.001)
    edges = np.geomspace(lo, hi, bins + 1)
    idx = np.clip(np.searchsorted(edges, lev, side="right") - 1, 0, bins - 1)
    order = np.argsort(idx.astype(np.uint8 if bins <= 256 else np.int64), kind="stable")
    counts = np.bincount(idx, minlength=bins)
    ends = np.cumsum(counts)
    d, lev = d[order], lev[order]
    x, sg, n = [], [], []
    for b in range(bins):
        if counts[b] >= min_count:
            sel = slice(int(ends[b] - counts[b]), int(ends[b]))
            x.append(float(np.median(lev[sel])))
            sg.append(1.4826 * float(np.median(np.abs(d[sel]))))
            n.append(int(counts[b]))
    if not x:
        sg0 = max(1.4826 * float(np.median(np.abs(d))), 1e-12)
        return np.array([0.0, max(top, 1e-12)]), np.full(2, sg0), None
    return np.array(x), np.array(sg), np.array(n, float)


def stabilise(lum, isotonic=False, curve=None):
    """Brightness transformed so that the pixel noise has unit σ at every level:
    T(x) = ∫ dx / σ(x) with σ from :func:`noise_curve` (a generalised Anscombe transform;
    monotone, so edges stay edges and a step's height in T is its height in noise σ)."""
    x, sg = curve if curve is not None else noise_curve(lum, isotonic=isotonic)
    grid = np.concatenate([[0.0], np.geomspace(max(x[0] * 1e-3, 1e-12), max(float(lum.max()), x[-1]) * 1.01, 512)])
    sgrid = np.interp(grid, x, sg)
    t = np.concatenate([[0.0], np.cumsum(np.diff(grid) * 0.5 * (1 / sgrid[1:] + 1 / sgrid[:-1]))])
    return np.interp(np.clip(lum, 0, None), grid, t)


def _highlights(lum, max_blobs=8):
    """Centroids of the largest blobs of clipped pixels (≥ 98 % of the image maximum); none
    when over a fifth of the image is clipped."""
    from scipy import ndimage

    peak = float(lum.max())
    if peak <= 0:
        return []
    m = lum >= 0.98 * peak
    if m.mean() > 0.2:
        return []
    lab, n = ndimage.label(m)
    if n == 0:
        return []
    idx = np.arange(1, n + 1)
    sizes = np.bincount(lab.ravel(), minlength=n + 1)[1:].astype(np.float64)  # ndimage.sum's counts
    top = idx[np.argsort(-sizes)[:max_blobs]]
    # each blob's centroid read in its own box (ndimage.center_of_mass over the whole photo took
    # 1.2 s at 21.7 MP): sums of integer coordinates, exact in float64, so the same values
    boxes = ndimage.find_objects(lab, max_label=int(top.max()))
    out = []
    for k in top:
        by, bx = boxes[k - 1]
        ys, xs = np.nonzero(lab[by, bx] == k)
        out.append((float((xs.sum() + bx.start * len(xs)) / sizes[k - 1]) + 0.5,
                    float((ys.sum() + by.start * len(ys)) / sizes[k - 1]) + 0.5))
    return out


def _holds(c, spots):
    cx, cy, r = _xyr(c)
    return any(np.hypot(x - cx, y - cy) < 0.95 * r for x, y in spots)


def _seeds(g, spots, max_seeds=16):
    """Circles of any origin from OpenCV's Hough transforms (the accurate HOUGH_GRADIENT_ALT,
    then HOUGH_GRADIENT for fainter outlines) on the stabilised image brought to at most
    ``SEED_PX`` pixels and smoothed (noise and fine texture make both slow and blind), those
    holding a highlight first → [(x, y, r)] in pixels."""
    import cv2

    h, w = g.shape
    scale = min(1.0, SEED_PX / max(h, w))
    lo, hi = np.percentile(g, [0.5, 99.5])
    img8 = np.round(np.clip((g - lo) / max(hi - lo, 1e-12), 0, 1) * 255).astype(np.uint8)
    if scale < 1:
        img8 = cv2.resize(img8, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    img8 = cv2.GaussianBlur(img8, (5, 5), 1.0)
    ms = min(img8.shape)
    r_lo, r_hi = max(int(MIN_RADIUS_PX * scale * 0.8), int(0.04 * ms), 3), int(0.6 * ms)
    seeds = []
    for method, p1, p2 in ((cv2.HOUGH_GRADIENT_ALT, 150, 0.5), (cv2.HOUGH_GRADIENT_ALT, 80, 0.3),
                           (cv2.HOUGH_GRADIENT, 60, 40), (cv2.HOUGH_GRADIENT, 60, 25), (cv2.HOUGH_GRADIENT, 60, 15)):
        cs = cv2.HoughCircles(img8, method, dp=1, minDist=max(4, int(0.04 * ms)), param1=p1, param2=p2,
                              minRadius=r_lo, maxRadius=r_hi)
        if cs is not None:
            seeds += [((x + 0.5) / scale, (y + 0.5) / scale, r / scale) for x, y, r in cs[0][:max_seeds]]
    if spots:
        # the highlight is inside the ball: seeds whose circle holds it come first
        seeds.sort(key=lambda s: not _holds({"cx": s[0], "cy": s[1], "r": s[2]}, spots))
    out = []
    for s in seeds:
        if not any(abs(s[0] - o[0]) < 0.1 * o[2] and abs(s[1] - o[1]) < 0.1 * o[2] and abs(s[2] / o[2] - 1) < 0.15
                   for o in out):
            out.append(s)
    return out[:max_seeds]


def _polar(img, x0, y0, ts, n_rays=N_RAYS, arc_px=1.0, taps=3):
    """Profiles of img along n_rays rays from (x0, y0) at radii ts, each averaged over `taps`
    samples spread ±arc_px along the arc (bilinear).  → (profiles (n_rays, len(ts)), angles,
    in-frame mask of the same shape)."""
    from scipy import ndimage

    h, w = img.shape
    ang = np.arange(n_rays) * 2 * np.pi / n_rays
    r_ref = max(float(np.median(ts)), 1.0)
    offs = (np.arange(taps) - (taps - 1) / 2) * (arc_px / r_ref)
    acc = 0.0
    valid = np.ones((n_rays, len(ts)), bool)
    for o in offs:
        a = ang[:, None] + o
        xs = x0 + ts[None] * np.cos(a)
        ys = y0 + ts[None] * np.sin(a)
        valid &= (xs >= 0.5) & (xs <= w - 0.5) & (ys >= 0.5) & (ys <= h - 0.5)
        acc = acc + ndimage.map_coordinates(img, [ys - 0.5, xs - 0.5], order=1, mode="nearest")
    return acc / taps, ang, valid


def _circles_near(g, noise, x0, y0, r0, step=0.5):
    """Closed-circle candidates from edge points on rays around (x0, y0)."""
    ts = np.arange(max(2.0, 0.35 * r0), 1.9 * r0, step)
    prof, ang, valid = _polar(g, x0, y0, ts)
    s = _edge_snr(prof, valid, step, noise)
    peak = (s[:, 1:-1] >= s[:, :-2]) & (s[:, 1:-1] > s[:, 2:]) & (s[:, 1:-1] >= EDGE_SNR)
    # the strongest few peaks of each ray
    sp = np.where(peak, s[:, 1:-1], 0)
    top = np.argsort(-sp, axis=1)[:, :PEAKS_PER_RAY]
    keep = np.zeros_like(peak)
    np.put_along_axis(keep, top, True, axis=1)
    ri, ti = np.nonzero(peak & keep)
    ti = ti + 1
    if len(ri) < 8:
        return []
    pts_t = ts[ti]
    px = x0 + pts_t * np.cos(ang[ri])
    py = y0 + pts_t * np.sin(ang[ri])
    wgt = np.minimum(s[ri, ti], 12.0)
    out = []
    used = np.zeros(len(ri), bool)
    rng = np.random.default_rng(0)
    for _ in range(3):
        c = _ransac(px, py, ri, wgt, used, rng, r0)
        if c is None:
            break
        cx, cy, r = c
        sup, gap, _ = _support(g, noise, cx, cy, r)
        out.append({"cx": cx, "cy": cy, "r": r, "support": sup, "gap": gap})
        used |= np.abs(np.hypot(px - cx, py - cy) - r) < 2 * TOL_PX
    return out


def _edge_snr(prof, valid, step, noise, taps=3):
    """|p(t + 1 px) − p(t − 1 px)| / its noise (the profiles are means of `taps` samples)."""
    k = int(round(1.0 / step))
    s = np.zeros_like(prof)
    s[:, k:-k] = np.abs(prof[:, 2 * k:] - prof[:, :-2 * k]) / (noise * np.sqrt(2.0 / taps))
    ok = np.zeros_like(valid)
    ok[:, k:-k] = valid[:, 2 * k:] & valid[:, :-2 * k]
    s[~ok] = 0
    return s


def _ransac(px, py, ray, wgt, used, rng, r0, iters=250):
    free = np.nonzero(~used)[0]
    if len(free) < 8:
        return None
    i = rng.choice(free, size=(iters, 3))
    x1, y1, x2, y2, x3, y3 = px[i[:, 0]], py[i[:, 0]], px[i[:, 1]], py[i[:, 1]], px[i[:, 2]], py[i[:, 2]]
    den = 2 * (x1 * (y2 - y3) + x2 * (y3 - y1) + x3 * (y1 - y2))
    good = np.abs(den) > 1e-6
    den = np.where(good, den, 1)
    s1, s2, s3 = x1 * x1 + y1 * y1, x2 * x2 + y2 * y2, x3 * x3 + y3 * y3
    cx = (s1 * (y2 - y3) + s2 * (y3 - y1) + s3 * (y1 - y2)) / den
    cy = (s1 * (x3 - x2) + s2 * (x1 - x3) + s3 * (x2 - x1)) / den
    r = np.hypot(x1 - cx, y1 - cy)
    good &= (r > 0.3 * r0) & (r < 2.0 * r0)
    if not good.any():
        return None
    cx, cy, r = cx[good], cy[good], r[good]
    dist = np.abs(np.hypot(px[free][None] - cx[:, None], py[free][None] - cy[:, None]) - r[:, None])
    inl = dist < TOL_PX
    # score: distinct rays with an inlier (a ray counts once, with its strongest inlier)
    rays = ray[free]
    order = np.argsort(rays, kind="stable")
    starts = np.nonzero(np.r_[True, np.diff(rays[order]) > 0])[0]
    wm = np.where(inl[:, order], wgt[free][order][None], 0.0)
    score = np.maximum.reduceat(wm, starts, axis=1).sum(1)
    j = int(np.argmax(score))
    if score[j] <= 0:
        return None
    sel = free[inl[j]]
    c = _lsq_circle(px[sel], py[sel])
    for _ in range(3):
        dist = np.abs(np.hypot(px - c[0], py - c[1]) - c[2])
        sel = np.nonzero((dist < TOL_PX) & ~used)[0]
        if len(sel) < 8:
            break
        c = _lsq_circle(px[sel], py[sel])
    return c


def _lsq_circle(x, y, wgt=None):
    a = np.column_stack([x, y, np.ones_like(x)])
    b = x * x + y * y
    if wgt is not None:
        a, b = a * wgt[:, None], b * wgt
    sol = np.linalg.lstsq(a, b, rcond=None)[0]
    cx, cy = sol[0] / 2, sol[1] / 2
    return float(cx), float(cy), float(np.sqrt(max(sol[2] + cx * cx + cy * cy, 0)))


def _sectors(prof, valid, per=None):
    """Ray profiles averaged over sectors of `per` neighbouring rays (the noise falls by √per
    while the silhouette, at the same radius on every ray, stays sharp) → (profiles, valid)."""
    per = per or RAYS_PER_SECTOR
    n, t = prof.shape
    return prof.reshape(n // per, per, t).mean(1), valid.reshape(n // per, per, t).all(1)


def _support(g, noise, cx, cy, r):
    """(fraction of in-frame sectors with an edge within TOL_PX of radius r, largest gap in
    degrees, per-sector bool)."""
    n_sec = N_RAYS // RAYS_PER_SECTOR
    ts = np.arange(r - 3 * TOL_PX, r + 3 * TOL_PX + 1e-9, 0.5)
    if ts[0] <= 1:
        return 0.0, 360.0, np.zeros(n_sec, bool)
    prof, ang, valid = _polar(g, cx, cy, ts)
    prof, valid = _sectors(prof, valid)
    s = _edge_snr(prof, valid, 0.5, noise, taps=3 * RAYS_PER_SECTOR)
    near = np.abs(ts - r) <= TOL_PX
    inside = valid[:, np.abs(ts - r) <= TOL_PX + 1.0].all(1)   # the samples the test needs
    # a significant step within TOL_PX of r (not necessarily the strongest nearby: a mirror
    # ball's rim often darkens or brightens steeply just inside its silhouette)
    on = inside & (np.where(near[None], s, 0).max(1) >= EDGE_SNR)
    n_in = int(inside.sum())
    if n_in < MIN_IN_FRAME * n_sec:
        return 0.0, 360.0, on
    sup = float(on.sum()) / n_in
    gap = _longest_run(inside & ~on) * 360.0 / n_sec
    return sup, gap, on


def _longest_run(m):
    if not m.any():
        return 0
    if m.all():
        return len(m)
    mm = np.concatenate([m, m])
    best = run = 0
    for v in mm:
        run = run + 1 if v else 0
        best = max(best, run)
    return min(best, len(m))


def _xyr(c):
    return (c["cx"], c["cy"], c["r"]) if isinstance(c, dict) else (c.cx, c.cy, c.r)


def _same(a, b):
    (ax, ay, ar), (bx, by, br) = _xyr(a), _xyr(b)
    return np.hypot(ax - bx, ay - by) < 1.0 and abs(ar - br) < 1.0


def _concentric(outer, inner):
    """inner is concentric with outer and not larger."""
    (ox, oy, orr), (ix, iy, ir) = _xyr(outer), _xyr(inner)
    return np.hypot(ox - ix, oy - iy) < 0.15 * orr and ir <= orr + 1.0


def _contains(outer, inner):
    """inner is part of the ball outer: concentric with it (an edge of its reflection), or
    wholly inside it (a round feature of its content, the flash's halo)."""
    (ox, oy, orr), (ix, iy, ir) = _xyr(outer), _xyr(inner)
    return _concentric(outer, inner) or np.hypot(ox - ix, oy - iy) + ir <= orr + 1.0


def _subpixel(lum, g, noise, c, fov_deg, outline=None):
    """Sub-pixel silhouette, in two passes.  (a) Per sector of rays, the steepest point of the
    (sector-averaged) linear luminance profile within 1.5 px of the circle (parabolic peak of
    the gradient); robust circle (or cone) fit; iterated from the candidate circle.  (b) The
    outline polished (:class:`_Outline`): from the candidate and from (a), the circle (cone)
    along which the stabilised image's radial gradient is strongest, sector by sector — the
    rim's step, averaged round the whole outline, stands out of the noise where no single
    sector's does, and the nearest edge of (a) may be one of the reflection just inside.  Its
    support, gap and residual are read from the edges about the polished outline.  (b) is
    taken where (a) is not confident (where it is, its answers are kept as they were)."""
    h, w = lum.shape
    cx, cy, r = _xyr(c)
    good = np.zeros(0, bool)
    for it in range(8):
        te, ang, inside = _sector_edges(lum, g, noise, cx, cy, r, it)
        good = np.isfinite(te)
        if good.sum() < 8:
            break
        ex, ey = cx + te * np.cos(ang), cy + te * np.sin(ang)
        nc, res, keep = _robust_fit(ex, ey, good, w, h, fov_deg)
        moved = np.hypot(nc[0] - cx, nc[1] - cy) + abs(nc[2] - r)
        cx, cy, r = nc
        if moved < 0.01 and it > 0:
            break
    if good.sum() >= 8:
        rms = float(np.sqrt(np.mean(res[keep] ** 2)))
        # support: sectors (inside the frame) whose edge is on the fitted outline and significant
        _, _, on = _support(g, noise, cx, cy, r)
        res = _residual(ex, ey, (cx, cy, r), w, h, fov_deg)
        fit = _verdict(cx, cy, r, on & good & (np.abs(res) <= SNAP_PX), inside, rms, w, h)
        fit.sigma_px = rms * np.sqrt(2.0 / max(int(keep.sum()), 1))
        if outline is None or outline.mirror:
            # (a rim darker all round, over NOT_MIRROR of it, is a disc printed round the
            # ball: _doubt names that)
            _veto_cast_shadow(lum, fit, outline.curve if outline is not None else None, upto=NOT_MIRROR)
        if fit.confident:
            return fit
    else:
        fit = BallFit(float(cx), float(cy), float(r), False, "too few edge points on the outline")
    # (b) where (a) does not close, the polished outline
    outline = outline if outline is not None else _Outline(g, fov_deg)
    starts = [_xyr(c)] + ([(cx, cy, r)] if good.sum() >= 8 and np.all(np.isfinite((cx, cy, r))) else [])
    polished = max((outline.polish(s) for s in starts), key=outline.score)
    if outline.score(polished) <= 0:
        return fit
    p = outline.verdict(g, noise, polished, w, h)
    p.polished = True
    if outline.mirror:
        _veto_cast_shadow(lum, p, outline.curve)
    return p if p.confident or p.support >= fit.support else fit


def _veto_cast_shadow(lum, fit: BallFit, curve=None, upto: float = np.inf) -> None:
    """A confident outline of a mirror ball (a sector fit or a polished one) whose rim is darker
    than a mirror's can be on ``MAX_DARKER_SHARE`` of its sectors (and less than ``upto``)
    follows the edge of the ball's cast shadow along a side: made not confident, with the
    reason."""
    if not fit.confident:
        return
    dk = _darker_share(lum, fit, curve)
    if MAX_DARKER_SHARE <= dk < upto:
        fit.confident = False
        fit.reason = (f"just inside the outline found ({fit.summary()}) the image is darker than a mirror ball's rim "
                      f"can be on {100 * dk:.0f}% of it (a mirror's rim reflects the backdrop beyond its outline): "
                      "the edge of the ball's cast shadow, not its silhouette")


#: a sector's radial gradient (stabilised image: noise σ per pixel) counts up to this in the
#: outline's score, so that a few sectors against a bright lamp or a deep shadow do not outweigh
#: the rest of the outline
SCORE_CAP = 3.0
#: an outline of a mirror ball whose rim — the band 1–2 px inside — is darker than a mirror's rim
#: can be (:func:`_unreflected`) on this share of its sectors follows a cast shadow's edge along a
#: side: not taken.  Set on the tune half at 3× for polished outlines: tv25 (27 %, 2.4 px off: 5.4°
#: with exit 0 without it) and tv33 (18 %, 1.3 px off: 1.1°); the true circles there 0 % and 16 %
#: or less.  Since ProbeLight 13 for sector fits as well: tv33 at 1×, a closed fit 0.53 px off
#: (20 %), came back 1.31° with exit 0; the tune half's answered fits at 1–3× are at 0–4 %
MAX_DARKER_SHARE = 0.1
#: the polishing search's steps (px): centre and radius each way, halving
POLISH_STEPS_PX = (2.0, 1.0, 0.5, 0.25, 0.125)


class _Outline:
    """A ball's outline scored on an image: the mean over the 8° sectors inside the frame of the
    sector-averaged radial gradient |∇g·n| (capped at ``SCORE_CAP``) along the outline of the
    circle (cx, cy, r) — with ``fov_deg``, of the cone tangent to the sphere whose projected
    centre and radius they are (ProbeLight's convention) — on the stabilised image ``g``
    smoothed by a 1-px Gaussian.  Averaging the rim's step along the whole outline finds it where
    it is a fraction of the noise in every sector (benchmarks/bench_paris_outline_polish.py:
    varied_probes' tune half at 3×, from 2 px off, within 0.35 px of the true circle on 7 of 12
    probes, 0.55–0.78 px on two; on a stronger outline beside the rim on three, 1.4–3.6 px off)."""

    def __init__(self, g, fov_deg, curve=None, mirror=True, box=None):
        """``box`` (rows, columns slices): the gradients only there, zero elsewhere (an outline
        looked for near a circle of a many-megapixel photo; the box's last 5 px are its own
        border's, not the photo's)."""
        from scipy import ndimage

        from nodes.common.filters import gaussian_blur   # (SciPy: the same bytes on every CPU)

        self.curve, self.mirror = curve, mirror
        gb = gaussian_blur(np.asarray(g if box is None else g[box], np.float32), 1.0)
        gx = ndimage.sobel(gb, axis=1, mode="reflect") / np.float32(8)
        gy = ndimage.sobel(gb, axis=0, mode="reflect") / np.float32(8)
        if box is None:
            self.gx, self.gy = gx, gy
        else:
            self.gx, self.gy = np.zeros(g.shape, np.float32), np.zeros(g.shape, np.float32)
            self.gx[box], self.gy[box] = gx, gy
        self.h, self.w = g.shape
        self.fov_deg = fov_deg

    def points(self, c, n=N_RAYS):
        """(x, y, nx, ny): n points of the outline of c and their outward unit normals."""
        x, y, nx, ny = self.points_many([c], n)
        return x[0], y[0], nx[0], ny[0]

    def points_many(self, cs, n=N_RAYS):
        """:meth:`points` of several circles → arrays (circles, n)."""
        cs = np.asarray(cs, float).reshape(-1, 3)
        cx, cy, r = cs[:, :1], cs[:, 1:2], cs[:, 2:3]
        phi = np.arange(n) * 2 * np.pi / n
        if self.fov_deg is None:
            x, y = cx + r * np.cos(phi), cy + r * np.sin(phi)
        else:
            f = 0.5 * self.h / np.tan(np.radians(self.fov_deg) / 2)
            a = np.stack([(cs[:, 0] - 0.5 * self.w) / f, (cs[:, 1] - 0.5 * self.h) / f, np.ones(len(cs))], 1)
            dist = np.linalg.norm(a, axis=1, keepdims=True)
            a = a / dist
            al = np.arctan(cs[:, 2:3] / (f * dist))
            # e1 = y × a, e2 = a × e1: an orthonormal frame about the cone's axis
            e1 = np.stack([a[:, 2], np.zeros(len(cs)), -a[:, 0]], 1)
            e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
            e2 = np.cross(a, e1)
            cp, sp = np.cos(phi)[None, :, None], np.sin(phi)[None, :, None]
            d = np.cos(al)[:, :, None] * a[:, None] + np.sin(al)[:, :, None] * (cp * e1[:, None] + sp * e2[:, None])
            x = f * d[..., 0] / d[..., 2] + 0.5 * self.w
            y = f * d[..., 1] / d[..., 2] + 0.5 * self.h
        nx, ny = x - cx, y - cy
        nn = np.maximum(np.hypot(nx, ny), 1e-9)
        return x, y, nx / nn, ny / nn

    def sectors(self, c, offsets=(0.0,)):
        """(sector-averaged ∇g·n at each offset (px) along the normal, (sectors, offsets);
        sectors inside the frame)."""
        from scipy import ndimage

        x, y, nx, ny = self.points(c)
        o = np.asarray(offsets, float)[None]
        xs, ys = x[:, None] + o * nx[:, None], y[:, None] + o * ny[:, None]
        valid = ((xs >= 1) & (xs <= self.w - 2) & (ys >= 1) & (ys <= self.h - 2)).all(1)
        vx = ndimage.map_coordinates(self.gx, [ys - 0.5, xs - 0.5], order=1, mode="nearest")
        vy = ndimage.map_coordinates(self.gy, [ys - 0.5, xs - 0.5], order=1, mode="nearest")
        s = vx * nx[:, None] + vy * ny[:, None]
        n_sec = len(x) // RAYS_PER_SECTOR
        return (s.reshape(n_sec, RAYS_PER_SECTOR, -1).mean(1),
                valid.reshape(n_sec, RAYS_PER_SECTOR).all(1))

    def scores(self, cs) -> np.ndarray:
        """:meth:`score` of several circles, sampled together."""
        from scipy import ndimage

        cs = [tuple(c) for c in cs]
        ok = np.array([bool(np.all(np.isfinite(c))) and c[2] >= 2 for c in cs])
        out = np.zeros(len(cs))
        if not ok.any():
            return out
        x, y, nx, ny = (v.ravel() for v in self.points_many([c for c, k in zip(cs, ok) if k]))
        vx = ndimage.map_coordinates(self.gx, [y - 0.5, x - 0.5], order=1, mode="nearest")
        vy = ndimage.map_coordinates(self.gy, [y - 0.5, x - 0.5], order=1, mode="nearest")
        valid = (x >= 1) & (x <= self.w - 2) & (y >= 1) & (y <= self.h - 2)
        n_sec = N_RAYS // RAYS_PER_SECTOR
        sec = np.abs((vx * nx + vy * ny).reshape(-1, n_sec, RAYS_PER_SECTOR).mean(2))
        v = valid.reshape(-1, n_sec, RAYS_PER_SECTOR).all(2)
        sc = np.where(v, np.minimum(sec, SCORE_CAP), 0.0).sum(1) / np.maximum(v.sum(1), 1)
        out[ok] = np.where(v.mean(1) >= MIN_IN_FRAME, sc, 0.0)
        return out

    def score(self, c) -> float:
        return float(self.scores([c])[0])

    def polish(self, c):
        """The local maximum of :meth:`score` from c (centre and radius searched each way in
        steps of ``POLISH_STEPS_PX``)."""
        best = np.array(c, float)
        fb = self.score(best)
        moves = np.vstack([np.eye(3), -np.eye(3)])
        for step in POLISH_STEPS_PX:
            for _ in range(200):
                cand = best[None] + moves * step
                fs = self.scores(cand)
                i = int(np.argmax(fs))
                if fs[i] <= fb + 1e-9:
                    break
                best, fb = cand[i], fs[i]
        return tuple(float(v) for v in best)

    def verdict(self, g, noise, c, w, h) -> BallFit:
        """The polished outline c with its support (sectors whose significant step lies within
        ``SNAP_PX`` of it), largest gap, and residual (RMS offset along the normal of each
        sector's steepest point within 1.5 px, outliers over 3 MAD out)."""
        ts = np.arange(-2.0, 2.0 + 1e-9, 0.25)
        s, inside = self.sectors(c, ts)
        a = np.abs(s)
        band = np.abs(ts) <= 1.5
        k = np.argmax(np.where(band[None], a, -1), axis=1)
        kk = np.clip(k, 1, len(ts) - 2)
        rows = np.arange(len(a))
        gm, g0, gp = a[rows, kk - 1], a[rows, kk], a[rows, kk + 1]
        den = gm - 2 * g0 + gp
        off = np.where(den < 0, 0.5 * (gm - gp) / np.where(den == 0, 1, den), 0.0)
        e = ts[kk] + np.clip(off, -1, 1) * (ts[1] - ts[0])
        _, _, on = _support(g, noise, *c)
        good = inside & on
        keep = good.copy()
        for _ in range(5):
            if keep.sum() < 3:
                break
            new = _inliers(e, good, keep)
            if new.sum() < 3 or np.array_equal(new, keep):
                break
            keep = new
        rms = float(np.sqrt(np.mean(e[keep] ** 2))) if keep.any() else float("inf")
        fit = _verdict(c[0], c[1], c[2], good & (np.abs(e) <= SNAP_PX), inside, rms, w, h)
        fit.sigma_px = rms * np.sqrt(2.0 / max(int(keep.sum()), 1))
        return fit


def _sector_edges(lum, g, noise, cx, cy, r, it):
    """(edge radius, angle, inside the frame) per sector of rays around the circle (cx, cy, r):
    in each sector the significant step (in noise σ, on the stabilised image ``g``) nearest to
    the circle, not the strongest one in the band (the rim often holds a stronger edge of the
    reflection a few pixels inside), at the parabolic peak of the linear luminance gradient;
    NaN outside the frame.  The band is wider on the first iteration (``it`` 0)."""
    n_sec = N_RAYS // RAYS_PER_SECTOR
    ts = np.arange(r - 4, r + 4 + 1e-9, 0.25)
    prof, ang, valid = _polar(lum, cx, cy, ts)
    prof, valid = _sectors(prof, valid)
    ang = ang.reshape(n_sec, RAYS_PER_SECTOR).mean(1)
    d = np.gradient(prof, ts, axis=1)
    band = np.abs(ts - r) <= (2.5 if it == 0 else 1.5)
    inside = valid[:, np.abs(ts - r) <= (3.0 if it == 0 else 2.0)].all(1)
    gp_, _, _ = _polar(g, cx, cy, ts)
    gp_, _ = _sectors(gp_, valid.repeat(RAYS_PER_SECTOR, 0))
    snr = _edge_snr(gp_, np.ones_like(gp_, bool), ts[1] - ts[0], noise, taps=3 * RAYS_PER_SECTOR)
    a_ = np.abs(d)
    lmax = np.zeros_like(band[None] & inside[:, None])
    lmax[:, 1:-1] = (a_[:, 1:-1] >= a_[:, :-2]) & (a_[:, 1:-1] >= a_[:, 2:])
    cand = lmax & band[None] & (snr >= EDGE_SNR)
    dist = np.where(cand, np.abs(ts - r)[None], np.inf)
    k = np.where(cand.any(1), np.argmin(dist, axis=1), np.argmax(np.where(band[None], a_, -1), axis=1))
    kk = np.clip(k, 1, len(ts) - 2)
    rows = np.arange(n_sec)
    a = np.abs(d)
    gm, g0, gp = a[rows, kk - 1], a[rows, kk], a[rows, kk + 1]
    den = gm - 2 * g0 + gp
    off = np.where(den < 0, 0.5 * (gm - gp) / np.where(den == 0, 1, den), 0.0)
    te = np.where(inside, ts[kk] + np.clip(off, -1, 1) * (ts[1] - ts[0]), np.nan)
    return te, ang, inside


def _inliers(res, good, keep):
    """The ``good`` points whose residual is within 3 MAD (of those in ``keep``; at least 0.3
    px) — one step of the outlier loops of :func:`_robust_fit` and :meth:`_Outline.verdict`."""
    mad = 1.4826 * np.median(np.abs(res[keep])) + 0.05
    return good & (np.abs(res) < max(3 * mad, 0.3))


def _robust_fit(ex, ey, good, w, h, fov_deg):
    """Circle (or cone) through the ``good`` edge points, refitted without the outliers
    (over 3 MAD, at least 0.3 px) up to 5 times → (circle, residuals, points kept)."""
    keep = good.copy()
    for _ in range(5):
        nc = _fit(ex[keep], ey[keep], w, h, fov_deg)
        res = _residual(ex, ey, nc, w, h, fov_deg)
        new = _inliers(res, good, keep)
        if new.sum() < 8 or np.array_equal(new, keep):
            break
        keep = new
    return nc, res, keep


def _verdict(cx, cy, r, ok, inside, rms, w, h) -> BallFit:
    """The fitted circle with its support (``ok``: sectors with an edge on it, of those
    ``inside`` the frame), largest gap and residual ``rms``, and whether it is confident."""
    n_sec = N_RAYS // RAYS_PER_SECTOR
    n_ok = int(inside.sum())
    sup = ok.sum() / max(n_ok, 1) if n_ok >= MIN_IN_FRAME * n_sec else 0.0
    gap = _longest_run(inside & ~ok) * 360.0 / n_sec
    n_in = _in_frame(cx, cy, r, w, h)
    fit = BallFit(float(cx), float(cy), float(r), True, support=sup, max_gap_deg=gap, residual_px=rms,
                  in_frame=n_in)
    if n_in < MIN_IN_FRAME:
        fit.confident, fit.reason = False, f"only {100 * n_in:.0f}% of the ball's outline is inside the image"
    elif (sup < MIN_SUPPORT or gap > MAX_GAP_DEG) and not _tight(sup, gap, rms):
        fit.confident, fit.reason = False, f"the outline is not closed ({fit.summary()})"
    elif rms > MAX_RMS_PX:
        fit.confident, fit.reason = False, f"the outline is not a circle ({fit.summary()})"
    return fit


def _tight(sup, gap, rms) -> bool:
    """A partly closed outline whose edges lie tightly on the circle (see TIGHT_RMS_PX)."""
    return sup >= TIGHT_SUPPORT and gap <= TIGHT_GAP_DEG and rms <= TIGHT_RMS_PX


def _ring_fraction(mask, c, gap_px, width):
    """Fraction of the pixels of `mask` set in the ring r + gap_px … r·(1 + width) around c."""
    h, w = mask.shape
    cx, cy, r = _xyr(c)
    x0, x1 = max(int(cx - r * (1 + width)) - 1, 0), min(int(cx + r * (1 + width)) + 2, w)
    y0, y1 = max(int(cy - r * (1 + width)) - 1, 0), min(int(cy + r * (1 + width)) + 2, h)
    yy, xx = np.mgrid[y0:y1, x0:x1]
    d = np.hypot(xx + 0.5 - cx, yy + 0.5 - cy)
    ring = (d >= r + gap_px) & (d <= r * (1 + width))
    return float(mask[y0:y1, x0:x1][ring].mean()) if ring.any() else 0.0


def _in_frame(cx, cy, r, w, h):
    a = np.arange(N_RAYS) * 2 * np.pi / N_RAYS
    x, y = cx + r * np.cos(a), cy + r * np.sin(a)
    return float(np.mean((x >= 0) & (x <= w) & (y >= 0) & (y <= h)))


def _fit(x, y, w, h, fov_deg):
    if fov_deg is None:
        return _lsq_circle(x, y)
    f = 0.5 * h / np.tan(np.radians(fov_deg) / 2)
    d = np.column_stack([(x - 0.5 * w) / f, (y - 0.5 * h) / f, np.ones_like(x)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # rays tangent to the sphere: d·a = cos α, i.e. d·b = 1 with b = a / cos α
    b = np.linalg.lstsq(d, np.ones(len(d)), rcond=None)[0]
    cos_a = 1.0 / np.linalg.norm(b)
    a = b * cos_a
    cx, cy = f * a[0] / a[2] + 0.5 * w, f * a[1] / a[2] + 0.5 * h
    dist = np.linalg.norm([(cx - 0.5 * w) / f, (cy - 0.5 * h) / f, 1.0])
    r = f * dist * np.tan(np.arccos(np.clip(cos_a, -1, 1)))
    return float(cx), float(cy), float(r)


def _residual(x, y, c, w, h, fov_deg):
    """Signed distance (pixels, approximately) of points from the fitted outline."""
    cx, cy, r = c
    if fov_deg is None:
        return np.hypot(x - cx, y - cy) - r
    f = 0.5 * h / np.tan(np.radians(fov_deg) / 2)
    d = np.column_stack([(x - 0.5 * w) / f, (y - 0.5 * h) / f, np.ones_like(x)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a = np.array([(cx - 0.5 * w) / f, (cy - 0.5 * h) / f, 1.0])
    dist = np.linalg.norm(a)
    a /= dist
    alpha = np.arctan(r / (f * dist))
    ang = np.arccos(np.clip(d @ a, -1, 1))
    return (ang - alpha) * f * dist
