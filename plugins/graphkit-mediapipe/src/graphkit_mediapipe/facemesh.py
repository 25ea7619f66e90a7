"""FaceMesh — a 3D face mesh registered to a photograph (Paris, Sillion, Quan 2003, §1, §3).

The paper takes a scanned 3D face registered to the photo; here mediapipe's face mesh stands in
for the scanner: 468 landmarks with relative depth, triangulated by mediapipe's tessellation.

Geometry (all lengths in mm, "mm-ish": the scale rests on an assumed eye distance):

* the photo camera is a pinhole with square pixels, principal point at the image centre and a
  vertical field of view ``fov_deg`` (default 40°, a typical portrait lens); it sits at the
  origin of the world frame (``world_to_camera`` = identity, OpenCV axes: x right, y down,
  z forward) and says that world is in mm (``metres_per_unit`` 0.001, so point lights given in
  metres fall off correctly on this mesh);
* landmark ``k`` has pixel coordinates (u, v) = (x·W, y·H) from mediapipe's normalised (x, y)
  (continuous coordinates, pixel centres at integer + 0.5, as graphkit's Camera);
  mediapipe's z is relative depth in the units of x (image widths), so z·W is a depth in pixels;
* the face centre (mediapipe's z origin) is at depth D mm: ``distance_mm`` if given, otherwise
  D = f · eye_distance_mm / eye_distance_px, with the distance between the two eye centres
  (mean of each eye's corners) measured in pixels including the depth difference;
* vertex k is at depth Z_k = D + z_k·W·D/f (a pixel at depth D spans D/f mm) and is
  back-projected through its landmark pixel: X = (u − cx)·Z/f, Y = (v − cy)·Z/f.  The camera
  therefore reprojects every vertex onto its landmark exactly (up to float rounding).

Triangles: mediapipe ships the tessellation only as an edge set (FACEMESH_TESSELATION).  The
faces are its 3-cliques, less the two cliques (49, 64, 129) and (279, 294, 358) that are not
faces (each encloses one vertex, 102 / 331): 852 triangles = 2556 edges / 3.  They are wound
consistently and oriented so that their normals point out of the head, towards the camera.

Masks (float32 H×W in {0, 1}, filled landmark polygons): ``face`` the face oval, ``eyes`` both
eye openings, ``brows`` both eyebrows, ``lips`` the lips (outer contour less the mouth
opening), ``cheeks`` the mesh triangles within two rings of the cheek centres (landmarks 205
and 425; blush regions), ``nostrils`` both nostril openings.
"""
from __future__ import annotations

import functools
from typing import Optional

import numpy as np

from graphkit import Array, BadInput, Camera, Field, Image, In, Mask, Mesh, Node, Out

from .quiet import mediapipe, native_logs_filtered

N_LANDMARKS = 468
#: triangles of the 3-clique set of FACEMESH_TESSELATION that are not faces of the mesh
_NOT_FACES = {(49, 64, 129), (279, 294, 358)}
#: eyebrow outlines (lower path then upper path reversed), from FACEMESH_*_EYEBROW
_BROWS = ([46, 53, 52, 65, 55, 107, 66, 105, 63, 70],
          [276, 283, 282, 295, 285, 336, 296, 334, 293, 300])
#: nostril openings (subject's right, subject's left), around landmarks 60 and 290
_NOSTRILS = ([240, 75, 79, 239, 238, 241, 242, 97, 99],
             [460, 305, 309, 459, 458, 461, 462, 326, 328])
#: cheek centres (subject's right, left) for the blush regions
_CHEEKS = (205, 425)
#: eye corners (outer, inner) of each eye, for the eye-distance scale
_EYE_CORNERS = ((33, 133), (263, 362))


