// Studio live view of Render (Paris 2003 §5): the face relit in the browser with WebGL2.
// The programs are shaders/glsl/ as graphkit.glsl preprocesses them for GLSL ES 3.00 (the
// moderngl backend compiles the same files as GLSL 3.30); the scene (mesh, camera, detail
// texture, material, light uniforms, shadow-map frames) comes from nodes/paris/glscene.py.
// Passes as in plugins/graphkit-moderngl/graphkit_moderngl/render.py: shadow atlas (here depth-
// only, from the world positions: depth.vert WORLD, shade.frag SM_WINDOW), texture-
// camera depth, surface (g-buffer, kept while only the light changes), then a frame's one pass:
// lighting straight onto the canvas (shade.frag DISPLAY: × 2^exposure, sRGB as display.frag).
// readImage() runs the lighting pass into an RGBA32F target instead (the float image the tests
// compare with the numpy Render); drawFloat() shows that target through display.frag.
// Test/benchmark hooks on the canvas: canvas.gkFace = {setLight, readImage, readCanvas, sync, time,
// profile (median ms per pass), program (swap a program: shader experiments)}.

function decode(a) {
  const bin = atob(a.b64);
  const u8 = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) u8[i] = bin.charCodeAt(i);
  return a.dtype === 'u4' ? new Uint32Array(u8.buffer) : a.dtype === 'f8' ? new Float64Array(u8.buffer) : new Float32Array(u8.buffer);
}

// Light 0's part of the scene (FaceView._light_part's shape: lights' uniforms, shadow frames)
// for ``light`` = {direction, intensity, color} made directional, as FaceView.frame computes
// it on the host (_lights, render.world_lights, glscene.light_part → _shadow_setup →
// raster.shadow_frame / _look_frame, _view_geometry, _set_depth_range): the same formulas in
// float64 over the constants of FaceView._frame_constants (``fc``), so a drag needs no round
// trip; the other lights' parts are the view's (``d``).  null where a value is not valid
// (the host then says why).  tests/test_studio_face.py compares it with the host's.
function lightFrame(d, fc, light) {
  const norm = v => Math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const dir = light.direction, col = light.color, I = light.intensity;
  if (!Array.isArray(dir) || dir.length !== 3 || !Array.isArray(col) || col.length !== 3) return null;
  if (![...dir, ...col, I].every(x => typeof x === 'number' && Number.isFinite(x)) || I < 0) return null;
  const n0 = norm(dir);
  if (!(n0 > 0)) return null;
  const d1 = dir.map(x => x / n0);  // FaceView._lights
  const n1 = norm(d1);
  const l0 = { kind: 0, dir: d1.map(x => x / n1), pos: d.light.position.slice(), rgb: col.map(c => c * I) };
  const part = { lights: [l0, ...d.lights.slice(1)] };
  if (!d.shadow) return part;
  // raster._look_frame(−d1, up)
  const fw = d1.map(x => -x), nf = norm(fw), f = fw.map(x => x / nf);
  let up = fc.up;
  if (norm(cross(up, f)) < 0.1 * norm(up)) up = null;
  if (!up) up = Math.abs(f[1]) < 0.9 ? [0, 1, 0] : [1, 0, 0];
  let x = cross(up, f);
  const nx = norm(x);
  x = x.map(v => v / nx);
  const y = cross(f, x);
  // raster.shadow_frame (directional): q = V Rᵀ, the texel frame fitted to all vertices
  const V = fc.V64 || (fc.V64 = decode(fc.V)), nv = V.length / 3;
  let lo0 = Infinity, lo1 = Infinity, hi0 = -Infinity, hi1 = -Infinity;
  const qz = new Float64Array(nv);
  for (let i = 0; i < nv; i++) {
    const a = V[3 * i], b = V[3 * i + 1], c = V[3 * i + 2];
    const q0 = a * x[0] + b * x[1] + c * x[2], q1 = a * y[0] + b * y[1] + c * y[2];
    qz[i] = a * f[0] + b * f[1] + c * f[2];
    if (!(Number.isFinite(q0) && Number.isFinite(q1) && Number.isFinite(qz[i]))) return null;
    if (q0 < lo0) lo0 = q0; if (q0 > hi0) hi0 = q0;
    if (q1 < lo1) lo1 = q1; if (q1 > hi1) hi1 = q1;
  }
  const size = fc.size;
  const ext = Math.max(hi0 - lo0, hi1 - lo1) * (1 + 2 * fc.margin) || 1.0;
  const sc = size / ext;
  const ox = size / 2 - (lo0 + hi0) / 2 * sc, oy = size / 2 - (lo1 + hi1) / 2 * sc;
  // glscene._shadow_setup: the orthographic clip matrix; _view_geometry → _set_depth_range
  // over the vertices the faces use
  const used = fc.used ? (fc.usedIdx || (fc.usedIdx = decode(fc.used))) : null;
  let zlo = Infinity, zhi = -Infinity;
  const m = used ? used.length : nv;
  for (let k = 0; k < m; k++) { const z = qz[used ? used[k] : k]; if (z < zlo) zlo = z; if (z > zhi) zhi = z; }
  if (m === 0) zlo = zhi = 1.0;
  const pad = 0.01 * (zhi - zlo) + 1e-6 * Math.max(Math.abs(zlo), Math.abs(zhi), 1.0);
  const zn = zlo - pad, zf = zhi + pad;
  const P = [[2 * sc / size, 0, 0, 2 * ox / size - 1], [0, 2 * sc / size, 0, 2 * oy / size - 1],
             [0, 0, 2 / (zf - zn), -(zf + zn) / (zf - zn)], [0, 0, 0, 1]];
  const M = [[...x, 0], [...y, 0], [...f, 0], [0, 0, 0, 1]];
  const colMajor = A => [0, 1, 2, 3].flatMap(j => [0, 1, 2, 3].map(i => A[i][j]));
  const PM = P.map(row => [0, 1, 2, 3].map(j => row[0] * M[0][j] + row[1] * M[1][j] + row[2] * M[2][j] + row[3] * M[3][j]));
  const sm0 = { to_light: colMajor(M), proj: [sc, sc, ox, oy], bias: [ext / size, 1.0], world_clip: colMajor(PM),
                zmap: [0.5 + 0.5 * P[2][3], 0.5 * P[2][2], 0.0], faces: null };
  return { ...part, shadow: [sm0, ...d.shadow.slice(1)], shadow_map_size: d.shadow_map_size };
}

