"""The GL scene of ``Render`` (Paris 2003 §5): the arrays and uniforms that the programs of
``shaders/glsl/`` (depth, gbuffer, shade; through ``graphkit.glsl``) take, prepared on the host
in float64 from the node's inputs.  One implementation for both GL drivers of those shaders:
the ``opengl`` backend (plugins/graphkit-moderngl) and the studio's WebGL2 face view
(``nodes/paris/studio_view.py``).

* camera: perspective or orthographic (``graphkit.Camera``): its ``pixel_matrix`` → a GL clip
  matrix whose window coordinates *are* the reference's pixel coordinates (pixel centres at
  +0.5); vertices are turned into the camera frame in float64 here; triangles with a vertex at
  z ≤ 1e-6 are dropped, as the reference rasteriser does.
* shadow maps: the light frames of ``nodes.common.raster.shadow_frame`` (the one
  implementation), one atlas tile per light.
* the detail texture, its camera's clip matrix and occlusion tolerance; the eye spheres.
"""
from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from graphkit import BadInput, Camera, Light

MAX_LIGHTS = 32  # as the GL drivers take them
NEAR = 1e-6  # the reference rasteriser's near limit


_STATIC: "OrderedDict[bytes, tuple]" = OrderedDict()  # scene()'s light-independent set-ups
_STATIC_KEEP = 4
_STATIC_LOCK = threading.Lock()  # node threads and the studio's view threads share it


def not_drawn(p, mesh, lights=(), environment=None) -> str | None:
    """What Render's params ``p`` ask of ``mesh`` and ``lights`` that the GL programs (the opengl
    backend, the studio's WebGL face view) do not draw, as a sentence, or None: ``antialias``,
    ``mouth: photo`` on a mediapipe mesh (where the numpy reference keeps the photo's mouth),
    the soft shadows of a light with a size (LightSize; the GL programs draw hard shadow maps),
    and an ``environment``'s shadows from the visibility basis (``environment_basis`` > 0)."""
    from nodes.paris.environment import shadow_map_sizes
    from nodes.paris.render import _mediapipe_ids

    missing = []
    if p.mouth == "photo" and _mediapipe_ids(mesh) is not None:
        missing.append("mouth: photo (the mesh is a mediapipe face)")
    if p.antialias:
        missing.append("antialias: true")
    lights = lights if isinstance(lights, (list, tuple)) else [lights]
    sized = [i for i, light in enumerate(lights) if light is not None and light.has_size]
    if p.shadows and sized:
        missing.append(f"the soft shadows of light {sized[0]} (it has a size)")
    if p.shadows and p.environment_basis and environment is not None and \
            any(shadow_map_sizes(environment.lights, p.shadow_map_size, 0, p.environment_shadows)):
        missing.append(f"the environment's shadows from a visibility basis (environment_basis: {p.environment_basis})")
    if not missing:
        return None
    return (f"{' and '.join(missing)} are drawn by the numpy reference only; set mouth: skin, "
            f"antialias: false, lights without a size and environment_basis: 0 (or shadows: false) to use "
            "the GL programs")


