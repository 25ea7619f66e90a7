/* Relight's per-pixel maths (Loscos, Drettakis, Robert 2000 §4.4, §5, eq. 3 per pixel).
 *
 * The numpy reference is nodes/loscos/display.py `modulate_pixels`: radiosity is linear in
 * the emittances, so the preprocess (relight_plan) leaves, per drawn pixel p and light s, the
 * interpolated surface modulation R[s, p, c] (T_final/T × B/D per unit emittance, bilinear
 * over the leaf's corners, by coverage on mixed pixels) and the emitted radiance G[s, p, c]
 * per unit emittance.  For emittances e (S × 3, W/m²):
 *
 *   out[p, c] = base[p, c] · Σ_s R[s, p, c] · e[s, c]  +  Σ_s G[s, p, c] · e[s, c]
 *
 * every other pixel keeps the photograph, already in `out`.  One work item per drawn pixel.
 */
#pragma OPENCL FP_CONTRACT OFF   /* round like numpy's separate products and sums */

#ifndef S
#define S 1               /* lights */
#endif

__kernel void relight(__global float *restrict out,        /* H·W × 3: the photo on entry */
                      __global const int *restrict pix,    /* n: flat index of each drawn pixel */
                      __global const float *restrict base, /* n × 3 */
                      __global const float *restrict R,    /* S × n × 3 */
                      __global const float *restrict G,    /* S × n × 3 */
                      __constant float *restrict e,        /* S × 3 */
                      const int n)
{
    const int p = get_global_id(0);
    if (p >= n)
        return;
    const size_t o = (size_t)pix[p] * 3;
    for (int c = 0; c < 3; ++c) {
        const size_t q = (size_t)p * 3 + c;
        float ratio = R[q] * e[c];
        float glow = G[q] * e[c];
        for (int s = 1; s < S; ++s) {
            const size_t qs = (size_t)s * n * 3 + q;
            ratio += R[qs] * e[s * 3 + c];
            glow += G[qs] * e[s * 3 + c];
        }
        out[o + c] = base[q] * ratio + glow;
    }
}
