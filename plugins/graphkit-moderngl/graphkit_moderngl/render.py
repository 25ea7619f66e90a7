"""The ``opengl`` backend of ``Render`` (Paris, Sillion, Quan 2003, §5) with moderngl.

The same image, depth and coverage as the numpy reference (``nodes/paris/render.py``):

* camera: perspective or orthographic (``graphkit.Camera``): its ``pixel_matrix`` (the one
  implementation of the projection) → a GL clip matrix whose window coordinates *are* the
  reference's pixel coordinates (pixel centres at +0.5); no y flip is needed because the
  framebuffer is read back bottom row first, i.e. image row 0 first.  Vertices are transformed
  into the camera frame in float64 on the host; GL then interpolates world position, normal
  and z perspective-correctly (perspective) or linearly (orthographic: w = 1), like the
  reference's barycentrics.  Triangles with a vertex at z ≤ 1e-6 are dropped, as the
  reference does (which refuses meshes crossing the camera plane anyway).
* shading: ``shaders/glsl/render.frag`` — the Phong lobes of ``nodes/paris/phong.py``, point
  lights (always 1/d², in world units), ambient, shadow maps rendered by GL in the *same* light frames,
  resolution, bias and 3×3 PCF as ``nodes.common.raster.shadow_map``/``ShadowMap.visibility``,
  and the projective detail texture with the reference's occlusion test and bilinear lookup.
* ``shaders/glsl/composite.frag``: background, eye highlights (``Render._eyes``), exposure,
  clamp.
* float32 everywhere on the GL side (RGBA32F targets, read back as float32).

Differences: GL's fill rule and float32 arithmetic move a few silhouette / shadow-edge /
texture-occlusion-edge pixels (see ``tolerance``); at most 32 lights (BadInput beyond).
"""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Backend, Camera, Image, Light, Mask

from .runtime import Unavailable, runtime

MAX_LIGHTS = 32  # as in the shaders
NEAR = 1e-6  # the reference rasteriser's near limit
SHADOW_EMPTY = 1e30  # shadow-map value where nothing is in the way


