#version 330
// Render/opengl composite pass: background where uncovered, the eye highlights of Paris 2003
// §5 (Render._eyes: two specular cornea hemispheres hit by the pixel-centre rays of a
// perspective or orthographic camera, graphkit.Camera.ray_matrices), exposure, then the clamp
// to [0, 1].  Ray-sphere maths in a cancellation-free form (h = oc − (d·oc) d).
#define MAX_LIGHTS 32
out vec4 o;
uniform sampler2D color;                  // main pass: rgb, a = coverage
uniform sampler2D aux;                    // main pass: r = camera z
uniform vec3 background;
uniform float exposure;
uniform bool clamp01;

uniform bool eyes;
uniform mat3 ray_org;                     // pixel (x+.5, y+.5, 1) → world ray origin
uniform mat3 ray_dir;                     // pixel (x+.5, y+.5, 1) → world ray direction
uniform vec3 cam_pos;                     // camera centre (world)
uniform vec3 fwd;                         // camera +z in world
uniform vec3 eye_c[2];                    // sphere centres (world)
uniform vec3 eye_axis[2];
uniform float eye_R;
uniform float eye_s;
uniform float eye_ks;
uniform int n_lights;
uniform int light_kind[MAX_LIGHTS];
uniform vec3 light_dir[MAX_LIGHTS];
uniform vec3 light_pos[MAX_LIGHTS];
uniform vec3 light_rgb[MAX_LIGHTS];

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 c = texelFetch(color, px, 0);
    bool cov = c.a > 0.5;
    vec3 img = cov ? c.rgb : background;
    if (eyes) {
        vec3 pix = vec3(gl_FragCoord.xy, 1.0);
        vec3 ro = ray_org * pix;
        vec3 d = normalize(ray_dir * pix);
        float depth = cov ? texelFetch(aux, px, 0).r : 3.0e38;
        for (int k = 0; k < 2; ++k) {
            vec3 oc = ro - eye_c[k];
            float bq = dot(d, oc);
            vec3 h = oc - bq * d;
            float disc = eye_R * eye_R - dot(h, h);
            if (!(disc > 0.0)) continue;
            float sq = sqrt(disc);
            float t = -bq - sq;
            vec3 XC = h - sq * d;                 // X − c
            if (!(t > 0.0) || dot(XC, eye_axis[k]) < 0.0) continue;
            float zc = dot(ro - cam_pos, fwd) + t * dot(d, fwd);
            if (!(zc <= depth + eye_R * 0.35)) continue;
            vec3 n = XC / eye_R;
            vec3 X = eye_c[k] + XC;
            vec3 v = -d;
            for (int i = 0; i < n_lights; ++i) {
                vec3 l;
                vec3 L = light_rgb[i];
                if (light_kind[i] == 0) {
                    l = light_dir[i];
                } else {
                    vec3 dl = light_pos[i] - X;
                    float dist = length(dl);
                    l = dist > 0.0 ? dl / dist : vec3(0.0);
                    L = L / max(dot(dl, dl), 1e-24);
                }
                float nl = dot(n, l);
                vec3 r = 2.0 * nl * n - l;
                float rv = max(dot(r, v), 0.0);
                float spec = (nl > 0.0 && rv > 0.0) ? pow(rv, eye_s) : 0.0;
                img += eye_ks * L * spec;
            }
        }
    }
    img *= exposure;
    if (clamp01) img = clamp(img, 0.0, 1.0);
    o = vec4(img, 1.0);
}
