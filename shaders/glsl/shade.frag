#version 330
// Lighting pass of Render's GL pipeline (Paris 2003 §5; nodes/paris/render.py, Render.compute),
// a full-screen pass over the surface pass's buffers (gbuffer.frag), per pixel:
// * covered: Phong per light, kd·(L (n·l)) + i_s·L·(r·v)^s (phong.lobes/shade; point lights
//   1/d²), times the shadow-map visibility (raster.ShadowMap.visibility: slope-scaled bias,
//   3×3 PCF), plus kd × the ambient sum (ENV_SH: + an environment's SH irradiance at n), all
//   times the detail texture factor;
// * else the background;
// * then the eye highlights (Render._eyes: two specular cornea hemispheres hit by the pixel's
//   ray, graphkit.Camera.ray_matrices, where they are not behind the eyelids), the exposure
//   and the clamp to [0, 1] (§5: over-exposure, after the texture).
// Outputs: o_image.rgb = the image; o_image.a = the camera z where a surface is (0 elsewhere),
// negated where no light has n·l > 0 (one light; LIT_MASKS: per-light masks in o_lit), so that
// one RGBA read-back gives image, depth, coverage and the "light lights nothing" check.
// Defines: N_LIGHTS, DIRECTIONAL (lights.glsl), ORTHO, SHADOWS, EYES, LIT_MASKS, SM_WINDOW, SM_BILINEAR, DISPLAY,
// DETAIL, ALPHA_OUT, VIEW_RAY, NO_DEPTH, ENV_SH.  The drivers draw it scissored to the
// pixels a surface or an eye can cover (nodes/paris/glscene.screen_box), without EYES over the
// mesh's box and with EYES over the eyes' box, on a target cleared to the background output.
#include "lights.glsl"
#ifndef ORTHO
#define ORTHO 0
#endif
#ifndef SHADOWS
#define SHADOWS 0
#endif
#ifndef EYES
#define EYES 0
#endif
#ifndef LIT_MASKS
#define LIT_MASKS 0
#endif
#ifndef DISPLAY
#define DISPLAY 0
#endif
#ifndef DETAIL
#define DETAIL 1                          // 0: no detail texture (g_detail is 1: not fetched)
#endif
#if DISPLAY
// The studio's frames: the image straight onto the canvas as display.frag would show it
// (× 2^exposure, clip, sRGB; image row 0 at the top: canvas row y is image row view_h − 1 − y),
// in the same pass (no float target written and read again).
#include "srgb.glsl"
uniform float display_scale;              // 2^exposure of the view
uniform int view_h;                       // H
#endif
layout(location = 0) out vec4 o_image;    // rgb = image, a = ±camera z (covered), 0 (uncovered)
#if LIT_MASKS
layout(location = 1) out vec4 o_lit;      // r, g = bit masks (lights 0–23, 24–) with n·l > 0 here
#endif
#ifndef ALPHA_OUT
#define ALPHA_OUT 0
#endif
// VIEW_RAY (not ORTHO): the view vector from screen.vert's pixel ray, not from P;
// NO_DEPTH: no g_pos fetch where P is not needed (DIRECTIONAL, VIEW_RAY, no SHADOWS, no EYES);
// the alpha is then ±1 where covered, not ±z (the driver keeps depth from an earlier call)
#ifndef VIEW_RAY
#define VIEW_RAY 0
#endif
#ifndef NO_DEPTH
#define NO_DEPTH 0
#endif
#if VIEW_RAY
in vec3 v_ray;
#endif
#if ALPHA_OUT
layout(location = ALPHA_OUT) out float o_alpha;  // o_image.a also at this location (own target)
#endif

uniform sampler2D g_pos;                  // gbuffer.frag's outputs
uniform sampler2D g_normal;
uniform sampler2D g_detail;
uniform vec3 cam_pos;                     // camera centre (world)
uniform vec3 cam_back;                    // −(camera +z) in world
uniform vec3 kd;
uniform float i_s;
uniform float shininess;
uniform vec3 ambient;                     // Σ ambient terms × the material's ambient scale (host)
uniform vec3 background;
uniform float exposure;
uniform bool clamp01;

