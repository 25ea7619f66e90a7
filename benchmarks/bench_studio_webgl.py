"""Issue 14 benchmark (b): the studio's WebGL2 face view against a bare one-light Phong WebGL2
page, same mesh, same headless Chromium (Debian's chromium, SwiftShader WebGL2).

The face view is Render's live view (nodes/paris/studio_view.js) of ``left60`` in
graphs/face_relight.yaml at 512² (its smoothed FaceMesh: 13.6k triangles, detail texture,
shadow map, eyes as the graph says), opened in ``graphkit serve``.  Peer: a small static page
written here (``PEER_HTML``, in a second tab of the same browser) that draws the same vertex
and index arrays, fetched from the studio's /api/view, with one directional light, Phong, a
depth test, onto a 512² canvas: its buffers made once, as any hand-written viewer would.

Rows (median and best of ``--rounds`` rounds of ``--n`` frames; the two pages alternate):

* frame time: ``canvas.gkFace.time(n, round)``: n frames, light 0 turned each time along the
  drag's arc (the shadow atlas, then the lighting pass straight onto the canvas; the g-buffer is
  kept; the light parts are computed before the clock, the drag row below includes them), each
  synced with a 1-pixel gl.readPixels, not requestAnimationFrame (capped at the display rate);
  the peer the same with its one pass, its light turned each frame too.
  Ratio = face view / peer (goal of issue 14: ≤ 2×).
* drag: ``canvas.gkFace.setLight({direction})`` n times along an arc, each waiting for the new
  frame: the light's uniforms and shadow-map frame (computed in the page, studio_view.js
  lightFrame, with FaceView.frame's formulas; before, a websocket round trip to the host's
  FaceView.frame), the upload and the draw, synced; reported as fps (goal ≥ 30).

    .venv/bin/python benchmarks/bench_studio_webgl.py [--n 30] [--rounds 7] [--cache DIR]

The first run fills the cache with face_relight at 512² (FaceMesh, fit, …: about a minute).
``--scene`` uses the FaceScene test node (tests/support/studionodes.py) instead.
"""
from __future__ import annotations

import argparse
import base64
import math
import os
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "support"), str(ROOT / "benchmarks")]

import numpy as np  # noqa: E402
from peers import phong_peer  # noqa: E402
from studio_support import Server, browser_page, wait_for, wait_run  # noqa: E402

# the peer's shaders: benchmarks/peers.py (the same text as the moderngl peers), camera frame
PEER_HTML = """<!doctype html><html><body style="margin:0">
<canvas id="c" width="512" height="512"></canvas>
<script>
// A bare one-light Phong WebGL2 viewer (shaders: benchmarks/peers.py): one program, one vertex
// array (camera-frame positions and normals), the default framebuffer.
window.makePeer = function (W, H, vb64, fb64, clip, kd, ks, s, light, vs, fs) {
  const dec = (b, T) => { const s = atob(b), u = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) u[i] = s.charCodeAt(i); return new T(u.buffer); };
  const c = document.getElementById('c'); c.width = W; c.height = H;
  const gl = c.getContext('webgl2', {antialias: false, preserveDrawingBuffer: true});
  const prog = gl.createProgram();
  for (const [t, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
    const sh = gl.createShader(t); gl.shaderSource(sh, src); gl.compileShader(sh);
    if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(sh));
    gl.attachShader(prog, sh);
  }
  gl.linkProgram(prog);
  gl.useProgram(prog);
  const vao = gl.createVertexArray(); gl.bindVertexArray(vao);
  gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
  gl.bufferData(gl.ARRAY_BUFFER, dec(vb64, Float32Array), gl.STATIC_DRAW);
  ['pos', 'nrm'].forEach((a, i) => { const l = gl.getAttribLocation(prog, a); if (l < 0) return;
    gl.enableVertexAttribArray(l); gl.vertexAttribPointer(l, 3, gl.FLOAT, false, 24, 12 * i); });
  const faces = dec(fb64, Uint32Array);
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer());
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, faces, gl.STATIC_DRAW);
  const u = k => gl.getUniformLocation(prog, k);
  gl.uniformMatrix4fv(u('P'), false, clip);
  gl.uniform3fv(u('kd'), kd); gl.uniform1f(u('ks'), ks); gl.uniform1f(u('s'), s);
  gl.enable(gl.DEPTH_TEST); gl.viewport(0, 0, W, H);
  const px = new Uint8Array(4);
  let k = 0;
  window.peer = {
    time(n) {
      const ts = [];
      for (let i = 0; i < n; i++) {
        const t = performance.now();
        const a = 0.6 * Math.sin(0.37 * (k++));
        const l = [light[0] * Math.cos(a) + light[2] * Math.sin(a), light[1], -light[0] * Math.sin(a) + light[2] * Math.cos(a)];
        const m = Math.hypot(...l);
        gl.uniform3f(u('L'), l[0] / m, l[1] / m, l[2] / m);
        gl.clearColor(0, 0, 0, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
        gl.drawElements(gl.TRIANGLES, faces.length, gl.UNSIGNED_INT, 0);
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
        ts.push(performance.now() - t);
      }
      return ts;
    },
    read() { const a = new Uint8Array(W * H * 4); gl.readPixels(0, 0, W, H, gl.RGBA, gl.UNSIGNED_BYTE, a);
             let cov = 0; for (let i = 0; i < a.length; i += 4) cov += (a[i] + a[i + 1] + a[i + 2]) > 0; return cov; },
  };
  return faces.length / 3;
};
</script></body></html>"""

FACE = "document.querySelector('#view-body canvas.face-gl').gkFace"