def scene(p, mesh, camera: Camera, material, lights, detail=None, texture_camera=None, ambient=None,
          key: bytes | None = None, environment=None):
    """(job, lights in world units, per-light shadow-map errors or None, eyes) for Render's
    params ``p`` and inputs: the job is a dict of arrays and uniforms (see the GL drivers).
    An ``environment`` (EnvironmentLighting): its lights follow ``lights`` (job["own"] = how
    many were given on ``lights``: only those must light the face) and its SH ambient is
    job["env_sh"] (9 RGB weights, environment.sh_irradiance_weights; None without one).

    ``key``: a content key of the inputs the set-up depends on besides the lights, material
    and ambient (``p``, ``mesh``, ``camera``, ``detail``, ``texture_camera``; e.g. from their
    cache digests, ``static_key``).  With one, that set-up (holes closed, normals, camera and
    texture geometry, content keys of the GL objects, eyes, screen boxes) is kept between
    calls, so a call that changes only the lights redoes only their part."""
    from nodes.paris.environment import sh_irradiance_weights
    from nodes.paris.render import check_render_inputs, world_lights

    with _STATIC_LOCK:
        hit = _STATIC.get(key) if key is not None else None
        if hit is not None:
            _STATIC.move_to_end(key)
    if hit is None:
        static, m, V, F, up = _static_part(p, mesh, camera, lights, detail, texture_camera, environment)
        if key is not None:
            with _STATIC_LOCK:
                _STATIC[key] = (static, m, V, F, up)
                while len(_STATIC) > _STATIC_KEEP:
                    _STATIC.popitem(last=False)
    else:
        static, m, V, F, up = hit
    lights = world_lights(check_render_inputs(lights, detail, texture_camera, camera, environment), camera, m)
    own = len(lights)
    if environment is not None:
        lights += world_lights(environment.lights, camera, m, "environment")
    if len(lights) > MAX_LIGHTS:
        raise BadInput("lights" if own > MAX_LIGHTS else "environment",
                       f"{len(lights)} lights: the opengl backend takes at most "
                       f"{MAX_LIGHTS} (the numpy backend any number)")
    job = dict(static)
    job["own"] = own
    job["env_sh"] = None if environment is None else sh_irradiance_weights(environment.sh)
    kd = np.asarray(material.diffuse, np.float64)
    amb = np.zeros(3)
    for light in lights:
        amb += np.asarray(light.ambient, np.float64) * material.ambient_scale
    if ambient is not None:
        amb += np.asarray(ambient.ambient, np.float64) * material.ambient_scale * p.ambient_gain
    job["material"] = (kd, float(material.specular), float(material.shininess), amb)
    # shadow maps (same frames as nodes.common.raster.shadow_map)
    part, sm_errors = light_part(p, V, F, lights, up, own)
    job.update(part)
    return job, lights, sm_errors, job["eyes"]


def static_key(p, digests: dict, mesh=None, camera=None, detail=None, texture_camera=None) -> bytes | None:
    """scene()'s ``key`` from Render's params and the cache digests of its inputs
    (``graphkit.Context.inputs``); where the engine did not give them (a direct call of the
    backend), from the content of the inputs given here (None if ``mesh`` is not given)."""
    names = ("mesh", "camera", "detail", "texture_camera")
    if digests and all(isinstance(digests.get(n), str) for n in names[:2]):
        return digest("Render.scene", p.model_dump_json(), *[digests.get(n) for n in names])
    if mesh is None or camera is None:
        return None
    src = getattr(mesh, "vertex_attributes", {}).get("source_vertex")
    parts = [np.asarray(mesh.vertices), np.asarray(mesh.faces), np.asarray(mesh.vertex_normals),
             None if src is None else np.asarray(src)]
    for c in (camera, texture_camera):
        parts.append(None if c is None else c.model_dump_json())
    parts.append(None if detail is None else np.asarray(detail.pixels))
    return digest("Render.scene/content", p.model_dump_json(), *parts)