class FaceMesh(Node):
    """Photo → 468-vertex face mesh, the photo camera and region masks (Paris 2003 §1, §3).

    mediapipe 0.10.14 face mesh (static image mode, one face).  Units: mesh in mm (scale from
    ``eye_distance_mm``), landmarks in pixels, field of view in degrees.  See the module
    docstring for the camera model and how depth is built.
    """

    version = "2"  # 2: the camera says its world is in mm (metres_per_unit 0.001)
    inputs = {"image": In(Image, "the photograph, linear RGB (grey and RGBA are taken as RGB)",
                          channels=(1, 3, 4))}
    outputs = {
        "mesh": Out(Mesh, "468 vertices in the photo camera's frame (mm), 852 triangles facing the camera"),
        "camera": Out(Camera, "the photo camera: projects the vertices onto the landmarks"),
        "landmarks": Out(Array, "468×2 landmark pixel coordinates (pixel centres at +0.5)"),
        "face": Out(Mask, "face oval, filled"),
        "eyes": Out(Mask, "both eye openings"),
        "brows": Out(Mask, "both eyebrows"),
        "lips": Out(Mask, "lips (mouth opening excluded)"),
        "cheeks": Out(Mask, "cheek regions (for blush)"),
        "nostrils": Out(Mask, "both nostril openings"),
    }

    class Params(Node.Params):
        fov_deg: float = Field(40.0, gt=1, lt=170, description="assumed vertical field of view of the photo camera (degrees)")
        eye_distance_mm: float = Field(63.0, gt=0, description="assumed distance between the eye centres (mm); sets the scale")
        distance_mm: Optional[float] = Field(None, gt=0, description="depth of the face centre from the camera (mm); default: from eye_distance_mm")
        min_detection_confidence: float = Field(0.5, ge=0, le=1, description="mediapipe face detection threshold")

    def compute(self, image: Image):
        px = image.pixels
        if px.shape[2] == 1:
            px = np.repeat(px, 3, axis=2)
        elif px.shape[2] == 4:
            px = px[:, :, :3]
        h, w = px.shape[:2]
        if min(h, w) < 32:
            raise BadInput("image", f"photo is only {w}×{h} pixels; no face can be found in it")
        lm = detect_landmarks(px, self.params.min_detection_confidence)
        if lm is None:
            raise BadInput("image", "no face found in the photo (mediapipe face mesh found none at "
                                    f"min_detection_confidence={self.params.min_detection_confidence}); "
                                    "use a photo with one frontal, well-lit face")
        uv = lm[:, :2] * np.array([w, h], np.float64)
        zpx = lm[:, 2] * w
        camera, verts = back_project(uv, zpx, w, h, self.params.fov_deg,
                                     self.params.eye_distance_mm, self.params.distance_mm)
        import trimesh

        faces = orient_faces(verts, face_topology())
        mesh = trimesh.Trimesh(vertices=verts, faces=faces, process=False)
        masks = region_masks(uv, h, w, faces)
        return {"mesh": mesh, "camera": camera, "landmarks": uv, **masks}


def detect_landmarks(rgb_linear: np.ndarray, confidence: float) -> np.ndarray | None:
    """Linear RGB float image → mediapipe landmarks (468×3 normalised x, y, z) or None."""
    mp = mediapipe()

    from nodes.common.color import linear_to_codes

    u8 = np.ascontiguousarray(linear_to_codes(rgb_linear))
    with native_logs_filtered(), mp.solutions.face_mesh.FaceMesh(
            static_image_mode=True, max_num_faces=1, refine_landmarks=False,
            min_detection_confidence=confidence) as fm:
        res = fm.process(u8)
    if not res.multi_face_landmarks:
        return None
    pts = res.multi_face_landmarks[0].landmark
    lm = np.array([[p.x, p.y, p.z] for p in pts[:N_LANDMARKS]], np.float64)
    return lm


def back_project(uv, zpx, w, h, fov_deg, eye_mm, distance_mm=None):
    """Landmark pixels + relative depth in pixels → (Camera, vertices N×3 in mm)."""
    f = 0.5 * h / np.tan(np.radians(fov_deg) / 2)
    cx, cy = 0.5 * w, 0.5 * h
    if distance_mm is None:
        p = np.column_stack([uv, zpx])
        eyes = [p[list(c)].mean(0) for c in _EYE_CORNERS]
        eye_px = float(np.linalg.norm(eyes[0] - eyes[1]))
        distance_mm = f * eye_mm / max(eye_px, 1e-6)
    d = float(distance_mm)
    z = d + zpx * d / f
    verts = np.column_stack([(uv[:, 0] - cx) * z / f, (uv[:, 1] - cy) * z / f, z])
    cam = Camera(width=w, height=h, fx=f, fy=f, cx=cx, cy=cy, metres_per_unit=0.001)  # mesh in mm
    return cam, verts


