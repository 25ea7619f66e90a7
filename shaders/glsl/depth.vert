#version 330
// View-space depth pass of Render's GL pipeline (shadow maps, texture-camera occlusion map).
// `q` is the vertex in the view's frame (computed in float64 on the host); `proj` maps it to
// clip space so that window coordinates are the reference rasteriser's pixel coordinates.
// WORLD (the studio's shadow maps): the vertex is the world position `P` of the drawn mesh's
// own vertex buffer and `proj` maps world → clip (the light frame folded in on the host), so a
// light change uploads one matrix, not the mesh in the light's frame; with it the fragment
// shader is depth-only (depth.frag DEPTH_ONLY: the window depth is the shadow map).
#ifndef WORLD
#define WORLD 0
#endif
uniform mat4 proj;
#if WORLD
in vec3 P;
#else
in vec3 q;
out float vz;
#endif
invariant gl_Position;
void main() {
#if WORLD
    gl_Position = proj * vec4(P, 1.0);
#else
    vz = q.z;
    gl_Position = proj * vec4(q, 1.0);
#endif
}