def _static_part(p, mesh, camera, lights, detail, texture_camera, environment=None):
    """(the light-independent part of the job, the drawn mesh, its float64 vertices and
    faces, the camera's up vector) for scene()."""
    from nodes.paris.render import eye_spheres, prepare_render, vertex_normals

    eye_mesh = mesh
    _, mesh = prepare_render(mesh, camera, lights, detail, texture_camera, p.fill_holes, environment)
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    vn = vertex_normals(mesh)
    H, W = camera.height, camera.width

    job = dict(W=W, H=H, p=p)
    # camera pass
    qc = camera.to_camera(V)
    job["main"] = _view_geometry(qc, F, camera_clip(camera), not camera.orthographic, near=True)
    job["vertices"] = np.hstack([qc, V, vn]).astype(np.float32)
    job["vertices_key"] = digest(job["vertices"])
    job["faces_key"] = digest(job["main"][1])
    job["mesh_faces"] = np.ascontiguousarray(F, np.int32)  # all faces (the studio's shadow maps)
    job["cam_pos"] = camera.position
    job["cam_ortho"] = camera.orthographic
    job["cam_back"] = -camera.forward
    # projective detail texture (render.projective_texture)
    job["detail"] = None
    det_key = None
    if detail is not None:
        px = np.asarray(detail.pixels, np.float32)
        if px.ndim == 2:
            px = px[..., None]
        if px.shape[2] == 1:  # (check_render_inputs refuses 2 channels)
            px = np.repeat(px, 3, axis=2)
        px = np.ascontiguousarray(px[..., :3])
        tc = texture_camera
        qt = tc.to_camera(V)
        scale = float(np.median(np.ptp(V, axis=0))) or 1.0
        proj = np.zeros((4, 4))
        proj[:3] = tc.world_pixel_matrix()
        proj[3] = tc.pose[2]  # camera z
        geom = _view_geometry(qt, F, camera_clip(tc), not tc.orthographic, near=True)
        q32 = qt.astype(np.float32)
        q_key = (digest(q32), digest(geom[1]))
        det = dict(pixels=px, cam=tc, tol=0.02 * scale, proj=proj, geom=geom, q=q32, q_key=q_key,
                   pixels_key=digest(px), depth_key=digest(q_key, geom[0], tc.width, tc.height))
        det_key = (det["pixels_key"], det["depth_key"], digest(proj, det["tol"]))
        job["detail"] = det
    job["gbuffer_key"] = digest(job["vertices_key"], job["faces_key"], job["main"][0],
                                np.asarray(job["cam_pos"]), np.asarray(job["cam_back"]),
                                bool(job["cam_ortho"]), det_key)
    # eye highlights (Render._eyes)
    eyes = None
    if p.eye_highlights != "off":
        eyes = eye_spheres(eye_mesh, p.eyes, p.cornea_radius_mm, p.mm_per_unit,
                           p.eye_protrusion_mm, camera.position)
    job["eyes"] = eyes
    # each pixel's world ray (the eye highlights; the WebGL surface pass's EXACT mode)
    job["ray_org"], job["ray_dir"] = camera.ray_matrices()
    job["fwd"] = camera.forward
    # the lighting pass runs only where a surface or an eye can be (every other pixel is the
    # background, glscene.background_out): the mesh's box without the eye highlights, then
    # the eyes' box with them (a second program over that small box)
    Fm = job["main"][1]
    job["bbox"] = screen_box(camera, qc[used_vertices(Fm, len(qc))])
    job["eye_box"] = None
    job["boxes"] = [job["bbox"]]  # the boxes of the pass without the eye highlights
    if eyes is not None:
        job["eye_box"] = screen_box(camera, camera.to_camera(_eye_cube_corners(eyes)))
        # the eyes' program shades every pixel of its box: the other one skips that box
        job["boxes"] = box_minus(job["bbox"], job["eye_box"])
        job["bbox"] = union_box(job["bbox"], job["eye_box"])
    job["bg_out"] = background_out(p)
    return job, mesh, V, F, camera.rotation[1]


def light_part(p, V: np.ndarray, F: np.ndarray, lights, up, own: int | None = None) -> tuple[dict, list]:
    """(the light-dependent part of the job: ``lights`` uniforms, ``shadow`` frames or None,
    ``sm_sizes`` and ``shadow_key``; per-light shadow-map errors or None) for world-unit
    ``lights`` (scene()'s second result; those after the first ``own`` an environment's, whose
    maps are sized as numpy's, side 0 for none: environment.shadow_map_sizes) and the drawn mesh's
    vertices/faces; what a light drag recomputes."""
    from nodes.paris.environment import shadow_map_sizes

    own = len(lights) if own is None else own
    sizes = shadow_map_sizes(lights, p.shadow_map_size, own, p.environment_shadows)
    part = {"lights": [_light_uniforms(light) for light in lights], "shadow": None, "sm_sizes": sizes}
    sm_errors = [None] * len(lights)
    if p.shadows and lights:  # (none: an environment's SH ambient alone, unshadowed)
        sms = []
        for i, light in enumerate(lights):
            if not sizes[i]:  # an environment light that casts no shadow (shade.frag: SM_SIZE 0)
                sms.append(None)
                continue
            try:
                sm = _shadow_setup(V, F, light, sizes[i], up=up)
                sm["key"] = (digest(sm["q"]), digest(sm["faces"]))
                sms.append(sm)
            except ValueError as e:
                sm_errors[i] = str(e)
                sms.append(None)
        part["shadow"] = sms
        part["shadow_key"] = digest(p.shadow_map_size, *[
            None if sm is None else (sm["key"], digest(sm["clip"])) for sm in sms])
    return part, sm_errors


