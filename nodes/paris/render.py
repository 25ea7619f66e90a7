"""ShadeFace and Render — the rendering side of Paris, Sillion, Quan 2003 (§3 shaded face, §5).

Both rasterise the mesh with the shared numpy z-buffer (``nodes.common.raster``) through a
perspective or orthographic :class:`graphkit.Camera`: per pixel the nearest triangle, its
barycentrics (perspective-correct, or affine for orthographic views), world position and a
smooth (vertex-interpolated) normal.  Normals are turned towards the viewer (two-sided
lighting), so meshes with either winding render the same.

Frames and units: meshes and lights are in the world frame; the camera's ``metres_per_unit``
gives the world's unit, so point lights (positions in metres) fall off as I/d² with d in
metres (:func:`world_lights` converts them to world units once).
"""
from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Literal, NamedTuple, Optional

import numpy as np
import xxhash

from graphkit import BadInput, Camera, Field, Image, In, Light, Mask, Mesh, Node, Out
from graphkit.hashing import canonical
from graphkit.store import value_parts
from nodes.common.parallel import run_balanced
from nodes.common.shadows import is_sized

from .checks import check_lit, check_mesh, check_rgb, unit_direction
from .environment import EnvironmentLighting, sh_irradiance, shadow_map_sizes
from .models import PhongMaterial

# mediapipe face-mesh eye contours (FACEMESH_LEFT_EYE / FACEMESH_RIGHT_EYE vertex ids)
MP_EYES = (
    (263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398),
    (33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173),
)
INTEROCULAR_MM = 63.0  # mean adult distance between the eye centres (mm)
#: mediapipe face-mesh outer lip contour (the larger loop of FACEMESH_LIPS)
MP_LIPS_OUTER = (0, 37, 39, 40, 185, 61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 409, 270, 269, 267)
#: the mouth region reaches this fraction of the mouth's height beyond the outer lip contour
#: (a fitted mesh's lips miss the photo's by about that much: the astronaut's by 2–4 px of 17)
MOUTH_MARGIN = 0.3


# ----------------------------------------------------------------------------------------------
# shared helpers (also used by ReflectanceMap and FitSkinPhong)


@dataclass
class Surface:
    """The visible surface of a mesh through a camera, per pixel."""

    raster: object
    coverage: np.ndarray  # H×W bool
    points: np.ndarray  # M×3 world positions of covered pixels (row-major order)
    normals: np.ndarray  # M×3 unit world normals, turned towards the camera
    view: np.ndarray  # M×3 unit directions towards the camera centre


def _in_front_and_frame(V: np.ndarray, camera: Camera) -> tuple[np.ndarray, bool]:
    """(vertices in front of the camera, does their projection overlap the image?)"""
    from nodes.common.raster import NEAR

    xy, z = camera.project(V)
    front = z > NEAR
    if not front.any():
        return front, False
    lo, hi = xy[front].min(0), xy[front].max(0)
    overlap = bool(hi[0] > 0 and hi[1] > 0 and lo[0] < camera.width and lo[1] < camera.height)
    return front, overlap


def check_in_view(mesh, camera: Camera, port: str = "mesh", camera_port: str = "camera") -> None:
    """BadInput unless the whole mesh lies in front of the camera and its projection meets the
    image: a mesh behind the camera, crossing its image plane, or beside it (no overlap) is
    refused, with a hint when ``world_to_camera`` looks inverted (the camera's own pose,
    camera → world, given in its place)."""
    V = np.asarray(mesh.vertices, np.float64)
    front, overlap = _in_front_and_frame(V, camera)
    if front.all() and overlap:
        return
    hint = ""
    try:
        inv = camera.model_copy(update={"world_to_camera": np.linalg.inv(camera.pose).tolist()})
        f2, o2 = _in_front_and_frame(V, inv)
        if f2.all() and o2:
            hint = (f"; with world_to_camera inverted it would be in view: the camera's pose "
                    f"(camera → world) seems to be given instead of world → camera (port "
                    f"'{camera_port}')")
    except np.linalg.LinAlgError:  # pragma: no cover - rigid poses are invertible
        pass
    n = len(V)
    if not front.any():
        raise BadInput(port, f"the mesh is behind the camera: all {n} vertices have camera depth "
                             f"z ≤ 0{hint or ' (wrong pose or mesh frame?)'}")
    if not front.all():
        raise BadInput(port, f"the mesh crosses the camera's image plane: {int((~front).sum())} of "
                             f"{n} vertices are behind the camera (z ≤ 0){hint}; the renderers do "
                             "not clip")
    raise BadInput(port, f"the mesh is beside the camera: its projection misses the "
                         f"{camera.width}×{camera.height} image{hint or ' (wrong pose, units or image size?)'}")


def skin_surface(mesh, camera: Camera, skin: Mask, threshold: float, fewest: int) -> tuple[Surface, np.ndarray]:
    """(the mesh's :func:`surface` in the photo, which of its pixels are skin: alpha ≥
    ``threshold``), after the checks every node fitting to a photo makes: the skin mask is not
    empty and at least ``fewest`` skin pixels lie on the mesh (BadInput at the skin port).
    That the camera and the mask are the photo's size is declared on the ports
    (``same_size_as="image"``)."""
    sk = skin.alpha >= threshold
    if not sk.any():
        raise BadInput("skin", "the skin mask is empty (no pixel ≥ skin_threshold)")
    s = surface(mesh, camera, min_pixels=1)
    use = sk[s.coverage]
    if use.sum() < fewest:
        raise BadInput("skin", f"only {int(use.sum())} skin pixels lie on the mesh (at least {fewest} are "
                               "needed): the skin mask and the mesh hardly overlap")
    return s, use


def surface(mesh, camera: Camera, min_pixels: int = 1, port: str = "mesh") -> Surface:
    """Rasterise ``mesh`` through ``camera`` (perspective or orthographic); BadInput when the
    mesh is not in view or covers < ``min_pixels`` pixels."""
    from nodes.common import raster

    from .phong import unit

    check_mesh(mesh, port)
    check_in_view(mesh, camera, port)
    faces = np.asarray(mesh.faces, np.int64)
    V = np.asarray(mesh.vertices, np.float64)
    r = raster.rasterize(V, faces, camera)
    cov = r.coverage
    if cov.sum() < min_pixels:
        raise BadInput(port, f"the mesh covers {int(cov.sum())} pixels of the {camera.width}×"
                             f"{camera.height} camera image: it does not match the camera "
                             "(wrong pose, units or image size?)")
    vn = vertex_normals(mesh)
    f = faces[r.tri[cov]]
    b = r.bary[cov]
    P = V[f[:, 0]] * b[:, 0:1] + V[f[:, 1]] * b[:, 1:2] + V[f[:, 2]] * b[:, 2:3]
    N = unit(vn[f[:, 0]] * b[:, 0:1] + vn[f[:, 1]] * b[:, 1:2] + vn[f[:, 2]] * b[:, 2:3])
    Vd = camera.view_dirs(P)
    flip = np.sum(N * Vd, axis=1) < 0
    N[flip] *= -1
    return Surface(r, cov, P, N, Vd)