function program(gl, [vs, fs]) {
  const p = gl.createProgram();
  for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    gl.attachShader(p, s);
  }
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  const loc = {};
  p.u = name => (name in loc ? loc[name] : (loc[name] = gl.getUniformLocation(p, name)));
  // shade.frag SM_BILINEAR declares the shadow atlas a sampler2DShadow: bound with comparison
  p.shadowCompare = Array.from({ length: gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS) }, (_, i) => gl.getActiveUniform(p, i))
    .some(u => u.name === 'shadow_maps' && u.type === gl.SAMPLER_2D_SHADOW);
  return p;
}

function target(gl, W, H, formats, depth = true) {
  const fbo = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
  const tex = formats.map((f, i) => {
    const t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texStorage2D(gl.TEXTURE_2D, 1, f, W, H);
    for (const k of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, k, gl.NEAREST);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, gl.TEXTURE_2D, t, 0);
    return t;
  });
  if (depth) {
    const rb = gl.createRenderbuffer();
    gl.bindRenderbuffer(gl.RENDERBUFFER, rb);
    gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT24, W, H);
    gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, rb);
  }
  gl.drawBuffers(formats.map((_, i) => gl.COLOR_ATTACHMENT0 + i));
  const st = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
  if (st !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`framebuffer incomplete (${st})`);
  return { fbo, tex, W, H, n: formats.length };
}

// A vertex array of float vec3 attributes (``layout``: their names, interleaved in ``verts``),
// drawn indexed by ``faces``, or un-indexed when ``faces`` is null.
function mesh(gl, prog, verts, faces, layout) {
  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  const vb = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, vb);
  gl.bufferData(gl.ARRAY_BUFFER, verts, gl.STATIC_DRAW);
  const stride = layout.length * 12;
  layout.forEach((name, i) => {
    const l = gl.getAttribLocation(prog, name);
    if (l < 0) return;
    gl.enableVertexAttribArray(l);
    gl.vertexAttribPointer(l, 3, gl.FLOAT, false, stride, i * 12);
  });
  let ib = null;
  if (faces) {
    ib = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, faces, gl.STATIC_DRAW);
  }
  gl.bindVertexArray(null);
  const count = faces ? faces.length : verts.length / (layout.length * 3);
  return {
    vao, vb, ib, count,
    draw() {
      gl.bindVertexArray(vao);
      if (faces) gl.drawElements(gl.TRIANGLES, count, gl.UNSIGNED_INT, 0);
      else gl.drawArrays(gl.TRIANGLES, 0, count);
    },
    release() { gl.deleteVertexArray(vao); gl.deleteBuffer(vb); if (ib) gl.deleteBuffer(ib); },
  };
}

// The surface pass's mesh for gbuffer.frag's EXACT mode: triangles drawn un-indexed, each
// corner with its own q, P, N and its triangle's three world vertices (A0–A2) and normals
// (B0–B2), which the shaders pass on flat.
function exactMesh(gl, prog, verts, faces) {
  const n = faces.length, out = new Float32Array(n * 27);
  for (let t = 0; t < n; t += 3) {
    const c = [faces[t] * 9, faces[t + 1] * 9, faces[t + 2] * 9];
    for (let k = 0; k < 3; k++) {
      const o = (t + k) * 27;
      out.set(verts.subarray(c[k], c[k] + 9), o);
      for (let j = 0; j < 3; j++) {
        out.set(verts.subarray(c[j] + 3, c[j] + 6), o + 9 + 3 * j);   // A_j = P of corner j
        out.set(verts.subarray(c[j] + 6, c[j] + 9), o + 18 + 3 * j);  // B_j = N of corner j
      }
    }
  }
  return mesh(gl, prog, out, null, ['q', 'P', 'N', 'A0', 'A1', 'A2', 'B0', 'B1', 'B2']);
}