class RenderGL(Backend):
    """Render on OpenGL 3.3 through an EGL standalone context (Mesa llvmpipe on a CPU)."""

    node = "Render"
    name = "opengl"
    version = "2"  # bump when the output for the same inputs changes
    # float32 vs float64 maths and GL's fill rule move pixels whose centre lies on a
    # silhouette, shadow-map or texture-occlusion boundary (or a PCF tap at a texel boundary):
    # 0.5% of the values may differ (measured: ≤ 0.06% on tests/test_opengl_backend.py, 0.02%
    # in the 512² benchmark, 0 on Render.examples()); all others within the node's rtol/atol
    # (measured max |diff| off edges: 1e-4, 6e-4 on eye highlights with exponent 60).
    tolerance = {"rtol": 1e-3, "atol": 2e-3, "bad_fraction": 0.005}

    @classmethod
    def available(cls) -> bool:
        """True when moderngl imports, an EGL context starts and the shaders build (never raises)."""
        return _probe() is None

    @classmethod
    def why_unavailable(cls) -> str:
        return _probe() or "available"

    def compute(self, mesh, camera: Camera, material, lights, detail: Image | None = None,
                texture_camera: Camera | None = None, ambient: Light | None = None):
        from nodes.paris.render import eye_spheres, prepare_render, vertex_normals

        p = self.params
        eye_mesh = mesh
        lights, mesh = prepare_render(mesh, camera, lights, detail, texture_camera, p.fill_holes)
        if len(lights) > MAX_LIGHTS:
            raise BadInput("lights", f"{len(lights)} lights: the opengl backend takes at most "
                                     f"{MAX_LIGHTS} (the numpy backend any number)")
        V = np.asarray(mesh.vertices, np.float64)
        F = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
        vn = vertex_normals(mesh)
        H, W = camera.height, camera.width

        job = dict(W=W, H=H, p=p)
        # camera pass
        qc = camera.to_camera(V)
        job["main"] = _view_geometry(qc, F, camera_clip(camera), not camera.orthographic, near=True)
        job["vertices"] = np.hstack([qc, V, vn]).astype(np.float32)
        job["cam_pos"] = camera.position
        job["cam_ortho"] = camera.orthographic
        job["cam_back"] = -camera.forward
        # lights
        job["lights"] = [_light_uniforms(light) for light in lights]
        kd = np.asarray(material.diffuse, np.float64)
        amb = np.zeros(3)
        for light in lights:
            amb += np.asarray(light.ambient, np.float64) * material.ambient_scale
        if ambient is not None:
            amb += np.asarray(ambient.ambient, np.float64) * material.ambient_scale * p.ambient_gain
        job["material"] = (kd, float(material.specular), float(material.shininess), amb)
        # shadow maps (same frames as nodes.common.raster.shadow_map)
        sm_errors = [None] * len(lights)
        job["shadow"] = None
        if p.shadows:
            sms = []
            for i, light in enumerate(lights):
                try:
                    sms.append(_shadow_setup(V, F, light, p.shadow_map_size, up=camera.rotation[1]))
                except ValueError as e:
                    sm_errors[i] = str(e)
                    sms.append(None)
            job["shadow"] = sms
        # projective detail texture (render.projective_texture)
        job["detail"] = None
        if detail is not None:
            px = np.asarray(detail.pixels, np.float32)
            if px.ndim == 2:
                px = px[..., None]
            if px.shape[2] == 1:
                px = np.repeat(px, 3, axis=2)
            elif px.shape[2] == 2:
                raise BadInput("detail", "a 2-channel detail texture cannot multiply RGB")
            tc = texture_camera
            qt = tc.to_camera(V)
            scale = float(np.median(np.ptp(V, axis=0))) or 1.0
            proj = np.zeros((4, 4))
            proj[:3] = tc.world_pixel_matrix()
            proj[3] = tc.pose[2]  # camera z
            job["detail"] = dict(
                pixels=np.ascontiguousarray(px[..., :3]), cam=tc, tol=0.02 * scale, proj=proj,
                geom=_view_geometry(qt, F, camera_clip(tc), not tc.orthographic, near=True),
                q=qt.astype(np.float32))
        # eye highlights (Render._eyes)
        eyes = None
        if p.eye_highlights != "off":
            eyes = eye_spheres(eye_mesh, p.eyes, p.cornea_radius_mm, p.mm_per_unit,
                               p.eye_protrusion_mm, camera.position)
        job["eyes"] = eyes
        if eyes is not None:
            job["ray_org"], job["ray_dir"] = camera.ray_matrices()
            job["fwd"] = camera.forward

        try:
            img, aux, cov = runtime().call(_render, job)
        except Unavailable as e:
            raise RuntimeError(f"OpenGL backend unavailable: {e}") from None

        M = int(cov.sum())
        if M == 0:  # as the reference (nodes.paris.render.surface)
            raise BadInput("mesh", f"the mesh covers 0 pixels of the {W}×{H} camera image: it does "
                                   "not match the camera (wrong pose, units or image size?)")
        masks = aux[..., 1][cov].astype(np.int64), aux[..., 2][cov].astype(np.int64)
        lit = np.bitwise_or.reduce(masks[0]) if len(masks[0]) else 0
        lit |= (np.bitwise_or.reduce(masks[1]) if len(masks[1]) else 0) << 24
        for i, light in enumerate(lights):
            if not (lit >> i) & 1:
                raise BadInput("lights", f"light {i} ({light.kind}, direction {light.direction}, "
                                         f"position {light.position}) is behind the face: it "
                                         f"lights none of the {M} visible pixels")
            if p.shadows and sm_errors[i]:
                raise BadInput("lights", f"light {i}: {sm_errors[i]}")
        if eyes is None and p.eye_highlights == "on":
            raise BadInput("mesh", "eye_highlights is 'on' but the eyes are unknown: the mesh "
                                   "is not a mediapipe face mesh; set the `eyes` param")
        depth = np.where(cov, aux[..., 0], 0.0).astype(np.float32)
        return {"image": Image(np.ascontiguousarray(img, np.float32)),
                "depth": Image(depth),
                "coverage": Mask(cov.astype(np.float32))}


def _probe() -> str | None:
    try:
        runtime()
    except Unavailable as e:
        return str(e)
    except Exception as e:  # noqa: BLE001 - a probe reports, it does not raise
        return f"{type(e).__name__}: {e}"
    return None


# ----------------------------------------------------------------------------------------------
# host-side set-up (float64)


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
    used = np.unique(Fk) if len(Fk) else np.zeros(0, np.int64)
    return _set_depth_range(P, q[used, 2], perspective), Fk


def _light_uniforms(light: Light):
    rgb = np.asarray(light.color, np.float64) * light.intensity
    d = np.asarray(light.direction, np.float64)
    nd = np.linalg.norm(d)
    d = d / nd if nd > 0 else d
    return (0 if light.kind == "directional" else 1, d, np.asarray(light.position, np.float64), rgb)


def _shadow_setup(V, F, light, size: int, margin: float = 0.02, up=None):
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


# ----------------------------------------------------------------------------------------------
# GL thread


def _mat(m) -> bytes:
    """A matrix as GLSL wants it (column-major float32)."""
    return np.asarray(m, np.float64).T.astype("f4").tobytes()


