"""The one-light Phong peer of the render benchmarks (bench_render.py, bench_render_gl_peer.py,
bench_studio_webgl.py): a bare vertex + fragment shader pair that draws a mesh given in the
camera frame with one directional light (camera frame), two-sided, Phong lobes as
nodes/paris/phong.py — what a hand-written viewer would draw, with no shadows, texture or eyes.
``phong_peer("330")`` for moderngl, ``phong_peer("es300")`` for WebGL2 (same text)."""
from __future__ import annotations

_VERT = """
uniform mat4 P; in vec3 pos; in vec3 nrm; out vec3 n; out vec3 p;
void main() { p = pos; n = nrm; gl_Position = P * vec4(pos, 1.0); }"""

_FRAG = """
in vec3 n; in vec3 p; out vec4 c;
uniform vec3 L; uniform vec3 kd; uniform float ks; uniform float s;
void main() {
    vec3 N = normalize(n); vec3 V = normalize(-p);
    if (dot(N, V) < 0.0) N = -N;
    float d = max(dot(N, L), 0.0);
    vec3 R = 2.0 * dot(N, L) * N - L;
    float sp = d > 0.0 ? pow(max(dot(R, V), 0.0), s) : 0.0;
    c = vec4(kd * d + ks * sp, 1.0);
}"""

_HEAD = {"330": "#version 330\n", "es300": "#version 300 es\nprecision highp float;\n"}


def phong_peer(target: str = "330") -> tuple[str, str]:
    """(vertex shader, fragment shader) of the peer for GLSL 3.30 or GLSL ES 3.00."""
    return _HEAD[target] + _VERT, _HEAD[target] + _FRAG
