#version 330
// Nearest-surface depth along the view's +z (mesh units); .y = 1 marks a covered texel.
in float vz;
out vec4 o;
void main() { o = vec4(vz, 1.0, 0.0, 0.0); }