def _set(prog, name, value):
    """Set a uniform that may have been optimised away."""
    if name in prog:
        prog[name].value = value


def _write(prog, name, data: bytes):
    if name in prog:
        prog[name].write(data)


def _set_lights(prog, lights):
    n = len(lights)
    kind = np.zeros(MAX_LIGHTS, np.int32)
    arr = {k: np.zeros((MAX_LIGHTS, 3), np.float32) for k in ("dir", "pos", "rgb")}
    for i, (k, d, pos, rgb) in enumerate(lights):
        kind[i] = k
        arr["dir"][i], arr["pos"][i], arr["rgb"][i] = d, pos, rgb
    _set(prog, "n_lights", n)
    _write(prog, "light_kind", kind.tobytes())
    for k, a in arr.items():
        _write(prog, f"light_{k}", a.tobytes())


def _depth_pass(rt, q32, clip, faces, W, H, clear):
    """Render view-space z of the nearest surface into a W×H RGBA32F texture (r = z, g = 1)."""
    ctx, mgl = rt.ctx, rt.gl
    prog = rt.program("depth.vert", "depth.frag")
    tex = ctx.texture((W, H), 4, dtype="f4")
    tex.filter = (mgl.NEAREST, mgl.NEAREST)
    rb = ctx.depth_renderbuffer((W, H))
    fbo = ctx.framebuffer(color_attachments=[tex], depth_attachment=rb)
    fbo.use()
    fbo.clear(clear, 0.0, 0.0, 0.0, depth=1.0)
    objs = [rb, fbo]
    if len(faces):
        prog["proj"].write(_mat(clip))
        vbo = ctx.buffer(np.ascontiguousarray(q32, np.float32).tobytes())
        ibo = ctx.buffer(faces.tobytes())
        vao = ctx.vertex_array(prog, [(vbo, "3f", "q")], ibo, index_element_size=4)
        vao.render(mgl.TRIANGLES)
        objs += [vao, vbo, ibo]
    return tex, fbo, objs