export function createFaceRenderer(canvas, d) {
  const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true });
  if (!gl) throw new Error('WebGL2 is not available in this browser');
  if (!gl.getExtension('EXT_color_buffer_float')) throw new Error('EXT_color_buffer_float is missing: no float render targets');
  const W = d.W, H = d.H;
  canvas.width = W; canvas.height = H;
  const P = {};
  for (const k of Object.keys(d.glsl)) P[k] = program(gl, d.glsl[k]);
  // the lighting programs with DIRECTIONAL (compiled when first needed), while every light is
  // directional; else the general ones
  const PD = {};
  const lit = k => {
    if (!scene.lights.every(l => l.kind === 0) || !(d.glsl_directional || {})[k]) return P[k];
    return PD[k] || (PD[k] = program(gl, d.glsl_directional[k]));
  };
  const PT = {};  // the general ones with the PCF's 9 texel fetches (readImage('taps'), tests)
  const taps = k => (d.glsl_taps && d.glsl_taps[k] ? PT[k] || (PT[k] = program(gl, d.glsl_taps[k])) : null);
  // the atlas as shade.frag SM_BILINEAR samples it: depth comparison (LEQUAL: lit where the
  // biased depth ≤ the map's), bilinear; the texture's own state (nearest, no comparison) is
  // what the 9-tap programs' texelFetch reads
  const compareSampler = gl.createSampler();
  for (const [k, v] of [[gl.TEXTURE_COMPARE_MODE, gl.COMPARE_REF_TO_TEXTURE], [gl.TEXTURE_COMPARE_FUNC, gl.LEQUAL],
                        [gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
                        [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) gl.samplerParameteri(compareSampler, k, v);
  const empty = gl.createVertexArray();
  const verts = decode(d.vertices), faces = decode(d.faces);
  const mainZ = mesh(gl, P.depth, verts, faces, ['q', 'P', 'N']);
  const mainG = exactMesh(gl, P.gbuffer, verts, faces);
  const gbuf = target(gl, W, H, [gl.RGBA32F, gl.RGBA32F, gl.RGBA32F]);
  const out = target(gl, W, H, [gl.RGBA32F], false);  // shade.frag's o_image (no LIT_MASKS here)
  let scene = d, atlas = null, atlasTiles = null, shadowMeshes = [], gbufDone = false, detailTex = null, texDepth = null;
  // the shadow maps: the drawn mesh (all its faces) from its world positions (depth.vert WORLD)
  const allFaces = d.shadow ? mesh(gl, P.shadow, verts, decode(d.mesh_faces), ['q', 'P', 'N']) : null;
  const nL = Math.max(d.lights.length, 1);

  function depthPass(geom, viewport) {
    gl.useProgram(P.depth);
    gl.uniformMatrix4fv(P.depth.u('proj'), false, geom.clip);
    gl.viewport(...viewport);
    geom.mesh.draw();
  }

  function depthTarget(W, H) {  // a depth texture only (shadow maps: window depths)
    const fbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    const t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.DEPTH_COMPONENT32F, W, H);
    for (const k of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, k, gl.NEAREST);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.TEXTURE_2D, t, 0);
    gl.drawBuffers([gl.NONE]);
    gl.readBuffer(gl.NONE);
    const st = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
    if (st !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`framebuffer incomplete (${st})`);
    return { fbo, tex: [t], W, H, n: 0 };
  }

  function shadowAtlas() {
    // depth-only (depth.frag DEPTH_ONLY) into a depth texture, from the world positions: a
    // light change uploads its matrix (and faces only where its frame drops some)
    const sms = scene.shadow, size = scene.shadow_map_size;
    const n = sms.length, cols = Math.ceil(Math.sqrt(n)), rows = Math.ceil(n / cols);
    // each tile: the size² map inside a border of 2 texels left at the clear's 1.0, which
    // shade.frag SM_WINDOW's taps outside the map read (lit) instead of clamping each tap; the
    // texture's sides are powers of two (SM_BILINEAR's exact sample coordinates), only the
    // tiles' part is cleared (no tap reads beyond its tile)
    const pitch = size + 4, aw = cols * pitch, ah = rows * pitch;
    const pow2 = n => 2 ** Math.ceil(Math.log2(n));
    if (!atlas || atlas.W !== pow2(aw) || atlas.H !== pow2(ah)) atlas = depthTarget(pow2(aw), pow2(ah));
    atlasTiles = sms.map((_, i) => [(i % cols) * pitch, Math.floor(i / cols) * pitch]);
    gl.bindFramebuffer(gl.FRAMEBUFFER, atlas.fbo);
    gl.enable(gl.DEPTH_TEST); gl.depthFunc(gl.LESS); gl.depthMask(true);
    gl.enable(gl.SCISSOR_TEST);
    gl.scissor(0, 0, aw, ah);
    gl.clearBufferfv(gl.DEPTH, 0, [1.0]);
    gl.disable(gl.SCISSOR_TEST);
    shadowMeshes.forEach(m => m && m.release());
    shadowMeshes = [];
    gl.useProgram(P.shadow);
    sms.forEach((sm, i) => {
      if (!sm) return;
      let m = allFaces;
      if (sm.faces) shadowMeshes.push(m = mesh(gl, P.shadow, verts, decode(sm.faces), ['q', 'P', 'N']));
      gl.uniformMatrix4fv(P.shadow.u('proj'), false, sm.world_clip);
      gl.viewport(atlasTiles[i][0] + 2, atlasTiles[i][1] + 2, size, size);
      m.draw();
    });
  }

  function surface() {
    gl.enable(gl.DEPTH_TEST); gl.depthFunc(gl.LESS); gl.depthMask(true);
    const det = d.detail;
    if (det) {
      const [tw, th] = det.size;
      texDepth = target(gl, tw, th, [gl.RGBA32F]);
      gl.bindFramebuffer(gl.FRAMEBUFFER, texDepth.fbo);
      gl.viewport(0, 0, tw, th);
      gl.clearBufferfv(gl.COLOR, 0, [0, 0, 0, 0]);
      gl.clearBufferfv(gl.DEPTH, 0, [1.0]);
      const m = mesh(gl, P.depth, decode(det.q), decode(det.faces), ['q']);
      depthPass({ clip: det.clip, mesh: m }, [0, 0, tw, th]);
      m.release();
      detailTex = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, detailTex);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGB32F, tw, th);
      gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, tw, th, gl.RGB, gl.FLOAT, decode(det.pixels));
      for (const k of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, k, gl.NEAREST);
    }
    gl.bindFramebuffer(gl.FRAMEBUFFER, gbuf.fbo);
    gl.viewport(0, 0, W, H);
    for (let i = 0; i < 3; i++) gl.clearBufferfv(gl.COLOR, i, [0, 0, 0, 0]);
    gl.clearBufferfv(gl.DEPTH, 0, [1.0]);
    // depth pre-pass, then the surface pass on the nearest fragment only (depth ==)
    gl.colorMask(false, false, false, false);
    depthPass({ clip: d.clip, mesh: mainZ }, [0, 0, W, H]);
    gl.colorMask(true, true, true, true);
    const g = P.gbuffer;
    gl.useProgram(g);
    gl.uniformMatrix4fv(g.u('proj'), false, d.clip);
    gl.uniform3fv(g.u('cam_pos'), d.cam_pos);
    gl.uniform3fv(g.u('cam_back'), d.cam_back);
    gl.uniformMatrix3fv(g.u('ray_org'), false, d.ray_org);
    gl.uniformMatrix3fv(g.u('ray_dir'), false, d.ray_dir);
    if (det) {
      gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_2D, detailTex);
      gl.activeTexture(gl.TEXTURE1); gl.bindTexture(gl.TEXTURE_2D, texDepth.tex[0]);
      gl.uniform1i(g.u('detail'), 0);
      gl.uniform1i(g.u('tex_depth'), 1);
      gl.uniformMatrix4fv(g.u('tex_proj'), false, det.proj);
      gl.uniform2iv(g.u('tex_size'), det.size);
      gl.uniform1f(g.u('occl_tol'), det.tol);
    }
    gl.depthFunc(gl.EQUAL);
    mainG.draw();
    gl.depthFunc(gl.LESS);
    gbufDone = true;
    coverRects();
  }

  // The lighting pass without the eye highlights is drawn over rectangles that hold every
  // pixel the surface covers in its boxes (d.boxes: the mesh's screen box without the eyes'
  // boxes, FaceView._eye_boxes), from the g-buffer's coverage read back once: bands of BAND rows, each
  // cut into runs of covered columns (gaps of up to GAP pixels bridged).  SwiftShader runs the
  // whole shader on every pixel drawn, covered or not (a branch is lane-masked), so this
  // shades ~117k pixels instead of the boxes' ~140k (face_relight left60 at 512²); the others
  // keep the background the target was cleared to, what shade.frag writes there
  // (glscene.background_out).  (2-row bands: 113k pixels but slower, the thin triangles cost.)
  const BAND = 16, GAP = 8;
  let rects = null;

  // The colour the canvas's pixels outside the rectangles and the eyes' boxes were last cleared
  // to (null: unknown); the drawing buffer is kept between frames (preserveDrawingBuffer), so a
  // frame with the same background clears nothing: only those pixels are drawn.
  let canvasBg = null;
  const preserved = gl.getContextAttributes().preserveDrawingBuffer;

  function coverRects() {
    const list = [];  // [x, y, w, h], window (image) rows
    gl.bindFramebuffer(gl.FRAMEBUFFER, gbuf.fbo);
    gl.readBuffer(gl.COLOR_ATTACHMENT1);  // o_normal: w = 1 where covered (shade.frag's test)
    for (const box of d.boxes) {
      if (!box || !(box[2] > 0 && box[3] > 0)) continue;
      const [bx, by, bw, bh] = box;
      const cov = new Float32Array(bw * bh * 4);
      gl.readPixels(bx, by, bw, bh, gl.RGBA, gl.FLOAT, cov);
      const col = new Uint8Array(bw);
      for (let y0 = by; y0 < by + bh; y0 += BAND) {
        const y1 = Math.min(y0 + BAND, by + bh);
        col.fill(0);
        for (let y = y0; y < y1; y++) {
          const row = (y - by) * bw * 4;
          for (let x = 0; x < bw; x++) if (cov[row + 4 * x + 3] > 0.5) col[x] = 1;
        }
        for (let x = 0; x < bw;) {
          if (!col[x]) { x++; continue; }
          let last = x;
          for (let e = x + 1; e < bw && e - last <= GAP + 1; e++) if (col[e]) last = e;
          list.push([bx + x, y0, last + 1 - x, y1 - y0]);
          x = last + 1;
        }
      }
    }
    gl.readBuffer(gl.COLOR_ATTACHMENT0);
    const v = new Float32Array(list.length * 12);
    list.forEach(([x, y, w, h], i) => v.set([x, y, x + w, y, x + w, y + h, x, y, x + w, y + h, x, y + h], 12 * i));
    const flipped = v.map((c, i) => (i & 1 ? H - c : c));  // canvas rows (DISPLAY): y → H − y
    if (rects) rects.release();
    canvasBg = null;
    const bufs = [v, flipped].map(a => { const b = gl.createBuffer(); gl.bindBuffer(gl.ARRAY_BUFFER, b); gl.bufferData(gl.ARRAY_BUFFER, a, gl.STATIC_DRAW); return b; });
    const vaos = new Map();  // (program, rows) → its vertex array over that buffer
    rects = {
      n: list.length, pixels: list.reduce((a, r) => a + r[2] * r[3], 0),
      draw(prog, canvasRows) {
        const key = canvasRows ? 1 : 0;
        let m = vaos.get(prog);
        if (!m) vaos.set(prog, m = []);
        if (!m[key]) {
          m[key] = gl.createVertexArray();
          gl.bindVertexArray(m[key]);
          gl.bindBuffer(gl.ARRAY_BUFFER, bufs[key]);
          const loc = gl.getAttribLocation(prog, 'corner');
          gl.enableVertexAttribArray(loc);
          gl.vertexAttribPointer(loc, 2, gl.FLOAT, false, 8, 0);
        }
        gl.bindVertexArray(m[key]);
        gl.uniform2f(prog.u('view_size'), W, H);
        gl.drawArrays(gl.TRIANGLES, 0, list.length * 6);
      },
      release() { for (const m of vaos.values()) m.forEach(x => x && gl.deleteVertexArray(x)); bufs.forEach(b => gl.deleteBuffer(b)); },
    };
  }

  function shadeUniforms(s) {
    gl.useProgram(s);
    for (let i = 0; i < 3; i++) { gl.activeTexture(gl.TEXTURE0 + i); gl.bindTexture(gl.TEXTURE_2D, gbuf.tex[i]); }
    gl.uniform1i(s.u('g_pos'), 0); gl.uniform1i(s.u('g_normal'), 1); gl.uniform1i(s.u('g_detail'), 2);
    const L = scene.lights;
    const kind = new Int32Array(nL), dir = new Float32Array(3 * nL), pos = new Float32Array(3 * nL), rgb = new Float32Array(3 * nL);
    for (let i = 0; i < nL; i++) dir[3 * i + 2] = 1;
    L.forEach((l, i) => { kind[i] = l.kind; dir.set(l.dir, 3 * i); pos.set(l.pos, 3 * i); rgb.set(l.rgb, 3 * i); });
    gl.uniform1iv(s.u('light_kind'), kind);
    gl.uniform3fv(s.u('light_dir'), dir); gl.uniform3fv(s.u('light_pos'), pos); gl.uniform3fv(s.u('light_rgb'), rgb);
    if (scene.shadow) {
      gl.activeTexture(gl.TEXTURE3); gl.bindTexture(gl.TEXTURE_2D, atlas.tex[0]);
      gl.bindSampler(3, s.shadowCompare ? compareSampler : null);
      gl.uniform1i(s.u('shadow_maps'), 3);
      if (s.shadowCompare) gl.uniform2f(s.u('sm_texel'), 1 / atlas.W, 1 / atlas.H);
      gl.uniform1i(s.u('sm_size'), scene.shadow_map_size);
      const tl = new Int32Array(2 * nL), M = new Float32Array(16 * nL), pr = new Float32Array(4 * nL), b = new Float32Array(2 * nL).fill(1);
      const zm = new Float32Array(3 * nL);
      for (let i = 0; i < nL; i++) M.set([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], 16 * i);
      scene.shadow.forEach((sm, i) => {
        tl.set(atlasTiles[i], 2 * i);
        if (!sm) return;
        M.set(sm.to_light, 16 * i); pr.set(sm.proj, 4 * i); b.set(sm.bias, 2 * i); zm.set(sm.zmap, 3 * i);
      });
      gl.uniform2iv(s.u('sm_tile'), tl);
      gl.uniformMatrix4fv(s.u('sm_to_light'), false, M);
      gl.uniform4fv(s.u('sm_proj'), pr);
      gl.uniform2fv(s.u('sm_bias'), b);
      gl.uniform3fv(s.u('sm_zmap'), zm);
    }
    gl.uniform3fv(s.u('cam_pos'), d.cam_pos); gl.uniform3fv(s.u('cam_back'), d.cam_back);
    gl.uniform3fv(s.u('kd'), d.kd); gl.uniform1f(s.u('i_s'), d.i_s); gl.uniform1f(s.u('shininess'), d.shininess);
    gl.uniform3fv(s.u('ambient'), d.ambient); gl.uniform3fv(s.u('background'), d.background);
    gl.uniform1f(s.u('exposure'), d.exposure); gl.uniform1i(s.u('clamp01'), d.clamp ? 1 : 0);
    const e = d.eyes;
    if (e) {
      gl.uniformMatrix3fv(s.u('ray_org'), false, d.ray_org); gl.uniformMatrix3fv(s.u('ray_dir'), false, d.ray_dir);
      gl.uniform3fv(s.u('fwd'), e.fwd); gl.uniform3fv(s.u('eye_c'), e.c); gl.uniform3fv(s.u('eye_axis'), e.axis);
      gl.uniform1f(s.u('eye_R'), e.R); gl.uniform1f(s.u('eye_s'), e.s); gl.uniform1f(s.u('eye_ks'), e.ks);
    }
  }

  function lighting(general = false) {  // general: the programs without DIRECTIONAL; 'taps': those with the PCF's 9 fetches (tests)
    gl.bindFramebuffer(gl.FRAMEBUFFER, out.fbo);
    gl.viewport(0, 0, W, H);
    gl.disable(gl.DEPTH_TEST);
    // only the pixels where a surface or an eye can be are shaded: the surface's rectangles
    // (coverRects) without the eye highlights, then the eyes' box with them; the rest is the
    // background as shade.frag would write it (glscene.background_out)
    gl.clearBufferfv(gl.COLOR, 0, [...d.bg_out, 0]);
    const s = general === 'taps' ? taps('shade') : general ? P.shade : lit('shade');
    shadeUniforms(s);
    rects.draw(s, false);
    eyesPass(general === 'taps' ? taps('shade_eyes') : general ? P.shade_eyes : lit('shade_eyes'), d.eye_boxes);
  }

  function eyesPass(prog, boxes) {  // the eyes' program over every pixel of their boxes (scissored)
    if (!prog || !boxes) return;
    shadeUniforms(prog);
    gl.enable(gl.SCISSOR_TEST);
    gl.bindVertexArray(empty);
    for (const box of boxes) {
      if (!(box[2] > 0 && box[3] > 0)) continue;
      gl.scissor(...box);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    }
    gl.disable(gl.SCISSOR_TEST);
  }

  function display(exposure) {  // the float target onto the canvas (display.frag)
    canvasBg = null;  // every canvas pixel drawn
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, W, H);
    gl.useProgram(P.display);
    gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_2D, out.tex[0]);
    gl.uniform1i(P.display.u('image'), 0);
    gl.uniform1f(P.display.u('scale'), Math.pow(2, exposure));
    gl.bindVertexArray(empty);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  // sRGB of one linear value (display.frag / srgb.glsl), for the canvas's background clear
  const srgb = v => { const x = Math.min(1, Math.max(0, v)); return x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055; };

  function lightingDisplay(exposure) {
    // a frame: the lighting pass straight onto the canvas (shade.frag DISPLAY: the same maths,
    // then display.frag's encoding), over the same rectangles and box flipped to canvas rows;
    // elsewhere the background output as the display pass would show it
    const scale = Math.pow(2, exposure);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, W, H);
    gl.disable(gl.DEPTH_TEST);
    const bg = d.bg_out.map(v => srgb(v * scale));
    if (!preserved || String(bg) !== canvasBg) {
      gl.clearColor(...bg, 1);
      gl.clear(gl.COLOR_BUFFER_BIT);
      canvasBg = String(bg);
    }
    const s = lit('shade_display');
    shadeUniforms(s);
    gl.uniform1f(s.u('display_scale'), scale);
    gl.uniform1i(s.u('view_h'), H);
    rects.draw(s, true);
    const e = lit('shade_eyes_display');
    if (e && d.eye_boxes) {
      gl.useProgram(e);
      gl.uniform1f(e.u('display_scale'), scale);
      gl.uniform1i(e.u('view_h'), H);
      eyesPass(e, d.eye_boxes.map(b => [b[0], H - b[1] - b[3], b[2], b[3]]));
    }
  }

  return {
    W, H, gl,
    setLights(part) { scene = { ...scene, ...part }; if (scene.shadow) shadowAtlas(); },
    draw(exposure = 0) {
      if (!gbufDone) { surface(); if (scene.shadow && !atlas) shadowAtlas(); }
      lightingDisplay(exposure);
    },
    drawFloat(exposure = 0) {  // the two-pass path: lighting into the float target, then display
      if (!gbufDone) { surface(); if (scene.shadow && !atlas) shadowAtlas(); }
      lighting();
      display(exposure);
    },
    readImage(general = false) {  // RGBA float32 of the lighting pass, image row 0 first (as the moderngl backend)
      if (!gbufDone) { surface(); if (scene.shadow && !atlas) shadowAtlas(); }
      lighting(general);
      gl.bindFramebuffer(gl.FRAMEBUFFER, out.fbo);
      gl.readBuffer(gl.COLOR_ATTACHMENT0);
      const px = new Float32Array(W * H * 4);
      gl.readPixels(0, 0, W, H, gl.RGBA, gl.FLOAT, px);
      return px;
    },
    program(k, srcs) { P[k] = program(gl, srcs); },  // swap a program (shader experiments)
    profile(n) {  // median ms of each pass over n frames, each pass synced (benchmarks)
      // shadow, then the frame's one lighting + display pass; the two-pass float path apart
      const t = { shadow: [], lighting_display: [], float_lighting: [], float_display: [] };
      const run = (k, f) => { const t0 = performance.now(); f(); this.sync(); t[k].push(performance.now() - t0); };
      this.draw();
      for (let i = 0; i < n; i++) {
        if (scene.shadow) run('shadow', shadowAtlas);
        run('lighting_display', () => lightingDisplay(0));
        run('float_lighting', lighting);
        run('float_display', () => display(0));
      }
      const med = a => a.length ? a.sort((x, y) => x - y)[a.length >> 1] : 0;
      return Object.fromEntries(Object.entries(t).map(([k, v]) => [k, med(v)]));
    },
    sync() { const p = new Uint8Array(4); gl.bindFramebuffer(gl.FRAMEBUFFER, null); gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, p); return p; },
  };
}

