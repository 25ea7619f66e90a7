#version 330
// Surface pass of Render's GL pipeline: what does not depend on the lights, per pixel of the
// nearest surface (after a depth pre-pass), once per mesh, camera and detail texture:
// the world position, the smooth normal turned towards the viewer (two-sided lighting, as
// nodes/paris/render.surface) and the projective detail texture factor
// (render.projective_texture: points outside the photo or hidden from its camera get 1;
// bilinear lookup, edge-clamped).  shade.frag lights it.
// Defines: ORTHO (the camera is orthographic: the view vector is cam_back everywhere),
// DETAIL (a detail texture is bound), EXACT (the surface point is the pixel ray's hit on the
// exact triangle, not GL's interpolation: GL rasterisers snap vertices to a sub-pixel grid —
// SwiftShader, WebGL's CPU renderer, to 1/16 px, which moves interpolated world positions by
// ~3e-4 of the face's size here and the projective detail lookup by up to 0.03 texel, ~6 % of
// the values outside the opengl tolerance; the reference rasteriser's barycentrics are exact.
// llvmpipe snaps to 1/256 px and needs no EXACT.)
#ifndef ORTHO
#define ORTHO 0
#endif
#ifndef DETAIL
#define DETAIL 0
#endif
#ifndef EXACT
#define EXACT 0
#endif
in vec3 vP;
in vec3 vN;
in float vz;
layout(location = 0) out vec4 o_pos;      // xyz = world position, w = camera z (> 0)
layout(location = 1) out vec4 o_normal;   // xyz = unit normal towards the viewer, w = 1 (covered)
layout(location = 2) out vec4 o_detail;   // rgb = detail texture factor

uniform vec3 cam_pos;                     // camera centre (world)
uniform vec3 cam_back;                    // −(camera +z) in world (ORTHO)
#if EXACT
flat in vec3 tA0;                         // gbuffer.vert: the triangle's world vertices
flat in vec3 tA1;
flat in vec3 tA2;
flat in vec3 tB0;                         // and normals
flat in vec3 tB1;
flat in vec3 tB2;
uniform mat3 ray_org;                     // pixel (x+.5, y+.5, 1) → world ray origin
uniform mat3 ray_dir;                     // pixel (x+.5, y+.5, 1) → world ray direction

// Barycentrics of the pixel centre's ray on the triangle (Möller–Trumbore); false where the
// ray grazes the triangle or the centre lies well outside it (then GL's interpolation is used).
bool exact_bary(out vec3 b) {
    vec3 pix = vec3(gl_FragCoord.xy, 1.0);
    vec3 ro = ray_org * pix;
    vec3 rd = ray_dir * pix;
    vec3 e1 = tA1 - tA0;
    vec3 e2 = tA2 - tA0;
    vec3 pv = cross(rd, e2);
    float det = dot(e1, pv);
    if (!(abs(det) > 1e-6 * length(e1) * length(e2) * length(rd))) return false;
    vec3 tv = ro - tA0;
    float u = dot(tv, pv) / det;
    float v = dot(rd, cross(tv, e1)) / det;
    b = vec3(1.0 - u - v, u, v);
    return all(greaterThan(b, vec3(-0.25)));
}
#endif
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
    vec3 Pw = vP;
    vec3 Nw = vN;
    float zc = vz;
#if EXACT
    vec3 b;
    if (exact_bary(b)) {
        Pw = b.x * tA0 + b.y * tA1 + b.z * tA2;
        Nw = b.x * tB0 + b.y * tB1 + b.z * tB2;
        zc = dot(cam_pos - Pw, cam_back);     // camera z: (P − C)·forward
    }
#endif
    float nn = length(Nw);
    vec3 n = nn > 0.0 ? Nw / nn : vec3(0.0);
#if ORTHO
    vec3 v = cam_back;
#else
    vec3 v = cam_pos - Pw;
    float vl = length(v);
    v = vl > 0.0 ? v / vl : vec3(0.0);
#endif
    if (dot(n, v) < 0.0) n = -n;
    o_pos = vec4(Pw, zc);
    o_normal = vec4(n, 1.0);
#if DETAIL
    o_detail = vec4(detail_factor(Pw), 1.0);
#else
    o_detail = vec4(1.0);
#endif
}
