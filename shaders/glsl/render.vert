#version 330
// Main pass of Render/opengl (Paris 2003 §5): camera-space position q (host float64 → f32),
// world position P and vertex normal N, interpolated perspective-correctly by GL like the
// reference rasteriser's barycentrics.
uniform mat4 proj;
in vec3 q;
in vec3 P;
in vec3 N;
out vec3 vP;
out vec3 vN;
out float vz;
invariant gl_Position;
void main() {
    vP = P;
    vN = N;
    vz = q.z;
    gl_Position = proj * vec4(q, 1.0);
}