@functools.lru_cache(maxsize=1)
def face_topology() -> np.ndarray:
    """The 852 triangles of mediapipe's tessellation, consistently wound (sorted, deterministic)."""
    mp = mediapipe()

    edges = sorted(tuple(sorted(e)) for e in mp.solutions.face_mesh.FACEMESH_TESSELATION)
    adj: dict[int, set[int]] = {}
    for a, b in edges:
        adj.setdefault(a, set()).add(b)
        adj.setdefault(b, set()).add(a)
    tris = sorted({tuple(sorted((a, b, c))) for a, b in edges for c in adj[a] & adj[b]} - _NOT_FACES)
    # consistent winding: a neighbour across edge a→b must hold b→a
    by_edge: dict[tuple[int, int], list[int]] = {}
    for t, (a, b, c) in enumerate(tris):
        for e in ((a, b), (b, c), (a, c)):
            by_edge.setdefault(e, []).append(t)
    out = [None] * len(tris)
    for start in range(len(tris)):
        if out[start] is not None:
            continue
        out[start] = tris[start]
        stack = [start]
        while stack:
            t = stack.pop()
            a, b, c = out[t]
            for x, y in ((a, b), (b, c), (c, a)):
                for n in by_edge[tuple(sorted((x, y)))]:
                    if n == t or out[n] is not None:
                        continue
                    p, q, r = tris[n]
                    cyc = [(p, q), (q, r), (r, p)]
                    out[n] = (p, q, r) if (y, x) in cyc else (p, r, q)
                    stack.append(n)
    return np.array(out, np.int64)


def orient_faces(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Flip all faces when their area-weighted normals point away from the camera (+z)."""
    e1 = verts[faces[:, 1]] - verts[faces[:, 0]]
    e2 = verts[faces[:, 2]] - verts[faces[:, 0]]
    nz = np.cross(e1, e2)[:, 2].sum()
    return faces[:, ::-1].copy() if nz > 0 else faces.copy()


def _loops(edges) -> list[list[int]]:
    """Closed loops (ordered vertex lists) of an edge set whose vertices all have degree 2."""
    adj: dict[int, list[int]] = {}
    for a, b in edges:
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    seen, loops = set(), []
    for s in sorted(adj):
        if s in seen:
            continue
        loop, prev, cur = [s], None, s
        seen.add(s)
        while True:
            nxt = [n for n in sorted(adj[cur]) if n != prev]
            if not nxt or nxt[0] == s:
                break
            prev, cur = cur, nxt[0]
            if cur in seen:
                break
            loop.append(cur)
            seen.add(cur)
        loops.append(loop)
    return loops


def _fill(h, w, polys, uv) -> np.ndarray:
    """Rasterise landmark polygons (lists of indices) with sub-pixel precision → uint8 H×W."""
    import cv2

    m = np.zeros((h, w), np.uint8)
    shift = 4
    pts = [np.round((uv[list(p)] - 0.5) * (1 << shift)).astype(np.int32) for p in polys]
    for p in pts:  # one at a time: fillPoly with several contours treats overlaps as holes
        cv2.fillPoly(m, [p], 1, lineType=cv2.LINE_8, shift=shift)
    return m


def _area(uv, loop):
    x, y = uv[loop, 0], uv[loop, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))


def region_masks(uv: np.ndarray, h: int, w: int, faces: np.ndarray) -> dict[str, Mask]:
    mp = mediapipe()

    fm = mp.solutions.face_mesh
    oval = _loops(fm.FACEMESH_FACE_OVAL)
    eyes = _loops(fm.FACEMESH_LEFT_EYE) + _loops(fm.FACEMESH_RIGHT_EYE)
    lip_loops = sorted(_loops(fm.FACEMESH_LIPS), key=lambda lp: _area(uv, lp))
    lips = _fill(h, w, lip_loops[-1:], uv) * (1 - _fill(h, w, lip_loops[:1], uv))
    # cheeks: the triangles within two rings of each cheek centre
    cheek_tris = []
    for c in _CHEEKS:
        ring = {c}
        for _ in range(2):
            ring |= set(faces[np.isin(faces, list(ring)).any(1)].ravel().tolist())
        sel = faces[np.isin(faces, list(ring)).all(1)]
        cheek_tris += [list(t) for t in sel]
    out = {
        "face": _fill(h, w, oval, uv),
        "eyes": _fill(h, w, eyes, uv),
        "brows": _fill(h, w, _BROWS, uv),
        "lips": lips,
        "cheeks": _fill(h, w, cheek_tris, uv),
        "nostrils": _fill(h, w, _NOSTRILS, uv),
    }
    return {k: Mask(v.astype(np.float32)) for k, v in out.items()}