def close_holes(mesh):
    """The mesh with its inner holes closed (eyes, mouth of a face mask), the outer boundary
    (the longest boundary loop) kept: each hole gets a fan of triangles around its centroid,
    wound like its neighbours.  Returns the mesh itself when there is no inner hole."""
    import trimesh
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = np.asarray(mesh.faces, np.int64)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    nv = len(mesh.vertices)
    key = np.minimum(e[:, 0], e[:, 1]) * nv + np.maximum(e[:, 0], e[:, 1])
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    bnd = e[cnt[inv.ravel()] == 1]
    if len(bnd) == 0:
        return mesh
    g = coo_matrix((np.ones(len(bnd)), (bnd[:, 0], bnd[:, 1])), shape=(nv, nv))
    ncomp, lab = connected_components(g, directed=False)
    comp = lab[bnd[:, 0]]
    ids, sizes = np.unique(comp, return_counts=True)
    if len(ids) < 2:
        return mesh
    outer = ids[np.argmax(sizes)]
    V = np.asarray(mesh.vertices, np.float64)
    newV, newF = [V], [F]
    n = nv
    for c in ids:
        if c == outer:
            continue
        loop = bnd[comp == c]
        centre = V[np.unique(loop)].mean(0)
        newV.append(centre[None])
        newF.append(np.stack([loop[:, 1], loop[:, 0], np.full(len(loop), n)], 1))
        n += 1
    return trimesh.Trimesh(np.vstack(newV), np.vstack(newF), process=False)


def vertex_normals(mesh) -> np.ndarray:
    """Unit vertex normals: the mesh's own ``vertex_normals`` (trimesh, face-area weighted)."""
    n = np.asarray(mesh.vertex_normals, np.float64)
    return n


def world_lights(lights, camera: Camera, mesh=None, port: str = "lights") -> list:
    """The lights (world frame, point positions in metres) in the camera's world units
    (``Light.in_world_units``), checked: a point light inside the mesh (its convex hull), whose
    sphere (``radius_m``) reaches the mesh, or with a non-finite position is refused."""
    out = []
    hull = None
    for i, light in enumerate(lights):
        if light.kind == "point":
            pos = np.asarray(light.position, np.float64)
            if not np.isfinite(pos).all():
                raise BadInput(port, f"light {i}: the point light's position {tuple(pos)} is not finite")
        lw = light.in_world_units(camera.metres_per_unit)
        if lw.kind == "point" and mesh is not None:
            if hull is None:
                hull = _hull_equations(mesh)
            p = np.asarray(lw.position, np.float64)
            if hull is not None and np.all(hull[:, :3] @ p + hull[:, 3] < 0):
                raise BadInput(port, f"light {i}: the point light at {tuple(light.position)} m (world) "
                                     "is inside the mesh: it must be outside the face (positions are "
                                     "in metres, world frame)")
            near = float(np.min(np.linalg.norm(np.asarray(mesh.vertices, np.float64) - p, axis=1)))
            if lw.radius_m >= near:
                raise BadInput(port, f"light {i}: the light's sphere (radius {light.radius_m:g} m) reaches the "
                                     f"mesh ({near * camera.metres_per_unit:.3g} m from its centre): give it a "
                                     "smaller radius or move it away")
        elif lw.kind == "directional":
            unit_direction(lw.direction, port, f"light {i}: the direction")
        out.append(lw)
    return out


def _hull_equations(mesh) -> np.ndarray | None:
    """Outward half-space equations (K×4: n·x + c ≤ 0 inside) of the mesh's convex hull, or
    None for a flat mesh."""
    from scipy.spatial import ConvexHull, QhullError

    V = np.asarray(mesh.vertices, np.float64)
    try:
        return ConvexHull(V).equations
    except (QhullError, ValueError):
        return None


def light_vectors(light: Light, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit directions towards the light M×3, light RGB per point M×3) for surface points P
    (world units; the light in the same units, see :func:`world_lights`).  Point lights
    always fall off as I/d²."""
    from .phong import unit

    rgb = np.asarray(light.color, np.float64) * light.intensity
    if light.kind == "directional":
        d = unit(np.asarray(light.direction, np.float64))
        return np.broadcast_to(d, P.shape), np.broadcast_to(rgb, P.shape)
    v = np.asarray(light.position, np.float64)[None, :] - P
    dist2 = np.maximum(np.einsum("ij,ij->i", v, v), 1e-24)[:, None]
    return unit(v), rgb[None, :] / dist2


def irradiance(light: Light, P: np.ndarray) -> np.ndarray:
    """Scalar irradiance scale of the light at points P (M,), at normal incidence: its
    intensity (directional) or intensity / d² (point; light and P in world units)."""
    if light.kind == "directional":
        return np.full(len(P), float(light.intensity))
    v = np.asarray(light.position, np.float64)[None, :] - P
    return float(light.intensity) / np.maximum(np.einsum("ij,ij->i", v, v), 1e-24)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup of H×W×C ``img`` at pixel coordinates (centres at +0.5), edge-clamped."""
    H, W = img.shape[:2]
    fx = np.clip(x - 0.5, 0, W - 1)
    fy = np.clip(y - 0.5, 0, H - 1)
    x0 = np.floor(fx).astype(np.int64)
    y0 = np.floor(fy).astype(np.int64)
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    tx, ty = (fx - x0)[:, None], (fy - y0)[:, None]
    return (img[y0, x0] * (1 - tx) * (1 - ty) + img[y0, x1] * tx * (1 - ty)
            + img[y1, x0] * (1 - tx) * ty + img[y1, x1] * tx * ty)


def projective_texture(detail: Image, tex_cam: Camera, mesh, P: np.ndarray,
                       occlusion: bool = True) -> np.ndarray:
    """Detail texture values (M×C) at world points P, by projective texture coordinates from
    the photo camera (§3).  Points outside the photo or hidden from it get 1 (neutral)."""
    from nodes.common import raster

    xy, z = tex_cam.project(P)
    H, W = detail.pixels.shape[:2]
    # (the camera and texture camera describe one world: the same unit)
    ok = (z > 0) & (xy[:, 0] >= 0) & (xy[:, 0] < W) & (xy[:, 1] >= 0) & (xy[:, 1] < H)
    out = np.ones((len(P), detail.channels))
    if occlusion and ok.any():
        r = raster.rasterize(mesh.vertices, mesh.faces, tex_cam)
        ix = np.clip(xy[ok, 0].astype(np.int64), 0, W - 1)
        iy = np.clip(xy[ok, 1].astype(np.int64), 0, H - 1)
        dz = r.depth[iy, ix]
        # a point is seen when it is (about) the nearest surface at its pixel
        scale = np.median(np.ptp(np.asarray(mesh.vertices), axis=0)) or 1.0
        vis = np.isfinite(dz) & (z[ok] <= dz + 0.02 * scale)
        idx = np.nonzero(ok)[0]
        ok[idx[~vis]] = False
    out[ok] = _bilinear(detail.pixels.astype(np.float64), xy[ok, 0], xy[ok, 1])
    return out


def _mediapipe_ids(mesh) -> np.ndarray | None:
    """Vertex index of each mediapipe landmark id in ``mesh`` (a FaceMesh mesh, or one made
    from it by SmoothMesh, whose ``source_vertex`` attribute keeps the ids), or None."""
    n = len(mesh.vertices)
    src = mesh.vertex_attributes.get("source_vertex") if hasattr(mesh, "vertex_attributes") else None
    if src is not None:
        src = np.asarray(src, np.int64)
        if int((src >= 0).sum()) in (468, 478) and np.array_equal(src[src >= 0], np.arange((src >= 0).sum())):
            return np.nonzero(src >= 0)[0]
        return None
    return np.arange(n) if n in (468, 478) else None


