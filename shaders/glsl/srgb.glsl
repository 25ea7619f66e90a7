// The studio's display encoding (graphkit/studio/imaging.py, as every preview is shown):
// x clipped to [0, 1], then sRGB-encoded (IEC 61966-2-1).  Included by display.frag and by
// shade.frag with DISPLAY.
vec3 srgb_encode(vec3 x) {
    x = clamp(x, 0.0, 1.0);
    vec3 lo = 12.92 * x;
    vec3 hi = 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055;
    return mix(hi, lo, vec3(lessThanEqual(x, vec3(0.0031308))));
}
