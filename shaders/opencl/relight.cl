/* Relight's per-pixel modulation (Loscos, Drettakis, Robert 2000 §4.4, §5, eq. 3 per pixel).
 *
 * The numpy reference is nodes/loscos/relight.py `relight_fast`: the solution keeps one
 * radiosity response per light (radiosity is linear in the emittances), so for emittances
 * e (S × 3, W/m²) a drawn pixel p seeing leaf k shows
 *
 *   out[p, c] = base[p, c] · Σ_s resp[c, k, s] · e[s, c]
 *
 * (base = photo × T_final/T / D for surfaces, 1/π for emitters: computed once per
 * preprocess by the reference's `prepare`); every other pixel keeps the photograph, already
 * in `out`.  One work item per drawn pixel: B is gathered from the responses of its leaf, so
 * the (leaves × lights) sum and the per-pixel product are one pass.
 */
#pragma OPENCL FP_CONTRACT OFF   /* round like numpy's einsum and product */

#ifndef S
#define S 1               /* lights */
#endif

__kernel void relight(__global float *restrict out,        /* H·W × 3: the photo on entry */
                      __global const int *restrict pix,    /* n: flat index of each drawn pixel */
                      __global const int *restrict leaf,   /* n: its leaf */
                      __global const float *restrict base, /* n × 3 */
                      __global const float *restrict resp, /* 3 × L × S */
                      __constant float *restrict e,        /* S × 3 */
                      const int L, const int n)
{
    const int p = get_global_id(0);
    if (p >= n)
        return;
    const size_t k = (size_t)leaf[p];
    const size_t o = (size_t)pix[p] * 3;
    for (int c = 0; c < 3; ++c) {
        __global const float *r = resp + ((size_t)c * L + k) * S;
        float B = 0.0f;
        for (int s = 0; s < S; ++s)
            B += r[s] * e[s * 3 + c];
        out[o + c] = base[(size_t)p * 3 + c] * B;
    }
}