#ifndef ENV_SH
#define ENV_SH 0
#endif
#if ENV_SH
// An environment's unshadowed ambient (nodes/paris/environment.py sh_irradiance, Ramamoorthi–
// Hanrahan): Σ_k env_sh[k] × the k-th real SH polynomial of the normal (sh_basis's order and
// polynomials; its constants SH_K, Â_l and 1/π are in the weights: sh_irradiance_weights).
uniform vec3 env_sh[9];

vec3 env_irradiance(vec3 n) {
    return env_sh[0] + env_sh[1] * n.y + env_sh[2] * n.z + env_sh[3] * n.x
         + env_sh[4] * (n.x * n.y) + env_sh[5] * (n.y * n.z) + env_sh[6] * (3.0 * n.z * n.z - 1.0)
         + env_sh[7] * (n.x * n.z) + env_sh[8] * (n.x * n.x - n.y * n.y);
}
#endif

#ifndef SM_WINDOW
#define SM_WINDOW 0
#endif
#if SHADOWS
// All lights' shadow maps in one R32F atlas: light i's SM_SIZE(i)² map starts at texel sm_tile[i]
// (an environment's dimmer lights have smaller maps, environment.shadow_map_sizes);
// values are light-frame depths (1e30 where nothing is in the way).  SM_WINDOW (the studio's
// depth-only shadow pass, depth.vert WORLD): a depth texture of window depths in [0, 1] (1
// where nothing is in the way), compared with the biased light-frame depth db mapped the same
// way, zw = a + b·db + c/db (sm_zmap[i] = (a, b, c), from the light's clip matrix: b = 0 for
// a point light, c = 0 for a directional one) — an increasing map, so the test is the same.
#ifndef SM_BILINEAR
#define SM_BILINEAR 0
#endif
// SM_BILINEAR (with SM_WINDOW): the same 3×3 PCF in 4 compare samples instead of 9 fetches. The
// atlas is bound with depth comparison (LEQUAL) and linear filtering, so one sample is the
// bilinear mix of its 2×2 texels' tests; a sample at a texel corner weighs each of its 4 texels
// 1/4, one at a texel centre (in x or y) weighs that texel's row or column alone: the 3×3 box
// sum is 4·(2×2) + 2·(1×2) + 2·(2×1) + (1×1), exactly the 9 taps' count when the coordinates
// are exact (integers, and half-integers for centres, times sm_texel = 1 / the atlas size, a
// power of two: studio_view.js shadowAtlas) and so the weights are exactly 0, 1/2 or 1.
#if SM_WINDOW && SM_BILINEAR
uniform sampler2DShadow shadow_maps;
uniform vec2 sm_texel;                    // 1 / the atlas's width and height (powers of two)
#else
uniform sampler2D shadow_maps;
#endif
#if SM_WINDOW
uniform vec3 sm_zmap[N_LIGHTS];
#endif
#if SM_WINDOW
uniform int sm_size;                      // (the studio: every light's map this size)
#define SM_SIZE(i) sm_size
#else
uniform int sm_size[N_LIGHTS];
#define SM_SIZE(i) sm_size[i]
#endif
uniform ivec2 sm_tile[N_LIGHTS];
uniform mat4 sm_to_light[N_LIGHTS];       // world → light frame
uniform vec4 sm_proj[N_LIGHTS];           // (sx, sy, ox, oy)
uniform vec2 sm_bias[N_LIGHTS];           // (texel, reference distance)