def eye_spheres(mesh, eyes, cornea_mm: float, mm_per_unit: float | None,
                protrude_mm: float, towards: np.ndarray):
    """Centres (2×3), outward axes (2×3) and radius (mesh units) of the cornea hemispheres.

    ``eyes``: explicit 2×3 eye-opening centres (world), else the mediapipe eye contours.
    The sphere's cap sticks ``protrude_mm`` out of the eye opening along its outward axis.
    """
    from .phong import unit

    V = np.asarray(mesh.vertices, np.float64)
    if eyes is not None:
        cen = np.asarray(eyes, np.float64).reshape(2, 3)
        vn = vertex_normals(mesh)
        near = np.argmin(np.linalg.norm(V[None] - cen[:, None], axis=2), axis=1)
        axes = vn[near]
    elif (ids := _mediapipe_ids(mesh)) is not None:
        cen = np.stack([V[ids[list(e)]].mean(0) for e in MP_EYES])
        vn = vertex_normals(mesh)
        axes = np.stack([vn[ids[list(e)]].mean(0) for e in MP_EYES])
    else:
        return None
    axes = unit(axes)
    for i in range(2):  # outward = towards the camera that sees the face
        if np.dot(axes[i], towards - cen[i]) < 0:
            axes[i] = -axes[i]
    if mm_per_unit is None:
        d = float(np.linalg.norm(cen[0] - cen[1]))
        mm_per_unit = INTEROCULAR_MM / d if d > 0 else 1.0
    R = cornea_mm / mm_per_unit
    centres = cen - axes * (R - protrude_mm / mm_per_unit)
    return centres, axes, R


