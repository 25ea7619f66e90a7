// Render's lights (Paris 2003 §5) and the Phong lobes of nodes/paris/phong.py, included by
// shade.frag.  Lights are in the WORLD frame and in world units (a point light's position and
// intensity through Camera.metres_per_unit, nodes.paris.render.world_lights).  N_LIGHTS (a
// define, default 1) sizes the arrays and bounds the loops, so each light count is its own
// program and no loop runs past the lights there are.
#ifndef N_LIGHTS
#define N_LIGHTS 1
#endif
uniform int light_kind[N_LIGHTS];         // 0 directional, 1 point
// DIRECTIONAL: every light is directional (the studio's programs once a drag has made light 0
// one), so the point-light code is compiled out (SwiftShader runs both sides of a branch)
#ifndef DIRECTIONAL
#define DIRECTIONAL 0
#endif
#if DIRECTIONAL
#define LIGHT_IS_DIRECTIONAL(i) true
#else
#define LIGHT_IS_DIRECTIONAL(i) (light_kind[i] == 0)
#endif
uniform vec3 light_dir[N_LIGHTS];         // unit, towards the light (directional)
uniform vec3 light_pos[N_LIGHTS];         // world units (point)
uniform vec3 light_rgb[N_LIGHTS];         // colour × intensity (point: radiant intensity)

// The unit direction from X towards light i; L = its irradiance at normal incidence
// (render.light_vectors: point lights always fall off as 1/d²).
vec3 towards_light(int i, vec3 X, out vec3 L) {
    L = light_rgb[i];
    if (LIGHT_IS_DIRECTIONAL(i)) return light_dir[i];
    vec3 d = light_pos[i] - X;
    float dist = length(d);
    L = L / max(dot(d, d), 1e-24);
    return dist > 0.0 ? d / dist : vec3(0.0);
}

// phong.lobes' specular factor: (r·v)^s with r = 2(n·l)n − l, 0 unless n·l > 0 and r·v > 0.
float phong_spec(vec3 n, vec3 l, vec3 v, float s) {
    float nl = dot(n, l);
    vec3 r = 2.0 * nl * n - l;
    float rv = max(dot(r, v), 0.0);
    return (nl > 0.0 && rv > 0.0) ? pow(rv, s) : 0.0;
}
