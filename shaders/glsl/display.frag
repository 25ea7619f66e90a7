#version 330
// The studio's face view (nodes/paris/studio_view.js): Render's linear image on a canvas, as
// the page shows every preview (graphkit/studio/imaging.py): × 2^exposure, clipped to [0, 1],
// sRGB-encoded (IEC 61966-2-1); image row 0 at the top of the canvas.
out vec4 o;
uniform sampler2D image;
uniform float scale;                      // 2^exposure
void main() {
    ivec2 size = textureSize(image, 0);
    ivec2 px = ivec2(int(gl_FragCoord.x), size.y - 1 - int(gl_FragCoord.y));
    vec3 x = clamp(texelFetch(image, px, 0).rgb * scale, 0.0, 1.0);
    vec3 lo = 12.92 * x;
    vec3 hi = 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055;
    o = vec4(mix(hi, lo, vec3(lessThanEqual(x, vec3(0.0031308)))), 1.0);
}