def screen_box(camera: Camera, q: np.ndarray) -> tuple[int, int, int, int]:
    """(x, y, w, h): the pixels (GL window = pixel coordinates, row 0 first) that a surface
    with camera-frame points ``q`` as its bounds can cover: their projected bounds, one pixel
    of margin; the whole image where a bound cannot be trusted (a point behind the camera)."""
    W, H = camera.width, camera.height
    if len(q) == 0:
        return 0, 0, 0, 0
    if not camera.orthographic and not np.all(q[:, 2] > NEAR):
        return 0, 0, W, H
    h = np.hstack([q, np.ones((len(q), 1))]) @ camera.pixel_matrix().T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = h[:, :2] / h[:, 2:3]
    if not np.all(np.isfinite(uv)):
        return 0, 0, W, H
    x0 = int(np.clip(np.floor(uv[:, 0].min()) - 1, 0, W))
    x1 = int(np.clip(np.ceil(uv[:, 0].max()) + 1, 0, W))
    y0 = int(np.clip(np.floor(uv[:, 1].min()) - 1, 0, H))
    y1 = int(np.clip(np.ceil(uv[:, 1].max()) + 1, 0, H))
    return x0, y0, max(x1 - x0, 0), max(y1 - y0, 0)


def box_minus(a, b) -> list:
    """Up to four (x, y, w, h) boxes that cover box ``a`` without box ``b``: below, above, left
    and right of ``b`` (empty ones left out)."""
    ax0, ay0, ax1, ay1 = a[0], a[1], a[0] + a[2], a[1] + a[3]
    if not (b[2] and b[3]) or not (a[2] and a[3]):
        return [tuple(a)] if a[2] and a[3] else []
    bx0, by0 = min(max(b[0], ax0), ax1), min(max(b[1], ay0), ay1)
    bx1, by1 = min(max(b[0] + b[2], ax0), ax1), min(max(b[1] + b[3], ay0), ay1)
    out = [(ax0, ay0, ax1 - ax0, by0 - ay0), (ax0, by1, ax1 - ax0, ay1 - by1),
           (ax0, by0, bx0 - ax0, by1 - by0), (bx1, by0, ax1 - bx1, by1 - by0)]
    return [tuple(int(v) for v in r) for r in out if r[2] > 0 and r[3] > 0]


def union_box(a, b):
    """The smallest (x, y, w, h) holding boxes ``a`` and ``b`` (empty boxes ignored)."""
    if not (a[2] and a[3]):
        return tuple(b)
    if not (b[2] and b[3]):
        return tuple(a)
    x0, y0 = min(a[0], b[0]), min(a[1], b[1])
    return x0, y0, max(a[0] + a[2], b[0] + b[2]) - x0, max(a[1] + a[3], b[1] + b[3]) - y0


def _eye_cube_corners(eyes) -> np.ndarray:
    c, _, R = eyes
    k = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
    return (np.asarray(c, np.float64)[:, None] + R * k[None]).reshape(-1, 3)


def background_out(p) -> tuple[float, float, float]:
    """shade.frag's output where no surface and no eye is: background × exposure, clamped
    (float32 maths, as the GPU does it)."""
    bg = np.asarray(p.background, np.float32) * np.float32(p.exposure)
    if p.clamp:
        bg = np.clip(bg, np.float32(0), np.float32(1))
    return tuple(float(x) for x in bg)




def clip_from_pixels(pix: np.ndarray, W: int, H: int) -> np.ndarray:
    """4×4 clip matrix for view-space points from a 3×4 pixel matrix (u·w, v·w, w) = pix·(q, 1):
    window coordinates are the pixel coordinates; clip w = w; the z row is filled in by
    :func:`_view_geometry`."""
    pix = np.asarray(pix, np.float64)
    P = np.zeros((4, 4))
    P[0] = 2 * pix[0] / W - pix[2]
    P[1] = 2 * pix[1] / H - pix[2]
    P[3] = pix[2]
    return P


def camera_clip(camera: Camera) -> np.ndarray:
    """The clip matrix of a perspective or orthographic ``graphkit.Camera`` (camera frame in)."""
    return clip_from_pixels(camera.pixel_matrix(), camera.width, camera.height)


def pinhole_proj(fx, fy, cx, cy, W, H) -> np.ndarray:
    """Clip matrix of a pinhole view (x = fx·X/Z + cx, y = fy·Y/Z + cy), e.g. a point light's
    shadow-map frame."""
    return clip_from_pixels(np.array([[fx, 0, cx, 0], [0, fy, cy, 0], [0, 0, 1.0, 0]]), W, H)


