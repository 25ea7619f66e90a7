#version 330
// The studio's face view (nodes/paris/studio_view.js): Render's linear image on a canvas, as
// the page shows every preview (graphkit/studio/imaging.py): × 2^exposure, clipped to [0, 1],
// sRGB-encoded (IEC 61966-2-1); image row 0 at the top of the canvas.  (The view's frames
// use shade.frag with DISPLAY instead: the same encoding in the lighting pass.)
#include "srgb.glsl"
out vec4 o;
uniform sampler2D image;
uniform float scale;                      // 2^exposure
void main() {
    ivec2 size = textureSize(image, 0);
    ivec2 px = ivec2(int(gl_FragCoord.x), size.y - 1 - int(gl_FragCoord.y));
    o = vec4(srgb_encode(texelFetch(image, px, 0).rgb * scale), 1.0);
}