# n drags along an arc, each: the server's frame, the upload, the draw, then a 1-pixel sync
DRAG = """async ([n, d0]) => {
  const f = %s;
  const ts = [];
  for (let i = 0; i < n; i++) {
    const a = 0.5 * Math.sin(0.29 * i + d0);
    const d = [Math.sin(a), -0.2, -Math.cos(a)];
    const t = performance.now();
    await f.setLight({direction: d});
    f.sync();
    ts.push(performance.now() - t);
  }
  return ts;
}""" % FACE


def stats(xs):
    return statistics.median(xs), min(xs)


FACE_SCENE = """graphkit: 1
name: face_webgl_bench
nodes:
  scene: {type: FaceScene, params: {size: 512}}
  key: {type: MakeLight, params: {azimuth_deg: 20.0, elevation_deg: 10.0}}
  left60:
    type: Render
    inputs: {mesh: scene.mesh, camera: scene.camera, material: scene.material, lights: [key.light],
             detail: scene.detail, texture_camera: scene.camera}
    params: {shadow_map_size: 512}
  save: {type: SaveImage, inputs: {image: left60.image}, params: {path: r.exr}}
"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=30, help="frames per round")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--scene", action="store_true", help="the FaceScene test node instead of face_relight")
    ap.add_argument("--cache", default=os.environ.get("GRAPHKIT_CACHE", str(ROOT / ".graphkit-cache")))
    a = ap.parse_args()
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        tmp = Path(tmp)
        g = tmp / "g.yaml"
        if a.scene:
            g.write_text(FACE_SCENE.replace("size: 512", f"size: {a.size}"))
            s = Server(g, tmp, cache=a.cache)
        else:
            text = (ROOT / "graphs" / "face_relight.yaml").read_text()
            g.write_text(text.replace("  size: null ", f"  size: {a.size} "))
            s = Server(g, tmp, plugins="", cache=a.cache)
        b, ctx = browser_page(pw, webgl=True)
        errors = []
        try:
            page = ctx.new_page()
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.goto(s.url)
            page.wait_for_selector("#dag g.node")
            wait_run(page, timeout=3600)
            page.click('#dag g.node[data-node="left60"]')
            page.wait_for_selector("#view-body canvas.face-gl", timeout=120_000)
            wait_for(lambda: page.evaluate(f"() => !!{FACE}"), 60, "the WebGL face view")
            d = s.api("/api/view/left60")["data"]
            ntri = len(base64.b64decode(d["faces"]["b64"])) // 12
            peer = ctx.new_page()
            peer.set_content(PEER_HTML)
            # the same vertices in the camera frame (positions as drawn, normals turned), light too
            va = np.frombuffer(base64.b64decode(d["vertices"]["b64"]), np.float32).reshape(-1, 9)
            R = np.asarray(d["cam_rotation"], np.float64).reshape(3, 3)  # row-major world → camera
            vb = np.hstack([va[:, :3], va[:, 6:9] @ R.T.astype(np.float32)]).astype(np.float32)
            lc = R @ np.asarray(d["light"]["direction"], np.float64)
            vs, fs = phong_peer("es300")
            peer.evaluate("a => makePeer(...a)", [d["W"], d["H"], base64.b64encode(vb.tobytes()).decode(),
                                                  d["faces"]["b64"], d["clip"], d["kd"], d["i_s"], d["shininess"],
                                                  list(lc / np.linalg.norm(lc)), vs, fs])
            peer.evaluate("() => peer.time(1)")
            cov = peer.evaluate("() => peer.read()")
            print(f"face view {d['W']}x{d['H']}, {ntri} triangles, shadows {'on' if d.get('shadow') else 'off'}"
                  f" ({d.get('shadow_map_size', 0)}²), detail {'on' if d.get('detail') else 'off'},"
                  f" eyes {'on' if d.get('eyes') else 'off'}; peer covers {cov} pixels")
            print("    face view passes, median ms (each synced):", page.evaluate(f"() => {FACE}.profile(5)"))
            face_t, peer_t, ratios, drag_t = [], [], [], []
            page.evaluate(f"() => {FACE}.time(5)")  # warm-up
            peer.evaluate("() => peer.time(5)")
            page.evaluate(DRAG, [5, 0.0])
            for r in range(a.rounds):
                ft = page.evaluate(f"([n, r]) => {FACE}.time(n, r)", [a.n, float(r)])
                pt = peer.evaluate("n => peer.time(n)", a.n)
                dt = page.evaluate(DRAG, [a.n, float(r)])
                face_t += ft
                peer_t += pt
                drag_t += dt
                ratios.append(statistics.median(ft) / statistics.median(pt))
                print(f"  round {r}: face {statistics.median(ft):6.2f} ms, peer {statistics.median(pt):6.2f} ms,"
                      f" ratio {ratios[-1]:4.2f}; drag {statistics.median(dt):6.2f} ms"
                      f" ({1e3 / statistics.median(dt):4.1f} fps)", flush=True)
            fm, fb = stats(face_t)
            pm, pb = stats(peer_t)
            dm, db = stats(drag_t)
            print(f"(b) face view frame (light changed, read-back sync): median {fm:.2f} ms, best {fb:.2f} ms; "
                  f"peer one-light Phong: median {pm:.2f} ms, best {pb:.2f} ms")
            print(f"    ratio face/peer (per round): median {statistics.median(ratios):.2f}x, best {min(ratios):.2f}x"
                  f" (goal <= 2x); over all frames: median {fm / pm:.2f}x, best {fb / pb:.2f}x")
            print(f"    drag (light frame + upload + draw + sync): median {dm:.2f} ms = {1e3 / dm:.1f} fps, "
                  f"best {db:.2f} ms = {1e3 / db:.1f} fps (goal >= 30 fps)")
            if errors:
                print("browser errors:", errors[:5])
        finally:
            ctx.close()
            b.close()
            s.stop()


if __name__ == "__main__":
    main()