def mouth_region(mesh, camera: Camera) -> tuple[np.ndarray, float] | None:
    """(alpha H×W: 1 inside the outer lip contour, falling smoothly to 0 at ``MOUTH_MARGIN`` ×
    the mouth's height outside it; the mouth's height in pixels) through ``camera``, from the
    mediapipe landmark ids of ``mesh`` (FaceMesh's, or SmoothMesh's of it); None without them."""
    import cv2

    from nodes.common.blend import feather

    ids = _mediapipe_ids(mesh)
    if ids is None:
        return None
    xy, _ = camera.project(np.asarray(mesh.vertices, np.float64)[ids[list(MP_LIPS_OUTER)]])
    inside = np.zeros((camera.height, camera.width), np.uint8)
    cv2.fillPoly(inside, [np.round((xy - 0.5) * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    height = max(float(np.ptp(xy[:, 1])), 1.0)
    return 1.0 - feather(inside == 0, MOUTH_MARGIN * height), height


class SmoothOver:
    """The per-pixel shading (M×3, the ``covered`` pixels in row-major order) with the region
    ``alpha`` > 0 taken over by the shading around it, smoothed to ``scale_px`` and carried in
    (``blend.SmoothFill``), blended by ``alpha``: where the mesh does not follow the photo
    (lips, teeth) the light changes smoothly, as on the skin around it.  What depends on the
    region only (its box, the fill's plan) is prepared here; calling it with a shading fills."""

    def __init__(self, covered: np.ndarray, alpha: np.ndarray, scale_px: float):
        from nodes.common.blend import SmoothFill

        self.fill = None
        a = np.where(covered, alpha, 0.0).astype(np.float32)
        known = covered & (alpha <= 0)
        if not (a > 0).any() or not known.any():
            return
        ys, xs = np.nonzero(a > 0)
        pad = int(np.ceil(3 * scale_px))
        H, W = covered.shape
        box = (slice(max(ys.min() - pad, 0), min(ys.max() + pad + 1, H)),
               slice(max(xs.min() - pad, 0), min(xs.max() + pad + 1, W)))
        if not known[box].any():
            return
        self.fill = SmoothFill(known[box], scale_px)
        self.inside = covered[box]  # the covered pixels of the box …
        rank = np.cumsum(covered.ravel()).reshape(H, W) - 1
        self.rows = rank[box][self.inside]  # … and their rows in the shading
        self.ab = a[box][:, :, None]

    def __call__(self, shade: np.ndarray) -> np.ndarray:
        if self.fill is None:
            return shade
        img = np.zeros(self.inside.shape + (shade.shape[1],), np.float64)
        img[self.inside] = shade[self.rows]
        fill = self.fill(img)
        out = shade.copy()
        out[self.rows] = (img * (1.0 - self.ab) + fill * self.ab)[self.inside]
        return out


# ----------------------------------------------------------------------------------------------


class ShadeFace(Node):
    """The "shaded face" of Paris 2003 §3: the mesh rendered in the photo's pose with the skin
    reflectance map.

    Each covered pixel looks up the map (``nodes.paris.sphere`` lat-long convention, normals in
    the photo camera's frame) at its interpolated normal.  With the flash ``light`` (the one
    ReflectanceMap divided out), the value is multiplied by the flash's irradiance at that
    point (I/d² for a point flash, d in metres), so the flash's fall-off across the face is in
    the shaded face and not in the detail texture.  The photo divided by this image is the
    detail texture (RatioImage).  Uncovered pixels are 0.  Perspective and orthographic
    cameras.  Units: linear RGB.
    """

    version = "2"
    inputs = {"mesh": In(Mesh, "face mesh in world coordinates", finite=True),
              "camera": In(Camera, "the photo camera"),
              "map": In(Image, "reflectance map (ReflectanceMap.map)"),
              "light": In(Light, "the flash (world frame), as given to ReflectanceMap", optional=True)}
    outputs = {"image": Out(Image, "shaded face, the photo's size"),
               "coverage": Out(Mask, "pixels covered by the mesh")}

    class Params(Node.Params):
        res_deg: float = Field(1.0, gt=0, le=10, description="map resolution (degrees/pixel)")
        fill_holes: bool = Field(True, description="close inner holes (eyes, mouth) as Render does")

    def compute(self, mesh, camera: Camera, map: Image, light: Light | None = None):
        from . import sphere

        rows, cols = sphere.shape(self.params.res_deg)
        if map.pixels.shape[:2] != (rows, cols):
            raise BadInput("map", f"map is {map.size_str()}, a {self.params.res_deg}° map is "
                                  f"{cols}×{rows}")
        check_mesh(mesh)
        m = close_holes(mesh) if self.params.fill_holes else mesh
        s = surface(m, camera)
        Ncam = camera.dir_to_camera(s.normals)
        vals = sphere.sample(map.pixels.astype(np.float64), Ncam, self.params.res_deg)
        if light is not None:
            (lw,) = world_lights([light], camera, m, "light")
            vals = vals * irradiance(lw, s.points)[:, None]
        out = np.zeros((camera.height, camera.width, map.channels), np.float32)
        out[s.coverage] = vals
        return {"image": Image(out), "coverage": Mask(s.coverage.astype(np.float32))}

    @classmethod
    def examples(cls):
        import trimesh

        from . import sphere

        m = trimesh.creation.icosphere(subdivisions=3)
        m.apply_translation([0, 0, 4.0])
        rmap = Image((0.5 + 0.5 * sphere.pixel_normals(1.0)).astype(np.float32))
        persp = Camera(width=40, height=32, fx=60, fy=60, cx=20, cy=16)
        ortho = Camera(width=40, height=32, projection="orthographic", pixels_per_m=14.0,
                       cx=20, cy=16)
        return [({}, {"mesh": m, "camera": persp, "map": rmap}),
                ({}, {"mesh": m, "camera": ortho, "map": rmap,
                      "light": Light(kind="point", position=(0.0, -0.5, 0.0), intensity=16.0)})]


def check_render_inputs(lights, detail, texture_camera, camera: Camera | None = None,
                        environment=None) -> list:
    """Render's input checks that no port constraint expresses (the declared one: the texture
    camera's size is the detail texture's), shared by its backends: at least one light or an
    environment; the lights as a list."""
    lights = [] if lights is None else list(lights) if isinstance(lights, (list, tuple)) else [lights]
    if not lights and environment is None:
        raise BadInput("lights", "needs at least 1 connection, got 0 (or connect an `environment`)")
    if detail is not None:
        check_rgb(detail, "detail", grey=True)  # it multiplies RGB
    if detail is not None and texture_camera is None:
        raise BadInput("texture_camera", "a detail texture needs the photo camera that maps it")
    if camera is not None and texture_camera is not None and \
            texture_camera.metres_per_unit != camera.metres_per_unit:
        raise BadInput("texture_camera", f"the texture camera's world unit ({texture_camera.metres_per_unit} m) "
                                         f"is not the camera's ({camera.metres_per_unit} m): both must "
                                         "describe the same world")
    return lights


def prepare_render(mesh, camera: Camera, lights, detail, texture_camera, fill_holes: bool,
                   environment=None):
    """Render's checks and set-up shared by every backend: (lights in world units, the mesh
    to draw (inner holes closed when asked))."""
    lights = check_render_inputs(lights, detail, texture_camera, camera, environment)
    m = prepare_mesh(mesh, camera, texture_camera, fill_holes)
    return world_lights(lights, camera, m), m


def prepare_mesh(mesh, camera: Camera, texture_camera, fill_holes: bool):
    """The light-independent part of :func:`prepare_render`: the mesh checked, its inner holes
    closed when asked, and seen by the camera(s)."""
    check_mesh(mesh)
    m = close_holes(mesh) if fill_holes else mesh
    check_in_view(m, camera)
    if texture_camera is not None:
        check_in_view(m, texture_camera, "mesh", "texture_camera")
    return m


def _example_environment() -> EnvironmentLighting:
    """Render.examples()'s environment: a light in front, one behind the mesh (it lights
    nothing: allowed for an environment's lights) and an SH ambient with every band set."""
    sh = ((0.3, 0.25, 0.2), (0.05, 0.02, 0.0), (-0.08, -0.05, -0.02), (0.06, 0.07, 0.1),
          (0.03, 0.0, -0.02), (-0.04, 0.02, 0.03), (0.05, 0.04, 0.02), (0.02, -0.03, 0.0),
          (-0.05, 0.01, 0.04))
    return EnvironmentLighting(lights=(Light(direction=(0.4, -0.5, -0.77), intensity=0.7),
                                       Light(direction=(0.0, 0.0, 1.0), intensity=2.0)), sh=sh)


class Render(Node):
    """Paris 2003 §5 rendering engine: Phong (ambient + diffuse + specular, §4) × detail texture.

    * Phong per light: kd·(A + L (n·l)) + i_s·L·(r·v)^s with the skin material of
      FitSkinPhong; L = light colour × intensity, for point lights divided by d² (always: the
      light's position and d in metres, through the camera's ``metres_per_unit``); A = the
      light's ambient × the material's ambient scale.  Lights are in the world frame.
    * Perspective or orthographic ``camera`` (view vectors towards the centre, or the camera's
      −z everywhere).
    * Detail texture multiplied in (GL_MODULATE), carried on the mesh by projective texture
      coordinates from ``texture_camera`` (the photo camera, §3); no [0, 2ⁿ] range limit.
    * ``exposure`` multiplies the light; the result is clamped to [0, 1] *after* the texture
      (§5 "Camera sensitivity": over-exposure when exposure > 1).
    * Cast shadows by shadow maps (§5, Williams 1978), toggled by ``shadows``; soft, with a
      penumbra set by the light's size, for lights with one (``LightSize``: percentage-closer
      soft shadows, ``nodes.common.shadows``); hard for a point or parallel light.
    * Eye highlights (§5): two purely specular hemispheres of cornea radius 7.8 mm with a high
      exponent, added on top (from the mediapipe eye contours or the ``eyes`` param).
    * An ``environment`` (EnvironmentLights, Paris 2003 Fig. 10-b): its lights are shaded as
      the others (they may lie behind the face); those of at least ``environment_shadows`` ×
      the brightest's luminance cast shadows (``environment.shadow_map_sizes``, the one rule
      of both backends), the dimmer ones none.  With ``environment_basis`` n > 0 (default
      2048) a shadow is soft, from a visibility basis (``nodes.paris.visibility``): each
      point's visibility towards n fixed directions, by rays through the mesh, each direction
      drawn when a light first needs it and kept with the surface (in this process's memory,
      not the cache), so a turning environment draws no shadow map; in a live session (the
      studio: ``Context.interactive``) the rest are drawn in the background after the first
      render, ~6–7 s of CPU at 1024² (bench_environment.py --prefill; its progress shown on the node),
      so later rotations draw none; a light takes the
      cosine-weighted visibility of the directions within ~√(4π/n) of it (an area light's
      soft shadow).  With 0, a shadow map per light (the brightest ``shadow_map_size``²,
      dimmer ones smaller, side ∝ luminance^⅓).  Its 9 spherical-harmonic coefficients add
      kd × irradiance/π (Ramamoorthi–Hanrahan) without shadows.  Then ``lights`` may be
      empty.  The numpy and opengl backends take it (the opengl one with ``environment_basis:
      0`` when it casts shadows; the studio's WebGL view does not).
    * The mouth (``mouth: photo``, on a mediapipe mesh): a fitted mesh's lips miss the photo's,
      so the mouth region (the outer lip contour, widened by 30 % of its height, feathered) takes
      the smooth shading of the skin around it, and the photo's lips and teeth come from the
      detail texture under it (no streak where the mesh's lip normals are wrong).
    * ``antialias``: each pixel the silhouette crosses is covered by 0.5 ± the distance from its
      centre to the mesh's outline (``raster.edge_coverage``), the colour blended with the
      background by it; the ``coverage`` output is that fraction.
    * What does not depend on the lights or the material (the surface, detail texture, eye
      hits, mouth, silhouette) is kept between calls on the same inputs: a new light re-shades.
    Outputs the image, the camera-space depth (mesh units, 0 where empty) and the coverage.
    A mesh behind, across or beside the camera, or a point light inside the mesh, is refused.
    """

    version = "7"  # 7: the mouth's smooth fill blurred through SciPy (the same bytes on every CPU); 3: mouth from the photo's detail under smooth shading; antialias; 4: environment lights' shadow maps sized by their share of the light; 5: only the dominant environment lights cast shadows (environment_shadows); 6: environment shadows from a visibility basis (environment_basis)
    studio_view = "nodes.paris.studio_view:FaceView"  # graphkit serve: WebGL2 relighting
    inputs = {"mesh": In(Mesh, "face mesh (world coordinates)", finite=True),
              "camera": In(Camera, "the camera to render from"),
              "material": In(PhongMaterial, "skin material (FitSkinPhong.material)"),
              "lights": In(Light, "light sources, world frame (any number; at least one unless "
                                  "an environment is connected)", variadic=True, optional=True),
              "detail": In(Image, "detail texture (RatioImage of photo / shaded face)", optional=True),
              "texture_camera": In(Camera, "the photo camera, for projective texture coordinates",
                                   optional=True, same_size_as="detail"),
              "ambient": In(Light, "a light whose ambient term is added (e.g. FitSkinPhong.light); "
                                   "its direct part is ignored", optional=True),
              "environment": In(EnvironmentLighting, "lights and SH ambient of an environment map "
                                                     "(EnvironmentLights.lighting)", optional=True)}
    outputs = {"image": Out(Image, "rendered image (linear RGB)"),
               "depth": Out(Image, "camera-space depth, mesh units, 0 where uncovered"),
               "coverage": Out(Mask, "pixels covered by the mesh")}
    tolerance = {"rtol": 1e-3, "atol": 2e-3}  # rasterisers may differ on edge pixels

    class Params(Node.Params):
        exposure: float = Field(1.0, gt=0, description="multiplier on the light (>1 over-exposes)")
        clamp: bool = Field(True, description="sensor saturation: clamp to [0, 1] after the texture")
        shadows: bool = Field(True, description="cast shadows with shadow maps")
        shadow_map_size: int = Field(1024, ge=16, le=8192, description="shadow-map pixels per side")
        environment_shadows: float = Field(
            0.2, ge=0, le=1, description="an environment's light casts a shadow only if its luminance is at "
                                         "least this fraction of its brightest light's (the dominant ones); "
                                         "the others light the face unshadowed. 0: all cast shadows")
        background: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="linear RGB")
        eye_highlights: Literal["auto", "on", "off"] = Field(
            "auto", description="auto: on when the eyes are known (mediapipe mesh or `eyes`)")
        eyes: Optional[list[list[float]]] = Field(None, description="2×3 world centres of the eye openings")
        cornea_radius_mm: float = Field(7.8, gt=0, description="cornea radius (mm), §5 / Wyszecki–Stiles")
        eye_protrusion_mm: float = Field(1.5, ge=0, description="how far the cornea cap stands out of the eye opening (mm)")
        eye_shininess: float = Field(80.0, gt=0, description="Phong exponent of the cornea")
        eye_specular: float = Field(1.0, ge=0, description="specular intensity of the cornea")
        mm_per_unit: Optional[float] = Field(None, gt=0, description="mesh unit in mm; default from a 63 mm interocular distance")
        fill_holes: bool = Field(True, description="close inner holes (eyes, mouth) so the detail texture covers them")
        ambient_gain: float = Field(1.0, ge=0, description="multiplier on the ambient of the `ambient` input")
        mouth: Literal["photo", "skin"] = Field(
            "photo", description="photo: the mouth (lips, teeth; known on a mediapipe mesh) keeps the photo's "
                                 "detail under the smooth shading of the skin around it, for the fitted mesh "
                                 "does not follow the photo's lips; skin: shaded as skin like the rest")
        antialias: bool = Field(False, description="fractional coverage along the silhouette (0.5 ± the "
                                                   "distance to the mesh's outline): no staircase border")
        environment_basis: int = Field(
            2048, ge=0, le=4096, description="an environment's shadows from the visibility towards this many fixed "
                                            "directions (soft; each direction drawn when a light first needs it and "
                                            "kept per mesh and camera: no shadow map per rotation); 0: a shadow "
                                            "map per light")

    def compute(self, mesh, camera: Camera, material: PhongMaterial, lights=None,
                detail: Image | None = None, texture_camera: Camera | None = None,
                ambient: Light | None = None, environment: EnvironmentLighting | None = None):
        from . import phong

        p = self.params
        # prepare_render's checks; the mesh's part is kept with the geometry
        lights = check_render_inputs(lights, detail, texture_camera, camera, environment)
        g = self._geometry(mesh, camera, detail, texture_camera)
        eye_mesh, mesh = mesh, g.mesh
        lights = world_lights(lights, camera, mesh)
        own = len(lights)  # the lights given on `lights`: each must light the face
        if environment is not None:
            lights += world_lights(environment.lights, camera, mesh, "environment")
        s = g.surface
        H, W = camera.height, camera.width
        M = len(s.points)
        kd = np.asarray(material.diffuse, np.float64)
        col = np.zeros((M, 3))
        amb = np.zeros(3)
        lit = []  # (light, the points facing it, L, their lobes, shadow-map task, its cost)
        sizes = shadow_map_sizes(lights, p.shadow_map_size, own, p.environment_shadows)
        round_ = []  # the directions of the environment lights shadowed from the visibility basis
        for i, light in enumerate(lights):
            ldir, L = light_vectors(light, s.points)
            # only the points facing the light: elsewhere it adds nothing (+0), whatever its
            # shadow (an environment's lights face ~⅓ of the face)
            nl = phong.dot(s.normals, ldir)
            idx = np.flatnonzero(nl > 0)
            if i < own:
                check_lit(nl, "lights", f"light {i} ({light.kind}, direction {light.direction}, "
                                        f"position {light.position})", f"{M} visible pixels")
            elif len(idx) == 0:
                continue
            diff, spec = phong.lobes(s.normals[idx], ldir[idx], s.view[idx], material.shininess)
            # a map's time, measured: ~2.5 ms of set-up (~90k texels' worth) + the texels drawn,
            # the facing points' share of the map (all of it for soft shadows); no map (None):
            # shadows off, or an environment light too dim to cast one (side 0)
            cost = 90000 + sizes[i] ** 2 * (1.0 if is_sized(light) else len(idx) / M)
            if not (p.shadows and sizes[i]):
                task = None
            elif i >= own and p.environment_basis:  # from the visibility basis: no map
                d = np.asarray(light.direction)
                task, cost = functools.partial(self._basis(g).light, d, idx), len(idx)
                round_.append(d)
            else:
                task = functools.partial(self._visibility, mesh, light, camera, s, idx, i,
                                         "lights" if i < own else "environment", sizes[i])
            lit.append((light, idx, L[idx], diff, spec, task, cost))
        if round_:  # the basis directions those lights read, drawn once
            self._basis(g).draw(round_)
            if self.ctx.interactive:  # a live session: the rest drawn before the next rotation needs it
                self._basis(g).fill_in_background(self.ctx.background_progress)
        # the lights' shadows are independent: on the cores (an environment's dominant lights),
        # dealt by cost
        cast = [t for t in lit if t[5] is not None]
        vis = iter(run_balanced([t[5] for t in cast], [t[6] for t in cast]))
        vis = [1.0 if t[5] is None else next(vis) for t in lit]
        for v in vis:
            if isinstance(v, BadInput):
                raise v
        for (light, idx, L, diff, spec, _, _), v in zip(lit, vis):
            col[idx] += phong.shade(kd, material.specular, 0.0, L, diff * v, spec * v)
            amb += np.asarray(light.ambient, np.float64) * material.ambient_scale
        if ambient is not None:
            amb += np.asarray(ambient.ambient, np.float64) * material.ambient_scale * p.ambient_gain
        col += kd * amb
        if environment is not None:
            col += kd * sh_irradiance(environment.sh, s.normals)
        if g.mouth is not None:
            col = g.mouth(col)
        if g.texture is not None:
            col = col * g.texture
        # the image over g.box (every pixel outside it is the background)
        bg = np.asarray(p.background, np.float64)
        box = g.box
        img = np.empty((box[0].stop - box[0].start, box[1].stop - box[1].start, 3))
        img[:] = bg
        img[s.coverage[box]] = col
        cover = s.coverage.astype(np.float32)
        if g.edges is not None:  # (the box is the whole image)
            cover, src = g.edges
            img = cover[:, :, None] * img.reshape(-1, 3)[src].reshape(H, W, 3) \
                + (1.0 - cover[:, :, None]) * bg
        if g.eyes:
            idx, add = self._eyes(g.eyes, lights)
            img.reshape(-1, 3)[idx] += add
        fill = self._exposed(bg)
        if fill.view(np.uint32).any():
            out = np.empty((H, W, 3), np.float32)
            out[:] = fill
        else:  # a black background: zeroed pages from the system, not written here
            out = np.zeros((H, W, 3), np.float32)
        out[box] = self._exposed(img)
        return {"image": Image(out),
                "depth": Image(g.depth.copy()),
                "coverage": Mask(cover)}

    def _exposed(self, img: np.ndarray) -> np.ndarray:
        """``img`` × exposure, clamped to [0, 1] with ``clamp``, as float32."""
        img = img * self.params.exposure
        if self.params.clamp:
            img = np.clip(img, 0.0, 1.0, out=img)
        return img.astype(np.float32)

    def _visibility(self, mesh, light, camera: Camera, s: Surface, idx: np.ndarray, i: int,
                    port: str, size: int) -> np.ndarray | BadInput:
        """Shadow-map visibility of the surface's points ``idx`` (those facing it) from light
        ``i`` (soft for a light with a size) on a ``size``² map; a shadow-map failure is bad
        input on ``port``, returned (the caller raises the first light's, however the tasks
        ran on the cores)."""
        from nodes.common.shadows import mesh_visibility

        try:
            return mesh_visibility(mesh.vertices, mesh.faces, light, size, s.points[idx],
                                   s.normals[idx], up=camera.rotation[1])
        except ValueError as e:
            return BadInput(port, f"light {i}: {e}")

    def _basis(self, g: "_Geometry"):
        """The geometry's visibility basis for ``environment_basis`` directions (made once)."""
        from .visibility import VisibilityBasis

        n = self.params.environment_basis
        with _GEOMETRY_LOCK:  # (nodes may run on several threads: made once)
            if n not in g.bases:
                g.bases[n] = VisibilityBasis(g.mesh, g.surface, n)
        return g.bases[n]

    def _geometry(self, eye_mesh, camera: Camera, detail, texture_camera) -> "_Geometry":
        """What does not depend on the lights or the material (the surface, its detail texture,
        the eyes' ray hits, the mouth, the silhouette's coverage): memoised on the inputs and
        params it comes from, so that a new light re-shades without it (a live view's drag)."""
        p = self.params
        given = {"mesh": eye_mesh, "camera": camera, "detail": detail, "texture_camera": texture_camera}
        key = xxhash.xxh3_128(canonical([
            {k: None if v is None else value_parts(self.in_ports[k].type, v)[2] for k, v in given.items()},
            p.fill_holes, p.eye_highlights, p.eyes, p.cornea_radius_mm, p.eye_protrusion_mm, p.mm_per_unit,
            p.mouth, p.antialias])).hexdigest()
        got = _GEOMETRY.get(key)
        if got is None:
            got = self._make_geometry(eye_mesh, camera, detail, texture_camera)
            with _GEOMETRY_LOCK:  # nodes may run on several threads (graphkit run --jobs)
                while len(_GEOMETRY) >= 4:
                    _GEOMETRY.pop(next(iter(_GEOMETRY)))
                _GEOMETRY[key] = got
        return got

    def _make_geometry(self, eye_mesh, camera: Camera, detail, texture_camera) -> "_Geometry":
        from nodes.common import raster

        p = self.params
        mesh = prepare_mesh(eye_mesh, camera, texture_camera, p.fill_holes)
        s = surface(mesh, camera, min_pixels=1)
        tex = None
        if detail is not None:
            tex = projective_texture(detail, texture_camera, mesh, s.points)[:, :3]
        eyes = None if p.eye_highlights == "off" else self._eye_hits(eye_mesh, camera, s)
        mouth = mouth_region(eye_mesh, camera) if p.mouth == "photo" else None
        if mouth is not None:
            mouth = SmoothOver(s.coverage, mouth[0], 0.5 * mouth[1])
        edges = None
        if p.antialias:
            xy, _ = camera.project(np.asarray(mesh.vertices, np.float64))
            edges = raster.edge_coverage(xy, mesh.faces, s.coverage)
        depth = np.where(s.coverage, s.raster.depth, 0.0).astype(np.float32)
        box, eyes = _image_box(s.coverage, eyes, whole=edges is not None)
        return _Geometry(mesh, s, tex, eyes, mouth, edges, depth, box, {})

    @classmethod
    def examples(cls):
        """Both camera kinds: perspective and orthographic, directional and point lights
        (positions in metres: the world unit here is 0.25 m), shadows, a detail texture."""
        import trimesh

        m = trimesh.creation.icosphere(subdivisions=3)
        m.vertices *= [0.8, 1.0, 0.9]
        m.apply_translation([0, 0, 4.0])
        cam = Camera(width=48, height=40, fx=70, fy=70, cx=24, cy=20, metres_per_unit=0.25)
        ortho = Camera(width=48, height=40, projection="orthographic", pixels_per_m=64.0,
                       cx=24, cy=20, metres_per_unit=0.25)
        mat = PhongMaterial(diffuse=(0.6, 0.4, 0.3), specular=0.3, shininess=15.0)
        lights = [Light(direction=(0.5, -0.3, -0.8)),
                  Light(kind="point", position=(-0.75, 0.0, 0.0), color=(0.3, 0.5, 1.0), intensity=1.2)]
        detail = Image(np.random.default_rng(0).uniform(0.5, 1.5, (40, 48, 3)).astype(np.float32))
        return [({}, {"mesh": m, "camera": cam, "material": mat, "lights": lights[:1]}),
                ({"exposure": 2.0, "shadow_map_size": 128},
                 {"mesh": m, "camera": cam, "material": mat, "lights": lights, "detail": detail,
                  "texture_camera": cam}),
                ({}, {"mesh": m, "camera": ortho, "material": mat, "lights": lights[:1]}),
                ({"exposure": 1.5, "shadow_map_size": 128},
                 {"mesh": m, "camera": ortho, "material": mat, "lights": lights, "detail": detail,
                  "texture_camera": cam}),
                ({"shadow_map_size": 128},
                 {"mesh": m, "camera": cam, "material": mat, "lights": lights[1:], "detail": detail,
                  "texture_camera": ortho}),
                ({"shadow_map_size": 128, "environment_basis": 0},  # (shadow maps: the GL programs draw them)
                 {"mesh": m, "camera": cam, "material": mat, "environment": _example_environment()})]

    def _eye_hits(self, mesh, camera, s: Surface) -> list | None:
        """Where the rays of the pixels meet the two cornea hemispheres: per eye (flat pixel
        indices, points, unit normals, directions towards the viewer); None when the eyes are
        unknown (refused when ``eye_highlights`` is 'on')."""
        p = self.params
        info = eye_spheres(mesh, p.eyes, p.cornea_radius_mm, p.mm_per_unit,
                           p.eye_protrusion_mm, camera.position)
        if info is None:
            if p.eye_highlights == "on":
                raise BadInput("mesh", "eye_highlights is 'on' but the eyes are unknown: the mesh "
                                       "is not a mediapipe face mesh; set the `eyes` param")
            return None
        centres, axes, R = info
        depth = s.raster.depth.ravel()
        C, fwd = camera.position, camera.forward
        hits = []
        for c, a in zip(centres, axes):
            # rays through the pixel centres (perspective or orthographic) of the box the
            # sphere projects into: a 12-megapixel photo's eyes are a few thousand of them
            idx = _sphere_pixels(camera, c, R)
            yy, xx = np.divmod(idx, camera.width)
            o, d = camera.rays(np.stack([xx + 0.5, yy + 0.5], 1))
            oc = o - c
            bq = np.sum(d * oc, 1)
            disc = bq ** 2 - (np.sum(oc * oc, 1) - R * R)
            hit = disc > 0
            t = -bq - np.sqrt(np.where(hit, disc, 0))
            X = o + d * t[:, None]
            hit &= (t > 0) & (np.sum((X - c) * a, 1) >= 0)
            zc = (X - C) @ fwd
            hit &= zc <= depth[idx] + R * 0.35  # the cap shows where it is not behind the eyelids
            if hit.any():
                hits.append((idx[hit], X[hit], (X[hit] - c) / R, -d[hit]))
        return hits

    def _eyes(self, hits: list, lights) -> tuple[np.ndarray, np.ndarray]:
        """Additive specular of the two cornea hemispheres: (the pixels it lights, flat
        indices as in ``hits``, sorted; its value there, K×3)."""
        from . import phong

        p = self.params
        idx = np.unique(np.concatenate([h[0] for h in hits]))
        out = np.zeros((len(idx), 3))
        for hit, X, n, v in hits:
            at = np.searchsorted(idx, hit)
            for light in lights:
                ldir, L = light_vectors(light, X)
                _, spec = phong.lobes(n, ldir, v, p.eye_shininess)
                out[at] += p.eye_specular * L * spec[:, None]
        return idx, out


def _sphere_pixels(camera: Camera, centre, radius: float) -> np.ndarray:
    """Flat indices (row-major, ascending) of the pixels whose centres lie in the box that the
    sphere (``centre``, ``radius``) projects into, a pixel wider each way: the corners of the
    cube about the sphere bound its image when they are all in front of the camera; otherwise
    every pixel."""
    H, W = camera.height, camera.width
    corners = np.asarray(centre, np.float64) + radius * np.array(
        [[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], np.float64)
    xy, z = camera.project(corners)
    if camera.orthographic or (z > 0).all():
        x0, y0 = np.floor(xy.min(0)).astype(int) - 1
        x1, y1 = np.ceil(xy.max(0)).astype(int) + 1
        x0, x1, y0, y1 = max(x0, 0), min(x1, W - 1), max(y0, 0), min(y1, H - 1)
        if x0 > x1 or y0 > y1:
            return np.zeros(0, np.int64)
        yy, xx = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        return (yy * W + xx).ravel().astype(np.int64)
    return np.arange(H * W, dtype=np.int64)


class _Geometry(NamedTuple):
    """Render's work that does not depend on the lights or the material."""
    mesh: object  # prepare_mesh: the mesh drawn
    surface: Surface
    texture: np.ndarray | None  # M×3 detail texture at the covered pixels
    eyes: list | None  # Render._eye_hits
    mouth: SmoothOver | None  # over mouth_region
    edges: tuple[np.ndarray, np.ndarray] | None  # raster.edge_coverage
    depth: np.ndarray  # the depth output (float32, 0 where uncovered)
    box: tuple[slice, slice]  # _image_box: the pixels that are not the background
    bases: dict  # visibility.VisibilityBasis by its number of directions, made when first asked


def _image_box(coverage: np.ndarray, eyes: list | None, whole: bool) -> tuple[tuple[slice, slice], list | None]:
    """(the box of the pixels Render shades: the covered ones and the eyes' hits; the whole
    image when ``whole``, the eyes' hits with their pixels' flat indices in that box)."""
    H, W = coverage.shape
    if whole:
        return (slice(0, H), slice(0, W)), eyes
    ys, xs = np.nonzero(coverage)
    if eyes:
        ey, ex = np.divmod(np.concatenate([h[0] for h in eyes]), W)
        ys, xs = np.concatenate([ys, ey]), np.concatenate([xs, ex])
    y0, x0 = int(ys.min()), int(xs.min())
    box = (slice(y0, int(ys.max()) + 1), slice(x0, int(xs.max()) + 1))
    if eyes:
        bw = box[1].stop - x0
        eyes = [((i // W - y0) * bw + i % W - x0, X, n, v) for i, X, n, v in eyes]
    return box, eyes


#: the last _Geometry values by the digest of what they come from (a live view's face, a
#: benchmark's; ~60 MB for a 1024² face, mostly the raster's per-pixel arrays)
_GEOMETRY: dict = {}
_GEOMETRY_LOCK = threading.Lock()


class MakeLight(Node):
    """A light source from params, in the WORLD frame (Paris 2003 §4: the flash, or a light to
    relight with).

    The direction (towards the light, OpenCV axes: x right, y down, z forward) is given either
    as a vector or by ``azimuth_deg`` (positive: towards the image's right) and
    ``elevation_deg`` (positive: up) around the axis pointing back at the camera (−z); 0, 0 is
    a frontal light.  Without a ``camera`` these axes are the world's; with one, they are that
    camera's (and ``position_m`` / ``target_m`` are metres from its centre along its axes), and
    the light is turned into the world frame with the camera's pose.

    A point light sits at ``position_m``, or, with ``distance_m``, at ``target_m`` +
    ``distance_m`` × the direction; its ``intensity`` is a radiant intensity (flash units × m²:
    the irradiance at d metres is intensity / d², always), and its ``direction`` is the unit
    vector from ``target_m`` towards it.  Units: degrees, metres.
    """

    version = "2"
    inputs = {"camera": In(Camera, "express the angles and positions in this camera's frame",
                           optional=True)}
    outputs = {"light": Out(Light, "the light (world frame)")}

    class Params(Node.Params):
        kind: Literal["directional", "point"] = Field("directional", description="light kind")
        azimuth_deg: float = Field(0.0, ge=-180, le=180, description="left/right angle from the camera axis (degrees, + = right)")
        elevation_deg: float = Field(0.0, ge=-90, le=90, description="up/down angle (degrees, + = up)")
        direction: Optional[tuple[float, float, float]] = Field(None, description="explicit direction towards the light (overrides the angles)")
        position_m: Optional[tuple[float, float, float]] = Field(None, description="point light: position (metres; world, or the camera's frame when a camera is connected)")
        distance_m: Optional[float] = Field(None, gt=0, description="point light: distance from target_m along the direction (metres), instead of position_m")
        target_m: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="what a point light at distance_m is placed around, and lights (metres, same frame as position_m)")
        color: tuple[float, float, float] = Field((1.0, 1.0, 1.0), description="linear RGB hue")
        intensity: float = Field(1.0, ge=0, description="directional: irradiance (1 = the flash of the photo); point: radiant intensity (flash units × m²)")
        ambient: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="ambient, linear RGB (flash units)")

    def compute(self, camera: Camera | None = None):
        p = self.params
        if p.direction is not None:
            d = unit_direction(p.direction, "direction")
        else:
            a, e = np.radians(p.azimuth_deg), np.radians(p.elevation_deg)
            d = np.array([np.sin(a) * np.cos(e), -np.sin(e), -np.cos(a) * np.cos(e)])
        pos = np.zeros(3)
        if p.kind == "point":
            target = np.asarray(p.target_m, np.float64)
            if p.position_m is not None and p.distance_m is not None:
                raise BadInput("distance_m", "give position_m or distance_m (with the angles), not both")
            if p.position_m is not None:
                pos = np.asarray(p.position_m, np.float64)
                v = pos - target
                if np.linalg.norm(v) > 0:
                    d = v / np.linalg.norm(v)
            elif p.distance_m is not None:
                pos = target + p.distance_m * d
            else:
                raise BadInput("position_m", "a point light needs position_m, or distance_m with the "
                                             "angles (metres)")
        elif p.position_m is not None or p.distance_m is not None:
            raise BadInput("position_m" if p.position_m is not None else "distance_m",
                           "position_m / distance_m are for point lights (set kind: point)")
        light = Light(kind=p.kind, direction=tuple(float(v) for v in d),
                      position=tuple(float(v) for v in pos), color=p.color,
                      intensity=p.intensity, ambient=p.ambient)
        return camera.light_to_world(light) if camera is not None else light


class LightSize(Node):
    """A light with a size, for soft shadows (Paris 2003 §7: shadow boundaries on skin "are
    always soft"): a point light becomes a sphere of ``radius_m`` metres, a directional light a
    disc of ``angular_radius_deg`` (the sun: 0.27°, a window or a softbox: several degrees).
    Render then casts shadows with a penumbra set by that size (percentage-closer soft
    shadows); its light and shading are otherwise those of the light's centre.  0: no size, a
    point or parallel light (a flash stays sharp).  Units: metres, degrees.
    """

    version = "1"
    inputs = {"light": In(Light, "the light (any frame)")}
    outputs = {"light": Out(Light, "the same light with its size")}

    class Params(Node.Params):
        radius_m: float = Field(0.0, ge=0, description="point light: radius of the emitting sphere (metres)")
        angular_radius_deg: float = Field(0.0, ge=0, lt=90, description="directional light: angular radius of the emitting disc (degrees)")

    def compute(self, light: Light):
        p = self.params
        if p.radius_m and light.kind != "point":
            raise BadInput("radius_m", "the light is directional: give its size as angular_radius_deg")
        if p.angular_radius_deg and light.kind != "directional":
            raise BadInput("angular_radius_deg", "the light is a point light: give its size as radius_m (metres)")
        return light.model_copy(update={"radius_m": p.radius_m, "angular_radius_deg": p.angular_radius_deg})

    @classmethod
    def examples(cls):
        return [({"angular_radius_deg": 3.0}, {"light": Light(direction=(0.0, 0.0, -1.0))}),
                ({"radius_m": 0.1}, {"light": Light(kind="point", position=(0.0, 0.0, -1.0))}),
                ({}, {"light": Light()})]


class FrameFace(Node):
    """A camera framing the mesh: the same pose and projection as ``camera`` (perspective or
    orthographic), the image magnified so the mesh's projection fills a ``size``² image with a
    margin; with ``image`` (taken by ``camera``) also that image resampled into the new view
    (bilinear).  ``size`` unset keeps the photo's own pixel scale (a crop, no magnification: the
    detail texture is not blurred).  For close-ups of a face that is small in its photo (Render
    takes the camera; the photo keeps its own camera as ``texture_camera``).  Units: pixels.
    """

    version = "2"
    inputs = {"mesh": In(Mesh, "the mesh to frame", finite=True),
              "camera": In(Camera, "the original camera"),
              "image": In(Image, "an image taken by `camera`, to resample", optional=True,
                          same_size_as="camera")}
    outputs = {"camera": Out(Camera, "the framing camera"),
               "image": Out(Image, "the image in the framing camera (black if no image)")}

    class Params(Node.Params):
        size: Optional[int] = Field(None, ge=8, le=8192, description="output width and height (pixels); "
                                                                     "default: the photo's pixel scale")
        margin: float = Field(0.12, ge=0, lt=2, description="margin around the mesh, fraction of its size")

    def compute(self, mesh, camera: Camera, image: Image | None = None):
        check_mesh(mesh)
        check_in_view(mesh, camera)
        xy, z = camera.project(np.asarray(mesh.vertices, np.float64))
        lo, hi = xy.min(0), xy.max(0)
        side = float(max(hi - lo)) * (1 + 2 * self.params.margin)
        if not side > 0:
            raise BadInput("mesh", "the mesh projects to a point")
        if self.params.size is None:
            n = int(np.ceil(side))
            k = 1.0
        else:
            n = self.params.size
            k = n / side  # new pixels per old pixel
        c = (lo + hi) / 2
        if self.params.size is None:  # whole-pixel crop: the new pixel centres are the photo's
            c = np.round(c - n / 2) + n / 2
        cam = camera.reframed(n, n, k, (float(c[0]), float(c[1])))
        out = np.zeros((n, n, image.channels if image is not None else 3), np.float32)
        if image is not None:
            yy, xx = np.mgrid[0:n, 0:n]
            u = (xx.ravel() + 0.5 - n / 2) / k + c[0]
            v = (yy.ravel() + 0.5 - n / 2) / k + c[1]
            out = _bilinear(image.pixels.astype(np.float64), u, v).reshape(n, n, -1).astype(np.float32)
        return {"camera": cam, "image": Image(out)}


class MeshMask(Node):
    """The pixels a mesh covers through a camera (perspective or orthographic), as a Mask (e.g.
    the face region of the photo for SkinSegment, Paris 2003 §3), optionally with its inner
    holes (eyes, mouth) left open.  A mesh behind or beside the camera, or one covering no
    pixel, is refused here (BadInput on ``mesh``), not passed on as an empty mask."""

    version = "2"
    inputs = {"mesh": In(Mesh, "the mesh", finite=True), "camera": In(Camera, "the camera")}
    outputs = {"mask": Out(Mask, "1 where the mesh is seen")}

    class Params(Node.Params):
        fill_holes: bool = Field(False, description="count the inner holes (eyes, mouth) as covered")

    def compute(self, mesh, camera: Camera):
        check_mesh(mesh)
        s = surface(close_holes(mesh) if self.params.fill_holes else mesh, camera, min_pixels=1)
        return Mask(s.coverage.astype(np.float32))
