#version 330
// View-space depth pass of Render's GL pipeline (shadow maps, texture-camera occlusion map).
// `q` is the vertex in the view's frame (computed in float64 on the host); `proj` maps it to
// clip space so that window coordinates are the reference rasteriser's pixel coordinates.
uniform mat4 proj;
in vec3 q;
out float vz;
invariant gl_Position;
void main() {
    vz = q.z;
    gl_Position = proj * vec4(q, 1.0);
}
