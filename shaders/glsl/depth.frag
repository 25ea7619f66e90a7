#version 330
// Nearest-surface depth along the view's +z (mesh units); .y = 1 marks a covered texel.
// DEPTH_ONLY: no colour output (the depth attachment is the result; depth.vert WORLD).
#ifndef DEPTH_ONLY
#define DEPTH_ONLY 0
#endif
#if DEPTH_ONLY
void main() {}
#else
in float vz;
out vec4 o;
void main() { o = vec4(vz, 1.0, 0.0, 0.0); }
#endif