def _set_depth_range(P: np.ndarray, z: np.ndarray, perspective: bool) -> np.ndarray:
    P = P.copy()
    if len(z) == 0:
        z = np.array([1.0])
    lo, hi = float(z.min()), float(z.max())
    if perspective:
        n, f = lo * 0.5, hi * 2.0 + 1e-9
        P[2, 2], P[2, 3] = (f + n) / (f - n), -2 * f * n / (f - n)
    else:
        pad = 0.01 * (hi - lo) + 1e-6 * max(abs(lo), abs(hi), 1.0)
        n, f = lo - pad, hi + pad
        P[2, 2], P[2, 3] = 2 / (f - n), -(f + n) / (f - n)
    return P


def _view_geometry(q: np.ndarray, F: np.ndarray, P: np.ndarray, perspective: bool = True,
                   near: bool | None = None):
    """(clip matrix, faces kept) for view-space vertices ``q``: the reference rasteriser drops
    triangles with a non-finite vertex or (camera views and perspective light views; ``near``
    defaults to ``perspective``) a vertex at z ≤ 1e-6."""
    fq = q[F]
    ok = np.all(np.isfinite(fq), axis=(1, 2))
    if perspective if near is None else near:
        ok &= np.all(fq[..., 2] > NEAR, axis=1)
    Fk = np.ascontiguousarray(F[ok], np.int32)
    used = used_vertices(Fk, len(q))
    return _set_depth_range(P, q[used, 2], perspective), Fk


def used_vertices(F: np.ndarray, n: int) -> np.ndarray:
    """The sorted indices of the vertices that faces ``F`` use (= np.unique(F), in O(n)
    with a mask instead of a sort), of ``n`` vertices."""
    used = np.zeros(n, bool)
    used[np.asarray(F).reshape(-1)] = True
    return np.flatnonzero(used)


def _light_uniforms(light: Light):
    rgb = np.asarray(light.color, np.float64) * light.intensity
    d = np.asarray(light.direction, np.float64)
    nd = np.linalg.norm(d)
    d = d / nd if nd > 0 else d
    return (0 if light.kind == "directional" else 1, d, np.asarray(light.position, np.float64), rgb)


SHADOW_MARGIN = 0.02  # the shadow frame's margin round the mesh (raster.shadow_frame; the studio's page too)


def _shadow_setup(V, F, light, size: int, margin: float = SHADOW_MARGIN, up=None):
    """The light frame of ``nodes.common.raster.shadow_map`` (one implementation:
    ``shadow_frame``) and the clip matrix that rasterises it in GL: dict(to_light 4×4,
    proj (sx, sy, ox, oy), bias (texel, dref), clip, faces, q)."""
    from nodes.common.raster import shadow_frame

    fr = shadow_frame(V, light, size, margin, up)
    (sx, sy), (ox, oy) = fr.scale, fr.offset
    if fr.perspective:
        P = pinhole_proj(sx, sy, ox, oy, size, size)
        clip, Fk = _view_geometry(fr.q, F, P)
    else:
        P = np.zeros((4, 4))
        P[0, 0], P[0, 3] = 2 * sx / size, 2 * ox / size - 1
        P[1, 1], P[1, 3] = 2 * sy / size, 2 * oy / size - 1
        P[3, 3] = 1.0
        clip, Fk = _view_geometry(fr.q, F, P, perspective=False)
    return dict(to_light=fr.M, proj=(sx, sy, ox, oy), bias=(fr.texel, fr.ref_dist), clip=clip,
                faces=Fk, q=fr.q.astype(np.float32))


def digest(*parts) -> bytes:
    """A content key for GL objects (arrays by dtype, shape and bytes; other parts by repr):
    xxh3-128, as the engine's own content digests (graphkit.hashing); 16 bytes."""
    import xxhash

    h = xxhash.xxh3_128()
    for x in parts:
        if isinstance(x, np.ndarray):
            a = np.ascontiguousarray(x)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            if a.size:
                h.update(a.reshape(-1).view(np.uint8))
        else:
            h.update(repr(x).encode())
        h.update(b"|")
    return h.digest()


def check_atlas_fits(n: int, size: int, limit: int) -> str | None:
    """Why ``n`` shadow maps of ``size``² do not fit in one ``limit``² atlas texture (None if they do)."""
    cols, rows = atlas_grid(n)
    if max(cols, rows) * size > limit:
        return f"{n} shadow maps of {size}² do not fit in one {limit}² texture; lower shadow_map_size"
    return None


def atlas_grid(n: int) -> tuple[int, int]:
    """(columns, rows) of the shadow atlas of ``n`` lights."""
    cols = int(np.ceil(np.sqrt(max(n, 1))))
    return cols, int(np.ceil(max(n, 1) / cols))
