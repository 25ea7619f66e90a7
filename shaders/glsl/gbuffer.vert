#version 330
// Surface pass of Render's GL pipeline (Paris 2003 §5): camera-frame position q (float64 on
// the host → f32), world position P and vertex normal N, interpolated perspective-correctly
// (orthographic: w = 1, linearly) by GL like the reference rasteriser's barycentrics.
// Defines: EXACT (also pass each triangle's three world vertices and normals, flat, so that
// gbuffer.frag can intersect the pixel's ray with the exact triangle; see there).
#ifndef EXACT
#define EXACT 0
#endif
uniform mat4 proj;                        // camera frame → clip; window coordinates = pixels
in vec3 q;
in vec3 P;
in vec3 N;
out vec3 vP;
out vec3 vN;
out float vz;
#if EXACT
in vec3 A0;                               // the triangle's world vertices (the same on its
in vec3 A1;                               // three corners: the mesh is drawn un-indexed)
in vec3 A2;
in vec3 B0;                               // and their normals
in vec3 B1;
in vec3 B2;
flat out vec3 tA0;
flat out vec3 tA1;
flat out vec3 tA2;
flat out vec3 tB0;
flat out vec3 tB1;
flat out vec3 tB2;
#endif
invariant gl_Position;                    // the same positions as depth.vert's pre-pass
void main() {
    vP = P;
    vN = N;
    vz = q.z;
#if EXACT
    tA0 = A0; tA1 = A1; tA2 = A2;
    tB0 = B0; tB1 = B1; tB2 = B2;
#endif
    gl_Position = proj * vec4(q, 1.0);
}