float visibility(int i, vec3 P, vec3 n, vec3 ldir) {
    vec4 q = sm_to_light[i] * vec4(P, 1.0);
    vec2 xy;
    if (LIGHT_IS_DIRECTIONAL(i)) xy = q.xy * sm_proj[i].xy + sm_proj[i].zw;
    else xy = q.xy / q.z * sm_proj[i].xy + sm_proj[i].zw;
    float cosv = clamp(abs(dot(n, ldir)), 0.05, 1.0);
    float b = 1.5 * sm_bias[i].x * min(sqrt(1.0 - cosv * cosv) / cosv + 1.0, 10.0);
    if (!LIGHT_IS_DIRECTIONAL(i)) b = b * max(q.z, 1e-9) / sm_bias[i].y;
    float db = q.z - b;
#if SM_WINDOW
    vec3 zm = sm_zmap[i];
    // a point light's db ≤ 0 is nearer than any surface: lit (as the light-frame test); at
    // most 1 (farther than the depth range: lit over an empty texel, as the reference's inf)
#if DIRECTIONAL
    db = min(zm.x + zm.y * db, 1.0);          // zm.z = 0
#else
    db = min((zm.z != 0.0 && db <= 0.0) ? -1.0 : zm.x + zm.y * db + (zm.z != 0.0 ? zm.z / db : 0.0), 1.0);
#endif
#endif
    vec2 fxy = clamp(floor(xy), -1.0, float(SM_SIZE(i)));
#if SM_WINDOW && SM_BILINEAR
    // texel (x, y) spans [x, x + 1) × [y, y + 1); the taps are the texels base + (−1…1)², base
    // as below: the corner c = base is between the 2×2 taps dx, dy ∈ {−1, 0}, c + 1.5 the centre
    // of dx (dy) = 1
    vec2 c = vec2(sm_tile[i] + 2) + fxy;
    float acc = 4.0 * texture(shadow_maps, vec3(c * sm_texel, db))
              + 2.0 * texture(shadow_maps, vec3(vec2(c.x + 1.5, c.y) * sm_texel, db))
              + 2.0 * texture(shadow_maps, vec3(vec2(c.x, c.y + 1.5) * sm_texel, db))
              + texture(shadow_maps, vec3((c + 1.5) * sm_texel, db));
#else
    int ix = int(fxy.x);
    int iy = int(fxy.y);
    float acc = 0.0;
    ivec2 tile = sm_tile[i];
    // the 3×3 taps written out (no loop: SwiftShader runs loops lane-masked), rows dy = −1, 0,
    // 1, each dx = −1, 0, 1 (the reference's order); outside the map: lit (as the reference);
    // clamped fetch + select, no branch
#if SM_WINDOW
    // each tile has a border of 2 texels of 1.0 (studio_view.js shadowAtlas), ≥ db: a tap
    // outside the map reads it and is lit, as below, with no clamp
    ivec2 base = tile + 2 + ivec2(ix, iy);
#define SM_TAP(DX, DY) acc += (db <= texelFetch(shadow_maps, base + ivec2(DX, DY), 0).r) ? 1.0 : 0.0;
#else
#define SM_TAP(DX, DY) { \
        ivec2 at = ivec2(ix + DX, iy + DY); \
        ivec2 c = clamp(at, ivec2(0), ivec2(SM_SIZE(i) - 1)); \
        acc += (at != c || db <= texelFetch(shadow_maps, tile + c, 0).r) ? 1.0 : 0.0; }
#endif
    SM_TAP(-1, -1) SM_TAP(0, -1) SM_TAP(1, -1)
    SM_TAP(-1, 0)  SM_TAP(0, 0)  SM_TAP(1, 0)
    SM_TAP(-1, 1)  SM_TAP(0, 1)  SM_TAP(1, 1)
#undef SM_TAP
#endif
    return acc / 9.0;
}
#endif

#if EYES
uniform mat3 ray_org;                     // pixel (x+.5, y+.5, 1) → world ray origin
uniform mat3 ray_dir;                     // pixel (x+.5, y+.5, 1) → world ray direction
uniform vec3 fwd;                         // camera +z in world
uniform vec3 eye_c[2];                    // cornea sphere centres (world)
uniform vec3 eye_axis[2];                 // their outward axes
uniform float eye_R;
uniform float eye_s;
uniform float eye_ks;

