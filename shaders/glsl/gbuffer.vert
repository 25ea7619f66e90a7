#version 330
// Surface pass of Render's GL pipeline (Paris 2003 §5): camera-frame position q (float64 on
// the host → f32), world position P and vertex normal N, interpolated perspective-correctly
// (orthographic: w = 1, linearly) by GL like the reference rasteriser's barycentrics.
uniform mat4 proj;                        // camera frame → clip; window coordinates = pixels
in vec3 q;
in vec3 P;
in vec3 N;
out vec3 vP;
out vec3 vN;
out float vz;
invariant gl_Position;                    // the same positions as depth.vert's pre-pass
void main() {
    vP = P;
    vN = N;
    vz = q.z;
    gl_Position = proj * vec4(q, 1.0);
}
