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
* the shaders are ``shaders/glsl/`` through ``graphkit.glsl`` (one source with the studio's
  WebGL2 face view; ``#define``s specialise each program: light count, orthographic camera,
  shadows, detail texture, eyes):
  - ``depth.vert/frag``: shadow maps (all lights in one atlas, rendered in the *same* light
    frames, resolution and bias as ``nodes.common.raster.shadow_map``), the texture camera's
    occlusion map and the main camera's depth pre-pass;
  - ``gbuffer.vert/frag``: per pixel of the nearest surface, world position, two-sided smooth
    normal and the projective detail texture factor (the reference's occlusion test and
    bilinear lookup);
  - ``shade.frag`` (+ ``lights.glsl``): Phong lobes of ``nodes/paris/phong.py``, point lights
    (always 1/d², in world units), ambient, shadow visibility (3×3 PCF as
    ``ShadowMap.visibility``), background, eye highlights (``Render._eyes``), exposure, clamp;
    an ``environment``'s lights are lights like the others (shadowed; they may light nothing)
    and its SH ambient is evaluated per pixel normal (``ENV_SH``, environment.py's weights).
* GL objects persist between calls and nodes (``runtime.GLObjects``): buffers keyed by the
  content of the vertices/faces, the detail texture by its pixels, render targets by size; the
  shadow atlas and the g-buffer remember what they hold, so a call that changes only the
  lights re-renders the shadow maps and the lighting pass, one that changes only the
  material/exposure only the lighting pass.
* the lighting pass runs only over the mesh's screen box (``glscene.screen_box``) and, with
  the eye highlights, over the eyes' box, on a target cleared to the background output
  (``glscene.background_out``); its alpha is the camera z where a surface is (0 elsewhere),
  negated where no light has n·l > 0 (one light; 2+ lights: per-light masks in a second
  target, ``LIT_MASKS``), so the read-back is the image, whole, as RGB straight into the
  output array, and the alpha over the box only (depth, coverage, the "lights nothing" check).
  Where the driver renders RGB32F (probed once) the image goes to an RGB32F target and the
  alpha to its own R32F one (``ALPHA_OUT``): both read back as stored, no conversion.  The
  programs are specialised by ``#define``s that change no value (``DETAIL`` 0: no detail
  fetch; ``DIRECTIONAL`` 1: no point-light branch).  Depth and coverage depend only on the
  g-buffer: they are kept per g-buffer key (``surface_key``, with the GL objects), so a light drag only checks the
  lights (the alpha's maximum).
* a direct call without the engine's input digests keys the kept set-up by the content of
  the inputs (``glscene.static_key``).
* float32 everywhere on the GL side (RGBA32F targets, read back as float32).

Differences: GL's fill rule and float32 arithmetic move a few silhouette / shadow-edge /
texture-occlusion-edge pixels (see ``tolerance``); at most 32 lights (BadInput beyond).
Not drawn: ``antialias``, ``mouth: photo`` on a mediapipe mesh, and, while shadows are on, the
soft shadows of lights with a size (``LightSize``) and an environment's shadows from the
visibility basis (Render's ``environment_basis`` > 0; 0 draws a shadow map per environment
light here as in numpy) (``glscene.not_drawn``): ``BackendCannotRun``,
so the engine computes the node with numpy (one notice) or, where the graph pins
``backend: opengl``, exits 2 saying why.
"""
from __future__ import annotations

import numpy as np

from graphkit import BackendCannotRun, BadInput, Backend, Camera, Image, Light, Mask

from .runtime import Unavailable, runtime

from nodes.paris.glscene import MAX_LIGHTS, atlas_grid, check_atlas_fits, digest  # noqa: F401

SHADOW_EMPTY = 1e30  # shadow-map value where nothing is in the way


class RenderGL(Backend):
    """Render on OpenGL 3.3 through an EGL standalone context (Mesa llvmpipe on a CPU)."""

    node = "Render"
    name = "opengl"
    version = "3"  # bump when the output for the same inputs changes
    # 3: the view vector from the pixel's ray (shade.frag VIEW_RAY), not from the interpolated
    #    world position: float32-rounding changes (see tolerance)
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

    def compute(self, mesh, camera: Camera, material, lights=None, detail: Image | None = None,
                texture_camera: Camera | None = None, ambient: Light | None = None, environment=None):
        from nodes.paris.glscene import not_drawn, scene, static_key

        p = self.params
        why = not_drawn(p, mesh, lights or (), environment)
        if why:  # never a silently different image: the engine falls back to numpy, or refuses if pinned
            raise BackendCannotRun(why)
        H, W = camera.height, camera.width
        job, lights, sm_errors, eyes = scene(p, mesh, camera, material, lights, detail, texture_camera, ambient,
                                             key=static_key(p, self.ctx.inputs, mesh, camera, detail, texture_camera),
                                             environment=environment)
        if job["shadow"] is not None:
            _check_atlas(len(job["shadow"]), p.shadow_map_size)

        try:
            img, (depth0, cov0, M), top, masks = runtime().call(_render_job, job)
        except Unavailable as e:
            raise RuntimeError(f"OpenGL backend unavailable: {e}") from None
        # depth0, cov0: kept between calls on the same g-buffer (copied: each call's outputs
        # are its own arrays); top: the maximum of shade.frag's alpha (the one-light check)
        if M == 0:  # as the reference (nodes.paris.render.surface)
            raise BadInput("mesh", f"the mesh covers 0 pixels of the {W}×{H} camera image: it does "
                                   "not match the camera (wrong pose, units or image size?)")
        depth, cov = depth0.copy(), cov0.copy()
        if masks is None:  # one light: lit somewhere iff some covered pixel has z > 0
            lit = int(bool(top > 0.0))
        else:
            x, y, w, h = job["bbox"]
            cb = cov0[y:y + h, x:x + w] != 0.0
            m0, m1 = masks[..., 0][cb].astype(np.int64), masks[..., 1][cb].astype(np.int64)
            lit = np.bitwise_or.reduce(m0) | (np.bitwise_or.reduce(m1) << 24)
        own = job["own"]  # an environment's lights (after these) may light nothing, as in numpy
        for i, light in enumerate(lights):
            if not (lit >> i) & 1:
                if i >= own:
                    continue
                raise BadInput("lights", f"light {i} ({light.kind}, direction {light.direction}, "
                                         f"position {light.position}) is behind the face: it "
                                         f"lights none of the {M} visible pixels")
            if p.shadows and sm_errors[i]:
                raise BadInput("lights" if i < own else "environment", f"light {i}: {sm_errors[i]}")
        if eyes is None and p.eye_highlights == "on":
            raise BadInput("mesh", "eye_highlights is 'on' but the eyes are unknown: the mesh "
                                   "is not a mediapipe face mesh; set the `eyes` param")
        return {"image": Image(img),
                "depth": Image(depth),
                "coverage": Mask(cov)}


def _surface(zs: np.ndarray, bbox, W: int, H: int):
    """(depth H×W, coverage H×W, number of covered pixels) from shade.frag's alpha ``zs``
    over ``bbox`` (± camera z where covered, 0 elsewhere; outside the box: uncovered)."""
    x, y, w, h = bbox
    box = np.s_[y:y + h, x:x + w]
    depth = np.zeros((H, W), np.float32)
    cov = np.zeros((H, W), np.float32)  # the coverage mask's values (1 / 0) straight away
    cb = zs != 0.0
    cov[box] = cb
    np.abs(zs, out=depth[box])
    return depth, cov, int(np.count_nonzero(cb))


def surface_key(job) -> tuple:
    """The key of a render's depth and coverage among the GL objects: they depend only on the
    g-buffer (content-keyed: job["gbuffer_key"]), the shaded box and the size, so calls on the
    same g-buffer (a light drag) share them."""
    return ("surface", job["gbuffer_key"], tuple(job["bbox"]), job["W"], job["H"])


def _drop_surfaces(rt) -> None:
    """Forget every kept depth and coverage (GL thread; tests)."""
    for k in [k for k in rt.objects._d if isinstance(k, tuple) and k[:1] == ("surface",)]:
        rt.objects.drop(k)


def _check_atlas(n: int, size: int):
    """The shadow maps share one texture (shaders/glsl/shade.frag): refuse (the engine then
    uses numpy unless the graph pins opengl) what exceeds the GL implementation's limit."""
    why = check_atlas_fits(n, size, runtime().max_texture_size)
    if why:
        raise BackendCannotRun(f"{why} ({runtime().describe()})")


def _probe() -> str | None:
    try:
        runtime()
    except Unavailable as e:
        return str(e)
    except Exception as e:  # noqa: BLE001 - a probe reports, it does not raise
        return f"{type(e).__name__}: {e}"
    return None


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


def _set_lights(prog, lights, n: int):
    """The lights' uniform arrays (``n`` = the program's N_LIGHTS ≥ len(lights); unused
    entries are black directional lights)."""
    kind = np.zeros(n, np.int32)
    arr = {k: np.zeros((n, 3), np.float32) for k in ("dir", "pos", "rgb")}
    arr["dir"][:, 2] = 1.0
    for i, (k, d, pos, rgb) in enumerate(lights):
        kind[i] = k
        arr["dir"][i], arr["pos"][i], arr["rgb"][i] = d, pos, rgb
    _write(prog, "light_kind", kind.tobytes())
    for k, a in arr.items():
        _write(prog, f"light_{k}", a.tobytes())


def _mesh_buffers(rt, vertices: np.ndarray, faces: np.ndarray, vkey: bytes, fkey: bytes):
    """The vertex and index buffers of a mesh (kept between calls): dict(vbo, ibo, vaos)."""
    def make():
        return {"vbo": rt.ctx.buffer(np.ascontiguousarray(vertices, np.float32).tobytes()),
                "ibo": rt.ctx.buffer(np.ascontiguousarray(faces, np.int32).tobytes()), "vaos": {}}

    return rt.objects.get(("mesh", vkey, fkey), make, vertices.nbytes + faces.nbytes)


def _vao(rt, bufs, prog, fmt: str, names: tuple):
    vaos = bufs["vaos"]
    key = (prog.glo, fmt)
    vao = vaos.get(key)
    if vao is None:
        vao = vaos[key] = rt.ctx.vertex_array(prog, [(bufs["vbo"], fmt, *names)], bufs["ibo"],
                                              index_element_size=4)
    return vao


def _target(rt, kind: str, W: int, H: int, colors: tuple, depth: bool = True):
    """A render target kept between calls: dict(tex=[textures], fbo, zfbo (depth only), key =
    what it holds now, None at first).  ``colors``: components (1–4) of each float32 target."""
    ctx, mgl = rt.ctx, rt.gl

    def make():
        texs = []
        for c in colors:
            t = ctx.texture((W, H), c, dtype="f4")
            t.filter = (mgl.NEAREST, mgl.NEAREST)
            texs.append(t)
        out = {"tex": texs}
        if depth:
            out["rb"] = ctx.depth_renderbuffer((W, H))
            out["zfbo"] = ctx.framebuffer(depth_attachment=out["rb"])
        out["fbo"] = ctx.framebuffer(color_attachments=texs, depth_attachment=out.get("rb"))
        out["key"] = None
        return out

    nbytes = W * H * (4 * sum(colors) + (4 if depth else 0))
    return rt.objects.get(("target", kind, W, H, colors, depth), make, nbytes)


def _depth_pass(rt, fbo, geom, viewport, key):
    """View-space z of the nearest surface of ``geom`` = (q32, faces, clip) into ``fbo``'s
    ``viewport`` (depth.frag: r = z, g = 1)."""
    q32, faces, clip = geom
    if not len(faces):
        return
    mgl = rt.gl
    prog = rt.program("depth.vert", "depth.frag")
    bufs = _mesh_buffers(rt, q32, faces, key[0], key[1])
    fbo.viewport = viewport
    prog["proj"].write(_mat(clip))
    _vao(rt, bufs, prog, "3f", ("q",)).render(mgl.TRIANGLES)


def _shadow_atlas(rt, job):
    """All lights' shadow maps in one R32F atlas (kept, and re-rendered only when a light or
    the mesh changed): (texture, tiles (n × 2 texel offsets)).  Light i's map fills the
    corner of its size² tile that job["sm_sizes"][i] gives."""
    sms, size, sizes = job["shadow"], job["p"].shadow_map_size, job["sm_sizes"]
    n = len(sms)
    cols, rows = atlas_grid(n)
    tiles = np.array([[(i % cols) * size, (i // cols) * size] for i in range(n)], np.int32)
    t = _target(rt, "shadow", cols * size, rows * size, (1,))
    if t["key"] != job["shadow_key"]:
        t["key"] = None
        fbo = t["fbo"]
        fbo.use()
        fbo.viewport = (0, 0, cols * size, rows * size)
        fbo.clear(SHADOW_EMPTY, 0.0, 0.0, 0.0, depth=1.0)
        for i, sm in enumerate(sms):
            if sm is not None:
                _depth_pass(rt, fbo, (sm["q"], sm["faces"], sm["clip"]),
                            (int(tiles[i, 0]), int(tiles[i, 1]), sizes[i], sizes[i]), sm["key"])
        fbo.viewport = (0, 0, cols * size, rows * size)
        t["key"] = job["shadow_key"]
    return t["tex"][0], tiles


def _gbuffer(rt, job):
    """The surface pass (gbuffer.frag) into a kept target; re-rendered only when the mesh,
    camera or detail texture changed.  Returns the target."""
    ctx, mgl = rt.ctx, rt.gl
    W, H = job["W"], job["H"]
    det = job["detail"]
    # without a detail texture the factor is 1 and shade.frag (DETAIL 0) does not read it:
    # no third target (gbuffer.frag's o_detail then goes to no draw buffer)
    g = _target(rt, "gbuffer", W, H, (4, 4, 4) if det is not None else (4, 4))
    if g["key"] == job["gbuffer_key"]:
        return g
    g["key"] = None
    defines = {"ORTHO": int(bool(job["cam_ortho"])), "DETAIL": int(det is not None)}
    prog = rt.program("gbuffer.vert", "gbuffer.frag", defines)
    if det is not None:
        tc = det["cam"]
        td = _target(rt, "texdepth", tc.width, tc.height, (4,))
        if td["key"] != det["depth_key"]:
            td["key"] = None
            td["fbo"].use()
            td["fbo"].viewport = (0, 0, tc.width, tc.height)
            td["fbo"].clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            clip, faces = det["geom"]
            _depth_pass(rt, td["fbo"], (det["q"], faces, clip), (0, 0, tc.width, tc.height),
                        det["q_key"])
            td["key"] = det["depth_key"]
        px = det["pixels"]

        def upload():
            t = ctx.texture((px.shape[1], px.shape[0]), 3, data=px.tobytes(), dtype="f4")
            t.filter = (mgl.NEAREST, mgl.NEAREST)
            return t

        dtex = rt.objects.get(("detail", det["pixels_key"]), upload, px.nbytes)
        dtex.use(location=0)
        td["tex"][0].use(location=1)
        _set(prog, "detail", 0)
        _set(prog, "tex_depth", 1)
        _write(prog, "tex_proj", _mat(det["proj"]))
        _set(prog, "tex_size", (tc.width, tc.height))
        _set(prog, "occl_tol", det["tol"])
    _set(prog, "cam_pos", tuple(job["cam_pos"]))
    _set(prog, "cam_back", tuple(job["cam_back"]))
    clip, faces = job["main"]
    prog["proj"].write(_mat(clip))
    g["fbo"].use()
    g["fbo"].viewport = (0, 0, W, H)
    g["fbo"].clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
    if len(faces):
        bufs = _mesh_buffers(rt, job["vertices"], faces, job["vertices_key"], job["faces_key"])
        # depth pre-pass (the same positions, `invariant gl_Position`), then the surface pass
        # on the nearest fragment of each pixel only (no overdraw)
        zprog = rt.program("depth.vert", "depth.frag", {"DEPTH_ONLY": 1})  # no colour: depth only
        zprog["proj"].write(_mat(clip))
        g["zfbo"].use()
        g["zfbo"].viewport = (0, 0, W, H)
        _vao(rt, bufs, zprog, "3f 24x", ("q",)).render(mgl.TRIANGLES)
        g["fbo"].use()
        ctx.depth_func = "=="
        _vao(rt, bufs, prog, "3f 3f 3f", ("q", "P", "N")).render(mgl.TRIANGLES)
        ctx.depth_func = "<"
    g["key"] = job["gbuffer_key"]
    return g


def _shade_uniforms(prog, job, p, tiles):
    """shade.frag's uniforms: g-buffer units 0–2, shadow atlas unit 3, lights, material, an
    environment's SH weights, eyes."""
    lights, eyes = job["lights"], job["eyes"]
    nL = max(len(lights), 1)
    _set(prog, "g_pos", 0)
    _set(prog, "g_normal", 1)
    _set(prog, "g_detail", 2)
    if tiles is not None:
        _set(prog, "shadow_maps", 3)
        sides = np.zeros(nL, np.int32)
        sides[:len(job["sm_sizes"])] = job["sm_sizes"]
        _write(prog, "sm_size", sides.tobytes())
        to_light = np.tile(np.eye(4), (nL, 1, 1))
        proj = np.zeros((nL, 4), np.float32)
        bias = np.ones((nL, 2), np.float32)
        for i, sm in enumerate(job["shadow"]):
            if sm is not None:
                to_light[i], proj[i], bias[i] = sm["to_light"], sm["proj"], sm["bias"]
        tl = np.zeros((nL, 2), np.int32)
        tl[:len(tiles)] = tiles
        _write(prog, "sm_tile", tl.tobytes())
        _write(prog, "sm_to_light", b"".join(_mat(m) for m in to_light))
        _write(prog, "sm_proj", proj.tobytes())
        _write(prog, "sm_bias", bias.tobytes())
    kd, i_s, s, amb = job["material"]
    _set(prog, "kd", tuple(kd))
    _set(prog, "i_s", i_s)
    _set(prog, "shininess", s)
    _set(prog, "ambient", tuple(amb))
    _set(prog, "cam_pos", tuple(job["cam_pos"]))
    _set(prog, "cam_back", tuple(job["cam_back"]))
    _set(prog, "background", tuple(float(b) for b in p.background))
    _set(prog, "exposure", float(p.exposure))
    _set(prog, "clamp01", bool(p.clamp))
    _set_lights(prog, lights, nL)
    if job["env_sh"] is not None:
        _write(prog, "env_sh", np.asarray(job["env_sh"], np.float32).tobytes())
    _write(prog, "ray_dir", _mat(job["ray_dir"]))  # screen.vert VIEW_RAY, the eyes
    _set(prog, "view_size", (float(job["W"]), float(job["H"])))
    if eyes is not None:
        centres, axes, R = eyes
        _write(prog, "ray_org", _mat(job["ray_org"]))
        _set(prog, "fwd", tuple(job["fwd"]))
        _write(prog, "eye_c", np.asarray(centres, np.float32).tobytes())
        _write(prog, "eye_axis", np.asarray(axes, np.float32).tobytes())
        _set(prog, "eye_R", float(R))
        _set(prog, "eye_s", float(p.eye_shininess))
        _set(prog, "eye_ks", float(p.eye_specular))


#: the lighting pass writes the image into an RGB32F target and the alpha into an R32F one
#: where the driver renders RGB32F (checked once: ``_split_alpha``); False: one RGBA32F target
SPLIT_ALPHA = True


def _split_alpha(rt) -> bool:
    """Whether this context renders into RGB32F textures (not required by OpenGL 3.3): a 2×2
    target cleared and read back (GL thread)."""
    ok = getattr(rt, "_rgb32f_ok", None)
    if ok is None:
        ok = False
        try:
            t = rt.ctx.texture((2, 2), 3, dtype="f4")
            try:
                f = rt.ctx.framebuffer(color_attachments=[t])
                try:
                    f.use()
                    f.clear(0.5, 0.25, -2.0, 1.0)
                    got = np.frombuffer(f.read(components=3, dtype="f4"), np.float32)
                    ok = bool(np.array_equal(got, np.tile(np.float32([0.5, 0.25, -2.0]), 4)))
                finally:
                    f.release()
            finally:
                t.release()
        except Exception:  # noqa: BLE001 - not renderable here: one RGBA32F target
            ok = False
        rt._rgb32f_ok = ok
    return ok and SPLIT_ALPHA


def _render_job(rt, job):
    rt.objects.begin()
    return _render(rt, job)


def _render(rt, job):
    """The GL passes: shadow atlas, surface (g-buffer), lighting (shade.frag); returns
    (image H×W×3, (depth H×W, coverage H×W, covered pixels) from shade.frag's alpha over
    the box job["bbox"] (± camera z, 0 where uncovered; kept per surface_key), that alpha's
    maximum, the lit masks over that box (h×w×4) or None with one light), float32."""
    ctx, mgl = rt.ctx, rt.gl
    W, H, p = job["W"], job["H"], job["p"]
    ctx.enable(mgl.DEPTH_TEST)
    ctx.disable(mgl.CULL_FACE | mgl.BLEND)
    ctx.depth_func = "<"
    lights = job["lights"]
    nL = max(len(lights), 1)
    shadows = job["shadow"] is not None
    eyes = job["eyes"]
    if shadows:
        atlas, tiles = _shadow_atlas(rt, job)
    g = _gbuffer(rt, job)
    masks = nL > 1  # one light: its "lit somewhere" check is the sign of the image's alpha
    # specialised (the same maths, less of it): DETAIL 0 when no detail texture (the g-buffer's
    # factor is 1, not fetched), DIRECTIONAL 1 when no light is a point light (no such branch)
    # VIEW_RAY (perspective): the view vector from the pixel's ray (the reference's, exactly
    # up to float32), which needs no world position; then NO_DEPTH where nothing else needs it
    # and depth and coverage are kept from an earlier call
    skey = surface_key(job)
    surf = rt.objects.peek(skey)
    ortho = bool(job["cam_ortho"])
    directional = all(kind == 0 for kind, *_ in lights)
    defines = {"N_LIGHTS": nL, "ORTHO": int(ortho), "SHADOWS": int(shadows), "EYES": 0,
               "LIT_MASKS": int(masks), "DETAIL": int(job["detail"] is not None),
               "DIRECTIONAL": int(directional), "VIEW_RAY": int(not ortho),
               "NO_DEPTH": int(not ortho and directional and not shadows and surf is not None),
               "ENV_SH": int(job["env_sh"] is not None)}
    # the image in an RGB32F target (read back as it is stored) and the alpha in its own R32F
    # target (ALPHA_OUT: its location), where the driver renders RGB32F; else one RGBA32F
    split = _split_alpha(rt)
    if split:
        defines["ALPHA_OUT"] = 2 if masks else 1
    # the mesh's box without the eye highlights, then the eyes' box with them (glscene.scene)
    # (the eyes' program shades every pixel of its box: the other one skips it, job["boxes"])
    prog = rt.program("screen.vert", "shade.frag", defines)
    passes = [(prog, box) for box in job["boxes"]]
    if eyes is not None:
        passes.append((rt.program("screen.vert", "shade.frag", {**defines, "EYES": 1, "NO_DEPTH": 0}),
                       job["eye_box"]))
    for i, t in enumerate(g["tex"]):
        t.use(location=i)
    if shadows:
        atlas.use(location=3)
    for prog in {id(pr): pr for pr, _ in passes}.values():
        _shade_uniforms(prog, job, p, tiles if shadows else None)
    colors = ((3,) if split else (4,)) + ((4,) if masks else ()) + ((1,) if split else ())
    out = _target(rt, "shade", W, H, colors, depth=False)
    fbo = out["fbo"]
    fbo.use()
    fbo.viewport = (0, 0, W, H)
    ctx.disable(mgl.DEPTH_TEST)
    # only the box where a surface or an eye can be (glscene.screen_box) is shaded; every
    # other pixel is the background output (glscene.background_out, alpha 0: uncovered), as
    # the target is cleared to it; the image is read back whole as RGB straight into the
    # output array (no host-side fill and copy), the alpha (± camera z) over the box only.
    # The clear is skipped when the kept target's last frame had the same background and
    # boxes (a light drag): the passes rewrite every pixel they wrote then, and no other
    # pixel has been written since its clear
    ctx.scissor = None
    layout = (tuple(job["bg_out"]), tuple(tuple(b) for _, b in passes))
    if out["key"] != layout:
        fbo.clear(*job["bg_out"], 0.0)
        if split:  # the alpha target: 0 (uncovered), not the background's red
            if "afbo" not in out:
                out["afbo"] = ctx.framebuffer(color_attachments=[out["tex"][-1]])
            out["afbo"].clear(0.0, 0.0, 0.0, 0.0)
            fbo.use()
        out["key"] = layout
    for prog, (x, y, w, h) in passes:
        if w and h:
            ctx.scissor = (x, y, w, h)
            vao = rt.objects.get(("screen", prog.glo), lambda: ctx.vertex_array(prog, []))
            vao.render(mgl.TRIANGLES, vertices=3)
    ctx.scissor = None
    img = np.empty((H, W, 3), np.float32)
    fbo.read_into(img, components=3, dtype="f4", attachment=0)
    x, y, w, h = job["bbox"]
    # the alpha over the box into a kept buffer (not returned: reduced here, copied if asked)
    nc = 1 if split else 4
    buf = rt.objects.get(("alpha", w, h, nc), lambda: np.empty((h, w, nc), np.float32), 0)
    alpha = buf[..., nc - 1]
    lit, top = None, 0.0
    if w and h:
        fbo.read_into(buf, viewport=(x, y, w, h), components=nc, dtype="f4", attachment=len(colors) - 1 if split else 0)
        top = float(np.fmax.reduce(alpha, axis=None))  # NaN-blind, as (alpha > 0).any()
        if masks:
            lit = np.empty((h, w, 4), np.float32)
            fbo.read_into(lit, viewport=(x, y, w, h), components=4, dtype="f4", attachment=1)
    if surf is None:
        surf = _surface(alpha, job["bbox"], W, H)
        rt.objects.put(skey, surf, surf[0].nbytes + surf[1].nbytes)
    ctx.enable(mgl.DEPTH_TEST)
    return img, surf, top, lit