function b64(f32) {
  const u8 = new Uint8Array(f32.buffer);
  let s = '';
  for (let i = 0; i < u8.length; i += 0x8000) s += String.fromCharCode.apply(null, u8.subarray(i, i + 0x8000));
  return btoa(s);
}

export function mount(el, api) {
  const d = api.data;
  const wrap = document.createElement('div');
  const canvas = document.createElement('canvas');
  canvas.className = 'view-img face-gl';
  canvas.style.maxWidth = '100%';
  const info = document.createElement('div');
  info.className = 'dim view-info';
  let r;
  if (d.not_drawn) {  // the page differs from the node's output there: say so (glscene.not_drawn)
    const warn = document.createElement('div');
    warn.className = 'view-info face-not-drawn';
    warn.textContent = `Not as Render's output: ${d.not_drawn} (the numpy reference draws it).`;
    wrap.append(warn);
  }
  try { r = createFaceRenderer(canvas, d); } catch (e) { info.textContent = `WebGL2 face view unavailable: ${e.message}`; wrap.append(info); el.append(wrap); return; }
  const light = { direction: d.light.direction, intensity: d.light.intensity, color: d.light.color };
  // the sphere widget: a point on the visible hemisphere = the light direction (camera frame:
  // x right, y down, towards the viewer = −z), turned into the world frame (Rᵀ c)
  const R = d.cam_rotation;  // row-major world → camera
  const toWorld = c => [0, 1, 2].map(j => R[j] * c[0] + R[3 + j] * c[1] + R[6 + j] * c[2]);
  const toCam = w => [0, 1, 2].map(i => R[3 * i] * w[0] + R[3 * i + 1] * w[1] + R[3 * i + 2] * w[2]);
  const ball = document.createElement('canvas');
  ball.width = ball.height = 120;
  ball.className = 'light-ball';
  ball.title = 'drag: the direction of light 0 (towards the light)';
  const g2 = ball.getContext('2d');
  function drawBall() {
    const c = toCam(light.direction);
    g2.clearRect(0, 0, 120, 120);
    g2.fillStyle = '#333'; g2.beginPath(); g2.arc(60, 60, 56, 0, 2 * Math.PI); g2.fill();
    g2.fillStyle = c[2] <= 0 ? '#ffd' : '#777';
    g2.beginPath(); g2.arc(60 + 56 * c[0], 60 + 56 * c[1], 6, 0, 2 * Math.PI); g2.fill();
  }
  let inflight = false, queued = false;
  let frames = 0;
  async function update() {
    if (inflight) { queued = true; return; }
    const part = d.light_frame ? lightFrame(d, d.light_frame, light) : null;
    if (part) {  // computed here (lightFrame): no round trip
      r.setLights(part);
      r.draw(api.exposure());
      frames += 1;
      canvas.dataset.frames = String(frames);
      info.textContent = `${r.W}×${r.H} WebGL2 · light frame in the page`;
      return;
    }
    inflight = true;
    try {  // a value lightFrame does not take: the host's frame (its error)
      const res = await api.frame({ ...light });
      if (res.info.error) { info.textContent = res.info.error; return; }
      r.setLights(res.info.scene);
      r.draw(api.exposure());
      frames += 1;
      canvas.dataset.frames = String(frames);
      info.textContent = `${r.W}×${r.H} WebGL2 · host ${res.info.compute_ms} ms`;
    } finally {
      inflight = false;
      if (queued) { queued = false; update(); }
    }
  }
  function fromBall(ev) {
    const b = ball.getBoundingClientRect();
    let x = ((ev.clientX - b.left) / b.width * 120 - 60) / 56, y = ((ev.clientY - b.top) / b.height * 120 - 60) / 56;
    const n = Math.hypot(x, y);
    if (n > 0.999) { x /= n / 0.999; y /= n / 0.999; }
    light.direction = toWorld([x, y, -Math.sqrt(Math.max(0, 1 - x * x - y * y))]);
    drawBall();
    update();
  }
  let dragging = false;
  ball.addEventListener('pointerdown', e => { dragging = true; ball.setPointerCapture(e.pointerId); fromBall(e); });
  ball.addEventListener('pointermove', e => { if (dragging) fromBall(e); });
  ball.addEventListener('pointerup', () => { dragging = false; });
  const row = document.createElement('div');
  row.className = 'ctl';
  const inten = Object.assign(document.createElement('input'), { type: 'range', min: 0, max: 4, step: 0.01, value: light.intensity, title: 'intensity of light 0' });
  inten.dataset.key = 'intensity';
  inten.addEventListener('input', () => { light.intensity = +inten.value; update(); });
  const hex = c => '#' + c.map(v => Math.round(Math.min(1, Math.max(0, v)) * 255).toString(16).padStart(2, '0')).join('');
  const col = Object.assign(document.createElement('input'), { type: 'color', value: hex(light.color), title: 'colour of light 0 (linear RGB)' });
  col.addEventListener('input', () => { light.color = [1, 3, 5].map(i => parseInt(col.value.slice(i, i + 2), 16) / 255); update(); });
  row.append(ball, inten, col);
  wrap.append(canvas, row, info);
  el.append(wrap);
  drawBall();
  r.draw(api.exposure());
  canvas.dataset.frames = '1';
  canvas.gkFace = {
    async setLight(values) { Object.assign(light, values); drawBall(); await update(); return frames; },
    lightFrame(values) { return lightFrame(d, d.light_frame, { ...light, ...values }); },  // tests: the page's part
    async hostFrame(values) { const res = await api.frame({ ...light, ...values }); return res.info.error || res.info.scene; },
    readImage(general = false) { return b64(r.readImage(general)); },
    profile(n) { return r.profile(n); },
    program(k, s) { r.program(k, s); },
    sync() { return r.sync(); },  // a 1-pixel read-back of the canvas: waits for the frame
    readCanvas(twoPass = false) {  // the canvas (RGBA8, GL rows) after a frame, or after the two-pass float path
      if (twoPass) r.drawFloat(api.exposure()); else r.draw(api.exposure());
      const gl = r.gl, px = new Uint8Array(r.W * r.H * 4);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.readPixels(0, 0, r.W, r.H, gl.RGBA, gl.UNSIGNED_BYTE, px);
      r.draw(api.exposure());
      return btoa(Array.from({ length: Math.ceil(px.length / 0x8000) }, (_, i) => String.fromCharCode.apply(null, px.subarray(i * 0x8000, (i + 1) * 0x8000))).join(''));
    },
    // n frames with light 0 turned each time (the drag's directions, offset d0): shadow atlas,
    // lighting and display, each synced with a 1-pixel readPixels.  The n light parts are
    // computed before the clock (lightFrame; the drag's timing includes it); without a
    // page-side frame the atlas is redrawn for the same light.  The view is left as it was.
    time(n, d0 = 0) {
      const parts = Array.from({ length: n }, (_, i) => {
        const a = 0.5 * Math.sin(0.29 * i + d0);
        return d.light_frame ? lightFrame(d, d.light_frame, { ...light, direction: [Math.sin(a), -0.2, -Math.cos(a)] }) : null;
      });
      const ts = [];
      for (let i = 0; i < n; i++) {
        const t = performance.now();
        r.setLights(parts[i] || {});
        r.draw(api.exposure());
        r.sync();
        ts.push(performance.now() - t);
      }
      const now = d.light_frame ? lightFrame(d, d.light_frame, light) : null;
      if (now) { r.setLights(now); r.draw(api.exposure()); }
      return ts;
    },
  };
}
