"""The ``opengl`` backend of ``Render`` (Paris, Sillion, Quan 2003, §5) with moderngl.

The same image, depth and coverage as the numpy reference (``nodes/paris/render.py``):

* camera: OpenCV pinhole intrinsics → a GL projection whose window coordinates *are* the
  reference's pixel coordinates (x = fx·X/Z + cx, y = fy·Y/Z + cy, pixel centres at +0.5); no
  y flip is needed because the framebuffer is read back bottom row first, i.e. image row 0
  first.  Vertices are transformed into the camera frame in float64 on the host; GL then
  interpolates world position, normal and z perspective-correctly like the reference's
  barycentrics.  Triangles with a vertex at z ≤ 1e-6 are dropped, as the reference does.
* shading: ``shaders/glsl/render.frag`` — the Phong lobes of ``nodes/paris/phong.py``, point
  lights (optionally 1/d²), ambient, shadow maps rendered by GL in the *same* light frames,
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
    version = "1"  # bump when the output for the same inputs changes
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
        from nodes.paris.render import (check_mesh, check_render_inputs, close_holes, eye_spheres,
                                        vertex_normals)

        lights = check_render_inputs(lights, detail, texture_camera)
        if len(lights) > MAX_LIGHTS:
            raise BadInput("lights", f"{len(lights)} lights: the opengl backend takes at most "
                                     f"{MAX_LIGHTS} (the numpy backend any number)")
        p = self.params
        eye_mesh = mesh
        check_mesh(mesh)
        if p.fill_holes:
            mesh = close_holes(mesh)
        V = np.asarray(mesh.vertices, np.float64)
        F = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
        vn = vertex_normals(mesh)
        H, W = camera.height, camera.width

        job = dict(W=W, H=H, p=p)
        # camera pass
        qc = V @ camera.pose[:3, :3].T + camera.pose[:3, 3]
        job["main"] = _view_geometry(qc, F, pinhole_proj(camera.fx, camera.fy, camera.cx,
                                                         camera.cy, W, H))
        job["vertices"] = np.hstack([qc, V, vn]).astype(np.float32)
        job["cam_pos"] = camera.position
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
                    sms.append(_shadow_setup(V, F, light, p.shadow_map_size))
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
            qt = V @ tc.pose[:3, :3].T + tc.pose[:3, 3]
            scale = float(np.median(np.ptp(V, axis=0))) or 1.0
            job["detail"] = dict(
                pixels=np.ascontiguousarray(px[..., :3]), cam=tc, tol=0.02 * scale,
                geom=_view_geometry(qt, F, pinhole_proj(tc.fx, tc.fy, tc.cx, tc.cy, tc.width, tc.height)),
                q=qt.astype(np.float32))
        # eye highlights (Render._eyes)
        eyes = None
        if p.eye_highlights != "off":
            eyes = eye_spheres(eye_mesh, p.eyes, p.cornea_radius_mm, p.mm_per_unit,
                               p.eye_protrusion_mm, camera.position)
        job["eyes"] = eyes
        if eyes is not None:
            Rm = camera.pose[:3, :3]
            job["ray_mat"] = Rm.T @ np.linalg.inv(camera.K)
            job["fwd"] = np.linalg.inv(camera.pose)[:3, 2]

        try:
            img, aux, cov = runtime().call(_render, job)
        except Unavailable as e:
            raise RuntimeError(f"OpenGL backend unavailable: {e}") from None

        M = int(cov.sum())
        if M:
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
        else:  # the reference adds no eye highlights when nothing is covered
            img = np.empty((H, W, 3), np.float32)
            img[:] = np.asarray(p.background, np.float64) * p.exposure
            if p.clamp:
                img = np.clip(img, 0.0, 1.0)
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


def pinhole_proj(fx, fy, cx, cy, W, H, near=None, far=None) -> np.ndarray:
    """4×4 clip matrix for view-space points (OpenCV axes) whose window coordinates are the
    pixel coordinates (fx·X/Z + cx, fy·Y/Z + cy); near/far filled in by :func:`_view_geometry`."""
    P = np.zeros((4, 4))
    P[0, 0], P[0, 2] = 2 * fx / W, 2 * cx / W - 1
    P[1, 1], P[1, 2] = 2 * fy / H, 2 * cy / H - 1
    P[3, 2] = 1.0
    return P


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


def _view_geometry(q: np.ndarray, F: np.ndarray, P: np.ndarray, perspective: bool = True):
    """(clip matrix, faces kept) for view-space vertices ``q``: the reference rasteriser drops
    triangles with a non-finite vertex or (perspective) a vertex at z ≤ 1e-6."""
    fq = q[F]
    ok = np.all(np.isfinite(fq), axis=(1, 2))
    if perspective:
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


def _shadow_setup(V, F, light, size: int, margin: float = 0.02):
    """The light frame of ``nodes.common.raster.shadow_map`` (one implementation:
    ``shadow_frame``) and the clip matrix that rasterises it in GL: dict(to_light 4×4,
    proj (sx, sy, ox, oy), bias (texel, dref), clip, faces, q)."""
    from nodes.common.raster import shadow_frame

    fr = shadow_frame(V, light, size, margin)
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


def _set_lights(prog, lights, inverse_square):
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
    _set(prog, "inverse_square", bool(inverse_square))


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
            _write(prog, "tex_pose", _mat(tc.pose))
            _set(prog, "tex_K", (tc.fx, tc.fy, tc.cx, tc.cy))
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
        _set_lights(prog, lights, p.inverse_square)
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
            o = job["cam_pos"]
            _write(comp, "ray_mat", _mat(job["ray_mat"]))
            _set(comp, "fwd", tuple(job["fwd"]))
            _write(comp, "eye_c", np.asarray(centres, np.float32).tobytes())
            _write(comp, "eye_oc", np.asarray(o[None] - centres, np.float32).tobytes())
            _write(comp, "eye_axis", np.asarray(axes, np.float32).tobytes())
            _set(comp, "eye_R", float(R))
            _set(comp, "eye_s", float(p.eye_shininess))
            _set(comp, "eye_ks", float(p.eye_specular))
            _set_lights(comp, lights, p.inverse_square)
        vao = ctx.vertex_array(comp, [])
        trash.append(vao)
        vao.render(mgl.TRIANGLES, vertices=3)
        img = np.frombuffer(ofbo.read(components=3, dtype="f4"), np.float32).reshape(H, W, 3).copy()
        return img, aux_px.copy(), cov
    finally:
        for o in reversed(trash):
            o.release()
