"""ProjectTextures: the photograph de-warped onto each polygon from the fixed viewpoint (§3)."""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Camera, Field, Image, Node

from . import geometry as G
from .ports import PROJECTION, ROOM_SCENE, Projection, RoomScene


def camera_rays(cam: Camera, step: int = 1):
    """World-space ray origins and unit directions through pixel centres, (H//step·W//step, 3)."""
    ys = np.arange(0, cam.height, step) + 0.5
    xs = np.arange(0, cam.width, step) + 0.5
    X, Y = np.meshgrid(xs, ys)
    dc = np.stack([(X - cam.cx) / cam.fx, (Y - cam.cy) / cam.fy, np.ones_like(X)], -1)
    R = cam.pose[:3, :3]
    d = dc.reshape(-1, 3) @ R  # camera → world (R orthonormal)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(cam.position, d.shape).copy()
    return o, d, (len(ys), len(xs))


def pixel_map(verts: np.ndarray, cam: Camera, step: int = 1):
    """Polygon index (-1: none or a back face) and (s, t) seen at each pixel centre."""
    o, d, shape = camera_rays(cam, step)
    po, pu, pv, pn, _ = G.frame(verts)
    idx, t, s, tt = G.ray_first_hit(o, d, po, pu, pv, pn, two_sided=True)
    back = np.zeros(len(idx), bool)
    m = idx >= 0
    back[m] = np.einsum("nc,nc->n", d[m], pn[idx[m]]) > 0
    idx = np.where(back, -1, idx)
    return idx.reshape(shape), np.stack([s, tt], -1).reshape(shape + (2,))


def sample_bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup of img (H,W,C) at continuous pixel coords (pixel centres at +0.5)."""
    from scipy.ndimage import map_coordinates

    out = np.empty(x.shape + (img.shape[2],), np.float64)
    for c in range(img.shape[2]):
        out[..., c] = map_coordinates(img[:, :, c], [y - 0.5, x - 0.5], order=1, mode="nearest")
    return out


def project(scene: RoomScene, cam: Camera, photo: np.ndarray, res: int) -> Projection:
    """Per-polygon res×res textures and the per-pixel polygon map (see Projection)."""
    verts = scene.verts
    po, pu, pv, pn, _ = G.frame(verts)
    P = len(verts)
    st = (np.arange(res) + 0.5) / res
    S, T = np.meshgrid(st, st, indexing="ij")
    pts = (po[:, None, None] + S[None, ..., None] * pu[:, None, None]
           + T[None, ..., None] * pv[:, None, None]).reshape(-1, 3)
    uv, z = cam.project(pts)
    c = cam.position
    front = (np.einsum("pc,pc->p", c[None] - po, pn) > 0)
    inside = (z > 1e-6) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) \
        & (uv[:, 1] < cam.height)
    inside &= np.repeat(front, res * res)
    # occlusion: segment texel → camera blocked by another polygon
    cand = np.flatnonzero(inside)
    pid = np.repeat(np.arange(P), res * res)
    ign = np.stack([pid[cand], np.full(len(cand), -1)], 1)
    blocked = G.segment_blocked(pts[cand], np.broadcast_to(c, (len(cand), 3)), po, pu, pv, pn,
                                ignore=ign)
    cov = np.zeros(len(pts), bool)
    cov[cand[~blocked]] = True
    tex = np.zeros((len(pts), 3))
    tex[cov] = sample_bilinear(photo, uv[cov, 0], uv[cov, 1])
    pp, pst = pixel_map(verts, cam)
    return Projection(tex.reshape(P, res, res, 3).astype(np.float32),
                      cov.reshape(P, res, res).astype(np.float32), pp, pst)


class ProjectTextures(Node):
    """Project the photograph onto every polygon: one res×res texture per polygon (§3, §4).

    A texel (s, t) of polygon p is the point o + s·u + t·v (metres); it is seen when it lies in
    the camera frame in front of the polygon and no other polygon blocks the segment to the
    camera; its value is the photograph bilinearly sampled there (linear radiance).  Also
    records, for each pixel, the polygon it sees and its (s, t), used to render results.
    """

    version = "1"
    inputs = {"scene": ROOM_SCENE, "camera": Camera, "photo": Image}
    outputs = {"projection": PROJECTION}

    class Params(Node.Params):
        resolution: int = Field(128, ge=4, le=1024, description="texels per polygon side")

    def compute(self, scene: RoomScene, camera: Camera, photo: Image):
        if photo.pixels.shape[:2] != (camera.height, camera.width):
            raise BadInput("photo", f"photo is {photo.width}×{photo.height} but the camera is "
                                    f"{camera.width}×{camera.height}")
        if photo.channels < 3:
            raise BadInput("photo", f"photo needs 3 channels (RGB), has {photo.channels}")
        pr = project(scene, camera, photo.pixels[:, :, :3].astype(np.float64),
                     self.params.resolution)
        if not (pr.pix_poly >= 0).any():
            raise BadInput("camera", "the camera sees no polygon of the scene")
        return pr
