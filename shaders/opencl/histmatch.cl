/* LocalHistMatch, fast path (Jimenez et al. 2010 §4.1 eqs. 1–3, §4.2, §6): the two passes
 * over the full-resolution maps.  The numpy reference is nodes/jimenez/histmatch.py; the
 * statistics on the cell grid between the passes (centring, the disc filter, eq. 3's scale)
 * stay on the host, in the reference's own code.
 *
 * cell_moments — `_cell_moments`: for each whole c × c-pixel cell, with x = h·m (h where
 * there is no mask) the sums Σx and Σx·h divided by c² (= cv2.resize INTER_AREA of the
 * reference).  One work item per cell; the products are rounded to float32 as cv2.multiply
 * rounds them, the sums are accumulated in double (up to c² ≥ 4096 terms), so the only
 * difference from the reference is its own float32 accumulation (~1e-7 of the mean).  The cells cut off by the
 * image's last row and column are summed on the host by the reference's `cell_means`.
 *
 * apply_scale_bias — eq. (3) as an affine map: out = max(a·h_n + b, 0), with a, b given on the
 * cell grid (gH × gW cells of c px tiling the image) and resampled bilinearly as cv2.resize
 * INTER_LINEAR does (source coordinate (x + ½)/c − ½, clamped to the first/last cell) — or,
 * with c = 1, given per pixel.  cv2.threshold TOZERO keeps only values > 0 (NaN → 0); so here.
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#pragma OPENCL FP_CONTRACT OFF   /* round each operation like numpy / cv2 */

__kernel void cell_moments(__global const float *restrict h,    /* H × W */
                           __global const float *restrict m,    /* H × W mask in [0, 1] (has_mask) */
                           __global float *restrict a1,         /* gH × gW: Σ h·m / c² */
                           __global float *restrict a2,         /* gH × gW: Σ h²·m / c² */
                           const int W, const int c, const int gW, const int qW,
                           const int has_mask)
{
    /* whole cells only (qH × qW); the host adds the cut-off last row and column */
    const int gx = get_global_id(0), gy = get_global_id(1);
    if (gx >= qW)
        return;
    __global const float *restrict p0 = h + (size_t)gy * c * W + (size_t)gx * c;
    __global const float *restrict q0 = m + (has_mask ? (size_t)gy * c * W + (size_t)gx * c : 0);
    double s1 = 0.0, s2 = 0.0;
    for (int y = 0; y < c; ++y) {
        for (int x = 0; x < c; ++x) {
            const float v = p0[(size_t)y * W + x];
            const float xm = has_mask ? v * q0[(size_t)y * W + x] : v;
            s1 += (double)xm;
            s2 += (double)(xm * v);
        }
    }
    const double inv = 1.0 / ((double)c * (double)c);
    a1[(size_t)gy * gW + gx] = (float)(s1 * inv);
    a2[(size_t)gy * gW + gx] = (float)(s2 * inv);
}

__kernel void apply_scale_bias(__global const float *restrict hn,  /* H × W */
                               __global const float *restrict a,   /* gH × gW (c > 1) or H × W (c = 1) */
                               __global const float *restrict b,
                               __global float *restrict out,       /* H × W */
                               const int H, const int W, const int c,
                               const int gH, const int gW)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= W || y >= H)
        return;
    const size_t i = (size_t)y * W + x;
    float av, bv;
    if (c == 1) {
        av = a[i];
        bv = b[i];
    } else {
        /* source coordinate (x + ½)/c − ½ = (2x + 1 − c)/(2c) ≥ −½: ⌊·⌋ by truncating
         * after + 1 (pocl's floor() and vector integer division are slow on CPUs) */
        const float inv2c = 0.5f / (float)c;
        float fx = (float)(2 * x + 1 - c) * inv2c;
        float fy = (float)(2 * y + 1 - c) * inv2c;
        int sx = (int)(fx + 1.0f) - 1, sy = (int)(fy + 1.0f) - 1;
        fx -= (float)sx;
        fy -= (float)sy;
        if (sx < 0) { sx = 0; fx = 0.0f; }
        if (sx >= gW - 1) { sx = gW - 1; fx = 0.0f; }
        if (sy < 0) { sy = 0; fy = 0.0f; }
        if (sy >= gH - 1) { sy = gH - 1; fy = 0.0f; }
        const int sx1 = min(sx + 1, gW - 1), sy1 = min(sy + 1, gH - 1);
        const size_t r0 = (size_t)sy * gW, r1 = (size_t)sy1 * gW;
        /* cv2: horizontal pass per source row, then vertical */
        const float a0 = a[r0 + sx] * (1.0f - fx) + a[r0 + sx1] * fx;
        const float a1 = a[r1 + sx] * (1.0f - fx) + a[r1 + sx1] * fx;
        const float b0 = b[r0 + sx] * (1.0f - fx) + b[r0 + sx1] * fx;
        const float b1 = b[r1 + sx] * (1.0f - fx) + b[r1 + sx1] * fx;
        av = a0 * (1.0f - fy) + a1 * fy;
        bv = b0 * (1.0f - fy) + b1 * fy;
    }
    const float v = bv + hn[i] * av;
    out[i] = (v > 0.0f) ? v : 0.0f;
}