// Ray–sphere in a cancellation-free form (h = oc − (d·oc) d): cornea k's highlight on the ray
// (ro, d), added to acc.
void eye_highlight(int k, vec3 ro, vec3 d, float depth, inout vec3 acc) {
    vec3 oc = ro - eye_c[k];
    float bq = dot(d, oc);
    vec3 h = oc - bq * d;
    float disc = eye_R * eye_R - dot(h, h);
    if (!(disc > 0.0)) return;
    float sq = sqrt(disc);
    float t = -bq - sq;
    vec3 XC = h - sq * d;                     // X − c
    if (!(t > 0.0) || dot(XC, eye_axis[k]) < 0.0) return;
    float zc = dot(ro - cam_pos, fwd) + t * dot(d, fwd);
    if (!(zc <= depth + eye_R * 0.35)) return;
    vec3 n = XC / eye_R;
    vec3 X = eye_c[k] + XC;
#if N_LIGHTS == 1
    {
        const int i = 0;
#else
    for (int i = 0; i < N_LIGHTS; ++i) {
#endif
        vec3 L;
        vec3 l = towards_light(i, X, L);
        acc += eye_ks * L * phong_spec(n, l, -d, eye_s);
    }
}

vec3 eye_highlights(ivec2 px, float depth) {
    vec3 pix = vec3(vec2(px) + 0.5, 1.0);     // the pixel centre
    vec3 ro = ray_org * pix;
    vec3 d = normalize(ray_dir * pix);
    vec3 acc = vec3(0.0);
    // the two eyes written out (a loop over them costs more: SwiftShader runs it lane-masked)
    eye_highlight(0, ro, d, depth, acc);
    eye_highlight(1, ro, d, depth, acc);
    return acc;
}
#endif

void main() {
#if DISPLAY
    ivec2 px = ivec2(int(gl_FragCoord.x), view_h - 1 - int(gl_FragCoord.y));
#else
    ivec2 px = ivec2(gl_FragCoord.xy);
#endif
#if NO_DEPTH
    vec4 gp = vec4(0.0, 0.0, 0.0, 1.0);
#else
    vec4 gp = texelFetch(g_pos, px, 0);
#endif
    vec4 gn = texelFetch(g_normal, px, 0);
    bool cov = gn.w > 0.5;
    vec3 img = background;
    float mask0 = 0.0, mask1 = 0.0;           // LIT_MASKS
    bool any_lit = false;
    if (cov) {
        vec3 P = gp.xyz;
        vec3 n = gn.xyz;
#if ORTHO
        vec3 v = cam_back;
#else
#if VIEW_RAY
        vec3 v = v_ray;
#else
        vec3 v = cam_pos - P;
#endif
        float vl = length(v);
        v = vl > 0.0 ? v / vl : vec3(0.0);
#endif
        vec3 col = vec3(0.0);
#if N_LIGHTS == 1
        {                                     // no loop: a constant index into the light
            const int i = 0;                  // arrays (SwiftShader runs loops lane-masked)
#else
        for (int i = 0; i < N_LIGHTS; ++i) {
#endif
            vec3 L;
            vec3 l = towards_light(i, P, L);
            float nl = dot(n, l);
            float diff = nl > 0.0 ? nl : 0.0;
            float spec = phong_spec(n, l, v, shininess);
            any_lit = any_lit || nl > 0.0;
#if LIT_MASKS
            if (nl > 0.0) {
                if (i < 24) mask0 += exp2(float(i));
                else mask1 += exp2(float(i - 24));
            }
#endif
#if SHADOWS
            if (nl > 0.0 && SM_SIZE(i) > 0) { // else diff = spec = 0, or no shadow (side 0)
                float vis = visibility(i, P, n, l);
                diff *= vis;
                spec *= vis;
            }
#endif
            col += kd * (L * diff) + i_s * L * spec;
        }
#if ENV_SH
        col += kd * (ambient + env_irradiance(n));
#else
        col += kd * ambient;
#endif
#if DETAIL
        img = col * texelFetch(g_detail, px, 0).rgb;
#else
        img = col;
#endif
    }
#if EYES
    img += eye_highlights(px, cov ? gp.w : 3.0e38);
#endif
    img *= exposure;
    if (clamp01) img = clamp(img, 0.0, 1.0);
#if DISPLAY
    o_image = vec4(srgb_encode(img * display_scale), 1.0);
#else
    o_image = vec4(img, cov ? (any_lit ? gp.w : -gp.w) : 0.0);
#if ALPHA_OUT
    o_alpha = o_image.a;
#endif
#endif
#if LIT_MASKS
    o_lit = vec4(mask0, mask1, 0.0, 0.0);
#endif
}
