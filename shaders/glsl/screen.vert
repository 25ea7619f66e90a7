#version 330
// A triangle covering the viewport (composite pass).
// VIEW_RAY (shade.frag's view vector from the pixel ray): v_ray = −ray_dir·(x, y, 1) at the
// vertex's window position (x, y) = (p + 1)/2 · view_size, linear in the pixel, so that each
// fragment gets it at its centre (the reference's view vector, with no world position).
#ifndef VIEW_RAY
#define VIEW_RAY 0
#endif
#if VIEW_RAY
uniform mat3 ray_dir;                     // pixel (x+.5, y+.5, 1) → world ray direction
uniform vec2 view_size;                   // the viewport (W, H)
out vec3 v_ray;
#endif
void main() {
    vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
#if VIEW_RAY
    v_ray = -(ray_dir * vec3((p * 0.5 + 0.5) * view_size, 1.0));
#endif
    gl_Position = vec4(p, 0.0, 1.0);
}
