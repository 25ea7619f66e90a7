#version 330
// Render/opengl fragment shader: the numpy reference (nodes/paris/render.py, Render.compute)
// per covered pixel: two-sided smooth normal, Phong per light (nodes/paris/phong.py lobes/shade;
// point lights always fall off as 1/d², positions and intensities in world units),
// shadow-map visibility (nodes/common/raster.py ShadowMap.visibility: slope bias, 3×3 PCF),
// ambient, projective detail texture (render.projective_texture: occlusion + bilinear).
// Cameras are perspective or orthographic (graphkit.Camera): the view vector runs towards the
// camera centre, or along the camera's −z (cam_back) everywhere.
#define MAX_LIGHTS 32
in vec3 vP;
in vec3 vN;
in float vz;
layout(location = 0) out vec4 o_color;  // rgb = shaded colour (before exposure), a = coverage
layout(location = 1) out vec4 o_aux;    // r = camera z, g/b = bit mask of lights with n·l > 0

uniform vec3 cam_pos;                     // camera centre (world)
uniform bool cam_ortho;                   // orthographic camera: the view vector is cam_back
uniform vec3 cam_back;                    // −(camera +z) in world
uniform int n_lights;
uniform int light_kind[MAX_LIGHTS];       // 0 directional, 1 point
uniform vec3 light_dir[MAX_LIGHTS];       // unit, towards the light
uniform vec3 light_pos[MAX_LIGHTS];
uniform vec3 light_rgb[MAX_LIGHTS];       // colour × intensity (point: radiant intensity)
uniform vec3 kd;
uniform float i_s;
uniform float shininess;
uniform vec3 ambient;                     // sum of ambient terms (host)

uniform bool shadows;
uniform sampler2DArray shadow_maps;       // layer i: light i's depth (1e30 where empty)
uniform int sm_size;
uniform mat4 sm_to_light[MAX_LIGHTS];     // world → light view
uniform vec4 sm_proj[MAX_LIGHTS];         // (sx, sy, ox, oy)
uniform vec2 sm_bias[MAX_LIGHTS];         // (texel, reference distance)

uniform bool has_detail;
uniform sampler2D detail;                 // RGB32F, texel (x, y) = detail.pixels[y, x]
uniform sampler2D tex_depth;              // texture camera depth (r) and coverage (g)
uniform mat4 tex_proj;                    // world → (u·w, v·w, w, camera z) of the texture camera
uniform ivec2 tex_size;                   // W, H
uniform float occl_tol;                   // 0.02 × mesh scale

float visibility(int i, vec3 P, vec3 n, vec3 ldir) {
    vec4 q = sm_to_light[i] * vec4(P, 1.0);
    vec2 xy;
    if (light_kind[i] == 0) xy = q.xy * sm_proj[i].xy + sm_proj[i].zw;
    else xy = q.xy / q.z * sm_proj[i].xy + sm_proj[i].zw;
    float cosv = clamp(abs(dot(n, ldir)), 0.05, 1.0);
    float b = 1.5 * sm_bias[i].x * min(sqrt(1.0 - cosv * cosv) / cosv + 1.0, 10.0);
    if (light_kind[i] == 1) b = b * max(q.z, 1e-9) / sm_bias[i].y;
    float db = q.z - b;
    int ix = int(clamp(floor(xy.x), -1.0, float(sm_size)));
    int iy = int(clamp(floor(xy.y), -1.0, float(sm_size)));
    float acc = 0.0;
    for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
            int x = ix + dx, y = iy + dy;
            float d = 3.0e38;
            if (x >= 0 && y >= 0 && x < sm_size && y < sm_size)
                d = texelFetch(shadow_maps, ivec3(x, y, i), 0).r;
            acc += (db <= d) ? 1.0 : 0.0;
        }
    return acc / 9.0;
}

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

void main() {
    vec3 P = vP;
    vec3 n = vN;
    float nn = length(n);
    n = nn > 0.0 ? n / nn : vec3(0.0);
    vec3 v = cam_back;
    if (!cam_ortho) {
        v = cam_pos - P;
        float vl = length(v);
        v = vl > 0.0 ? v / vl : vec3(0.0);
    }
    if (dot(n, v) < 0.0) n = -n;
    vec3 col = vec3(0.0);
    float mask0 = 0.0, mask1 = 0.0;
    for (int i = 0; i < n_lights; ++i) {
        vec3 l;
        vec3 L = light_rgb[i];
        if (light_kind[i] == 0) {
            l = light_dir[i];
        } else {
            vec3 d = light_pos[i] - P;
            float dist = length(d);
            l = dist > 0.0 ? d / dist : vec3(0.0);
            L = L / max(dot(d, d), 1e-24);
        }
        float nl = dot(n, l);
        vec3 r = 2.0 * nl * n - l;
        float rv = max(dot(r, v), 0.0);
        float diff = nl > 0.0 ? nl : 0.0;
        float spec = (nl > 0.0 && rv > 0.0) ? pow(rv, shininess) : 0.0;
        if (nl > 0.0) {
            if (i < 24) mask0 += exp2(float(i));
            else mask1 += exp2(float(i - 24));
        }
        if (shadows) {
            float vis = visibility(i, P, n, l);
            diff *= vis;
            spec *= vis;
        }
        col += kd * (L * diff) + i_s * L * spec;
    }
    col += kd * ambient;
    if (has_detail) col *= detail_factor(P);
    o_color = vec4(col, 1.0);
    o_aux = vec4(vz, mask0, mask1, 0.0);
}
