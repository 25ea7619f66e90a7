/* Screen-space subsurface scattering: one axis of one Gaussian of the sum-of-Gaussians skin
 * profile (d'Eon, Luebke & Enderton 2007; Jimenez et al. 2010 §6), shared by SkinShade and
 * CosmeticShade.  The numpy reference is nodes/common/sss.py (`sss_blur` with its one-axis
 * blur `_blur_planes_axis`); the profile loop, the weights and the final mask stay on the host
 * in the reference's own code.
 *
 * For each pixel and each of NCH planes:
 *
 *   out = Σ_k g(k) v(i+k) x(i+k) / Σ_k g(k) v(i+k),   |k| ≤ R = int(4σ + 0.5)
 *
 * along the axis (0 = y, 1 = x), indices mirrored at the borders like scipy's / cv2's
 * `reflect` (… c b a | a b c … , also for kernels longer than the image: the host pads), v
 * the skin mask (1 without one; no valid tap: the pixel is unchanged).
 *
 * * uniform σ (`per_pixel` = 0): g = the reference's own normalised taps (gaussian_kernel,
 *   passed in `taps`): the same weights as its cv2.filter2D;
 * * per-pixel σ = sd · inv_step (σ from the depth gradient or a pixel-footprint map):
 *   g(k) = exp(−k²/2σ²) with σ the pixel's own — the exact gather (the reference's
 *   `_blur_axis`), which the reference's σ-level approximation follows to ~1e-4 of the signal.
 *   Weights by the recurrence w_k = w_{k−1}·q_k, q_k = q_{k−1}·e^{−1/σ²} (two products a tap).
 */

#ifndef AXIS
#define AXIS 1
#endif
#ifndef PER_PIXEL
#define PER_PIXEL 0
#endif
#ifndef HAS_VALID
#define HAS_VALID 0
#endif

#ifndef V
#define V 16            /* pixels per work item along x */
#endif

/* src and valid come padded along the axis by R pixels on each side, mirrored like the
 * reference's border (numpy 'symmetric' = scipy 'reflect' = cv2 BORDER_REFLECT), plus V spare
 * floats at the end, so every tap is a plain load.  A work item computes V neighbouring
 * pixels of one row of one plane: its inner loops run over those V pixels (contiguous loads,
 * independent sums: the compiler vectorises them without reordering any sum).  AXIS,
 * PER_PIXEL and HAS_VALID are compile-time constants (-D). */
__kernel void sss_axis(__global const float *restrict src,      /* padded plane */
                       __global float *restrict dst,            /* H × W */
                       __global const float *restrict valid,    /* padded mask in {0, 1} */
                       __global const float *restrict inv_step, /* H × W: σ = sd · inv_step */
                       __global const float *restrict taps,     /* 2R + 1 normalised taps */
                       const int R, const float sd, const int H, const int W)
{
    const int x0 = get_global_id(0) * V, y = get_global_id(1);
    if (x0 >= W || y >= H)
        return;
#if AXIS
    const size_t ctr = (size_t)y * (W + 2 * R) + x0 + R;  /* pixel (y, x0) in the padded row */
    const size_t step = 1;
#else
    const size_t ctr = (size_t)(y + R) * W + x0;          /* pixel (y, x0) in the padded column */
    const size_t step = (size_t)W;
#endif
    float acc[V], wsum[V], norm[V];
#if PER_PIXEL
    float wk[V], q[V], e2[V];
    int r[V];
    for (int j = 0; j < V; ++j) {
        const int xj = min(x0 + j, W - 1);
        const float sigma = sd * inv_step[(size_t)y * W + xj];
        r[j] = (int)(4.0f * sigma + 0.5f);                /* this pixel's radius, ≤ R */
        const float a = (sigma > 0.0f) ? 0.5f / (sigma * sigma) : 0.0f;
        wk[j] = 1.0f;
        q[j] = exp(-a);
        e2[j] = q[j] * q[j];
    }
    const float w0 = 1.0f;
#else
    const float w0 = taps[R];
#endif
    for (int j = 0; j < V; ++j) {
#if HAS_VALID
        const float v0 = valid[ctr + j];
#else
        const float v0 = 1.0f;
#endif
        acc[j] = w0 * v0 * src[ctr + j];
        wsum[j] = w0 * v0;
        norm[j] = w0;
    }
    for (int k = 1; k <= R; ++k) {
        __global const float *sp = src + ctr + (size_t)k * step;
        __global const float *sm = src + ctr - (size_t)k * step;
#if HAS_VALID
        __global const float *vp = valid + ctr + (size_t)k * step;
        __global const float *vm = valid + ctr - (size_t)k * step;
#endif
#if !PER_PIXEL
        const float w = taps[R + k];
#endif
        for (int j = 0; j < V; ++j) {
#if PER_PIXEL
            wk[j] *= q[j];                                /* exp(−a k²) by the recurrence */
            q[j] *= e2[j];
            const float w = (k <= r[j]) ? wk[j] : 0.0f;   /* 0 beyond this pixel's radius */
#endif
#if HAS_VALID
            const float wp = w * vp[j], wm = w * vm[j];
#else
            const float wp = w, wm = w;
#endif
            acc[j] += wp * sp[j] + wm * sm[j];
            wsum[j] += wp + wm;
            norm[j] += 2.0f * w;
        }
    }
    const int n = min(V, W - x0);
    for (int j = 0; j < n; ++j) {
        const float self = src[ctr + j];
#if HAS_VALID   /* as the reference: where the normalised valid weight is > 1e-12, else unchanged */
        float out = (wsum[j] > 1e-12f * norm[j]) ? acc[j] / wsum[j] : self;
#elif PER_PIXEL
        float out = acc[j] / wsum[j];
#else           /* the taps sum to 1: cv2.filter2D's plain correlation */
        float out = acc[j];
#endif
#if PER_PIXEL
        out = (r[j] == 0) ? self : out;                   /* a one-tap kernel: the identity */
#endif
        dst[(size_t)y * W + x0 + j] = out;
    }
}
