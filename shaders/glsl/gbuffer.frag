#version 330
// Surface pass of Render's GL pipeline: what does not depend on the lights, per pixel of the
// nearest surface (after a depth pre-pass), once per mesh, camera and detail texture:
// the world position, the smooth normal turned towards the viewer (two-sided lighting, as
// nodes/paris/render.surface) and the projective detail texture factor
// (render.projective_texture: points outside the photo or hidden from its camera get 1;
// bilinear lookup, edge-clamped).  shade.frag lights it.
// Defines: ORTHO (the camera is orthographic: the view vector is cam_back everywhere),
// DETAIL (a detail texture is bound).
#ifndef ORTHO
#define ORTHO 0
#endif
#ifndef DETAIL
#define DETAIL 0
#endif
in vec3 vP;
in vec3 vN;
in float vz;
layout(location = 0) out vec4 o_pos;      // xyz = world position, w = camera z (> 0)
layout(location = 1) out vec4 o_normal;   // xyz = unit normal towards the viewer, w = 1 (covered)
layout(location = 2) out vec4 o_detail;   // rgb = detail texture factor

uniform vec3 cam_pos;                     // camera centre (world)
uniform vec3 cam_back;                    // −(camera +z) in world (ORTHO)
#if DETAIL
uniform sampler2D detail;                 // RGB32F, texel (x, y) = detail.pixels[y, x]
uniform sampler2D tex_depth;              // texture camera: r = depth, g = 1 where covered
uniform mat4 tex_proj;                    // world → (u·w, v·w, w, camera z) of the texture camera
uniform ivec2 tex_size;                   // W, H
uniform float occl_tol;                   // 0.02 × mesh scale

vec3 fetch(int x, int y) { return texelFetch(detail, ivec2(x, y), 0).rgb; }

vec3 detail_factor(vec3 P) {
    vec4 h = tex_proj * vec4(P, 1.0);
    float z = h.w;
    float x = h.x / h.z;
    float y = h.y / h.z;
    float W = float(tex_size.x), H = float(tex_size.y);
    if (!(z > 0.0 && x >= 0.0 && x < W && y >= 0.0 && y < H)) return vec3(1.0);
    int ix = clamp(int(x), 0, tex_size.x - 1);
    int iy = clamp(int(y), 0, tex_size.y - 1);
    vec4 dz = texelFetch(tex_depth, ivec2(ix, iy), 0);
    if (!(dz.g > 0.5 && z <= dz.r + occl_tol)) return vec3(1.0);
    float fx = clamp(x - 0.5, 0.0, W - 1.0);
    float fy = clamp(y - 0.5, 0.0, H - 1.0);
    int x0 = int(floor(fx)), y0 = int(floor(fy));
    int x1 = min(x0 + 1, tex_size.x - 1), y1 = min(y0 + 1, tex_size.y - 1);
    float tx = fx - float(x0), ty = fy - float(y0);
    return fetch(x0, y0) * (1.0 - tx) * (1.0 - ty) + fetch(x1, y0) * tx * (1.0 - ty)
         + fetch(x0, y1) * (1.0 - tx) * ty + fetch(x1, y1) * tx * ty;
}
#endif

void main() {
    float nn = length(vN);
    vec3 n = nn > 0.0 ? vN / nn : vec3(0.0);
#if ORTHO
    vec3 v = cam_back;
#else
    vec3 v = cam_pos - vP;
    float vl = length(v);
    v = vl > 0.0 ? v / vl : vec3(0.0);
#endif
    if (dot(n, v) < 0.0) n = -n;
    o_pos = vec4(vP, vz);
    o_normal = vec4(n, 1.0);
#if DETAIL
    o_detail = vec4(detail_factor(vP), 1.0);
#else
    o_detail = vec4(1.0);
#endif
}