def _render(rt, job):
    ctx, mgl = rt.ctx, rt.gl
    W, H, p = job["W"], job["H"], job["p"]
    trash = []
    try:
        ctx.enable(mgl.DEPTH_TEST)
        ctx.disable(mgl.CULL_FACE | mgl.BLEND)
        ctx.depth_func = "<"
        lights = job["lights"]
        nL = len(lights)
        # shadow maps → one R32F texture array, layer i = light i
        prog = rt.program("render.vert", "render.frag")
        size = p.shadow_map_size
        if job["shadow"] is not None:
            maps = np.full((nL, size, size), SHADOW_EMPTY, np.float32)
            to_light = np.tile(np.eye(4), (MAX_LIGHTS, 1, 1))
            proj = np.zeros((MAX_LIGHTS, 4), np.float32)
            bias = np.ones((MAX_LIGHTS, 2), np.float32)
            for i, sm in enumerate(job["shadow"]):
                if sm is None:
                    continue
                tex, fbo, objs = _depth_pass(rt, sm["q"], sm["clip"], sm["faces"], size, size, SHADOW_EMPTY)
                maps[i] = np.frombuffer(fbo.read(components=1, dtype="f4"), np.float32).reshape(size, size)
                trash += objs + [tex]
                to_light[i], proj[i], bias[i] = sm["to_light"], sm["proj"], sm["bias"]
            sm_tex = ctx.texture_array((size, size, nL), 1, data=maps.tobytes(), dtype="f4")
            sm_tex.filter = (mgl.NEAREST, mgl.NEAREST)
            trash.append(sm_tex)
            sm_tex.use(location=0)
            _set(prog, "shadows", True)
            _set(prog, "shadow_maps", 0)
            _set(prog, "sm_size", size)
            _write(prog, "sm_to_light", b"".join(_mat(m) for m in to_light))
            _write(prog, "sm_proj", proj.tobytes())
            _write(prog, "sm_bias", bias.tobytes())
        else:
            _set(prog, "shadows", False)
            dummy = ctx.texture_array((1, 1, 1), 1, dtype="f4")
            trash.append(dummy)
            dummy.use(location=0)
            _set(prog, "shadow_maps", 0)
        # detail texture + texture-camera depth map
        det = job["detail"]
        if det is not None:
            tc = det["cam"]
            clip, faces = det["geom"]
            tdepth, fbo, objs = _depth_pass(rt, det["q"], clip, faces, tc.width, tc.height, 0.0)
            trash += objs + [tdepth]
            dtex = ctx.texture((tc.width, tc.height), 3, data=det["pixels"].tobytes(), dtype="f4")
            dtex.filter = (mgl.NEAREST, mgl.NEAREST)
            trash.append(dtex)
            dtex.use(location=1)
            tdepth.use(location=2)
            _set(prog, "has_detail", True)
            _write(prog, "tex_proj", _mat(det["proj"]))
            _set(prog, "tex_size", (tc.width, tc.height))
            _set(prog, "occl_tol", det["tol"])
        else:
            _set(prog, "has_detail", False)
            dummy = ctx.texture((1, 1), 4, dtype="f4")
            trash.append(dummy)
            dummy.use(location=1)
            dummy.use(location=2)
        _set(prog, "detail", 1)
        _set(prog, "tex_depth", 2)
        # main pass
        kd, i_s, s, amb = job["material"]
        _set(prog, "kd", tuple(kd))
        _set(prog, "i_s", i_s)
        _set(prog, "shininess", s)
        _set(prog, "ambient", tuple(amb))
        _set(prog, "cam_pos", tuple(job["cam_pos"]))
        _set(prog, "cam_ortho", bool(job["cam_ortho"]))
        _set(prog, "cam_back", tuple(job["cam_back"]))
        _set_lights(prog, lights)
        clip, faces = job["main"]
        prog["proj"].write(_mat(clip))
        color = ctx.texture((W, H), 4, dtype="f4")
        aux = ctx.texture((W, H), 4, dtype="f4")
        for t in (color, aux):
            t.filter = (mgl.NEAREST, mgl.NEAREST)
        rb = ctx.depth_renderbuffer((W, H))
        fbo = ctx.framebuffer(color_attachments=[color, aux], depth_attachment=rb)
        zfbo = ctx.framebuffer(depth_attachment=rb)
        trash += [color, aux, rb, fbo, zfbo]
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if len(faces):
            vbo = ctx.buffer(job["vertices"].tobytes())
            ibo = ctx.buffer(faces.tobytes())
            # depth pre-pass (same vertex positions, `invariant gl_Position`), then shade only
            # the nearest fragment of each pixel (no overdraw)
            zprog = rt.program("depth.vert", "depth.frag")
            zprog["proj"].write(_mat(clip))
            zvao = ctx.vertex_array(zprog, [(vbo, "3f 24x", "q")], ibo, index_element_size=4)
            trash += [zvao, vbo, ibo]
            zfbo.use()
            zvao.render(mgl.TRIANGLES)
            fbo.use()
            ctx.depth_func = "=="
            vao = ctx.vertex_array(prog, [(vbo, "3f 3f 3f", "q", "P", "N")], ibo, index_element_size=4)
            trash.append(vao)
            vao.render(mgl.TRIANGLES)
            ctx.depth_func = "<"
        aux_px = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=1), np.float32).reshape(H, W, 4)
        cov = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=0), np.float32).reshape(H, W, 4)[..., 3] > 0.5
        # composite: background, eyes, exposure, clamp
        comp = rt.program("screen.vert", "composite.frag")
        out = ctx.texture((W, H), 4, dtype="f4")
        ofbo = ctx.framebuffer(color_attachments=[out])
        trash += [out, ofbo]
        ofbo.use()
        ctx.disable(mgl.DEPTH_TEST)
        color.use(location=0)
        aux.use(location=1)
        _set(comp, "color", 0)
        _set(comp, "aux", 1)
        _set(comp, "background", tuple(float(b) for b in p.background))
        _set(comp, "exposure", float(p.exposure))
        _set(comp, "clamp01", bool(p.clamp))
        eyes = job["eyes"]
        _set(comp, "eyes", eyes is not None)
        if eyes is not None:
            centres, axes, R = eyes
            _write(comp, "ray_org", _mat(job["ray_org"]))
            _write(comp, "ray_dir", _mat(job["ray_dir"]))
            _set(comp, "cam_pos", tuple(job["cam_pos"]))
            _set(comp, "fwd", tuple(job["fwd"]))
            _write(comp, "eye_c", np.asarray(centres, np.float32).tobytes())
            _write(comp, "eye_axis", np.asarray(axes, np.float32).tobytes())
            _set(comp, "eye_R", float(R))
            _set(comp, "eye_s", float(p.eye_shininess))
            _set(comp, "eye_ks", float(p.eye_specular))
            _set_lights(comp, lights)
        vao = ctx.vertex_array(comp, [])
        trash.append(vao)
        vao.render(mgl.TRIANGLES, vertices=3)
        img = np.frombuffer(ofbo.read(components=3, dtype="f4"), np.float32).reshape(H, W, 3).copy()
        return img, aux_px.copy(), cov
    finally:
        for o in reversed(trash):
            o.release()
