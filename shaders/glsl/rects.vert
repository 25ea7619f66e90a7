#version 330
// Rectangles in window pixel coordinates (two triangles each, corners on pixel edges, so a
// rectangle covers exactly its pixels): the studio's lighting pass drawn over the pixels the
// surface covers only (nodes/paris/studio_view.js, coverRects), not their whole screen box.
in vec2 corner;                           // window pixel coordinates
uniform vec2 view_size;                   // W, H
void main() {
    gl_Position = vec4(corner / view_size * 2.0 - 1.0, 0.0, 1.0);
}
