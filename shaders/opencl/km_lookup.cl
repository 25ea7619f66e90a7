/* Kubelka–Munk stack tables looked up per pixel (Huang et al. 2013 §3.1, eqs. 1–4).
 *
 * The numpy reference is nodes/huang/km.py `lookup` (used by nodes/huang/stack.py
 * `pixel_stack` and `stack_over_rgb`): the spectral KM work is done once on a grid of layer
 * thicknesses (km.stack_rgb_table, on the host) and every pixel interpolates the tables
 * multilinearly at its thicknesses.  This kernel is that per-pixel part:
 *
 *   f_i  = min(t_i · scale_i, N_i − 1)             position on axis i, in cells (float32)
 *   f_i  = rint(f_i)  where |f_i − rint(f_i)| ≤ SNAP (an axis within 1/2048 cell of a node is
 *          put on it, so a pixel on the nodes gets the table entry exactly)
 *   v    = Σ_corners Π_i (bit_i ? w_i : 1 − w_i) · table[lo + bits],  w_i = f_i − ⌊f_i⌋
 *
 * (only the corners of the axes off their node are read: a binary map reads one entry per
 * pixel, a feathered edge 2 or 4).  The
 * reference evaluates the same multilinear form by Horner's rule on float64-built finite
 * differences; the two agree to float32 round-off (~1e-7 relative).
 *
 * Compile-time constants (-D): NL layers (axes), NT tables of 3 channels each, packed per
 * grid node as NT float4 (RGB and a 0: table[node·NT + t]); OVER_RGB = 1 puts the
 * stack over a linear-RGB background image Rg (tables Rt, Rb, T, T²; stack_over_rgb):
 *
 *   R = Rt + T²·Rg / (1 − Rb·Rg)   → out (P × 3),  T → out2 (P × 3)
 *
 * else every table is written: out[(t·P + p)·3 + c].
 */
#pragma OPENCL FP_CONTRACT OFF   /* round each operation like numpy (no fused multiply-add) */
#ifndef NL          /* defaults: what the availability probe builds */
#define NL 3
#endif
#ifndef NT
#define NT 2
#endif
#ifndef OVER_RGB
#define OVER_RGB 0
#endif
#define SNAP (1.0f / 2048.0f)

__kernel void km_lookup(__global const float *restrict thick,   /* P × NL, mm */
                        __global const float4 *restrict table,  /* nodes × NT: RGB + 0 */
                        __constant float *restrict scale,       /* NL: cells per mm (0 for a one-node axis) */
                        __constant float *restrict last,        /* NL: N_i − 1 */
                        __constant int *restrict stride,        /* NL: node-index stride of axis i */
                        __global const float *restrict rg,      /* P × 3 background (OVER_RGB), else unused */
                        __global float *restrict out,
                        __global float *restrict out2,          /* P × 3: T (OVER_RGB), else unused */
                        const uint P)
{
    const uint p = get_global_id(0);
    if (p >= P)
        return;
    int base = 0;
    uint live = 0;            /* axes off their node: only their corners are read */
    float w[NL];
    for (int i = 0; i < NL; ++i) {
        float f = fmin(thick[(size_t)p * NL + i] * scale[i], last[i]);   /* ≥ 0 */
        /* |f − rint(f)| ≤ SNAP, tested as f − ⌊f⌋ ≤ SNAP or ⌊f⌋ + 1 − f ≤ SNAP: both
         * differences are exact in float32 (as the reference's f − rint(f) is), so the
         * decisions are the reference's; truncation is ⌊·⌋ for f ≥ 0 and, unlike pocl's
         * floor() and rint(), does not stop the vectoriser */
        float lo = (float)(int)f;
        if (f - lo <= SNAP) {
            f = lo;
        } else if (lo + 1.0f - f <= SNAP) {
            f = lo + 1.0f;
            lo = f;
        }
        w[i] = f - lo;
        base += (int)lo * stride[i];
        live |= (w[i] > 0.0f) ? (1u << i) : 0u;
    }
    float4 acc[NT];
    __global const float4 *e0 = table + (size_t)base * NT;
    if (live == 0) {           /* on a node (binary maps): the entry itself, exactly */
        for (int t = 0; t < NT; ++t)
            acc[t] = e0[t];
    } else {
        for (int t = 0; t < NT; ++t)
            acc[t] = (float4)(0.0f);
        for (uint corner = 0; corner < (1u << NL); ++corner) {
            if (corner & ~live)
                continue;      /* a corner along an axis that is on its node: weight 0 */
            float wt = 1.0f;
            int off = 0;
            for (int i = 0; i < NL; ++i) {
                if ((live >> i) & 1u) {
                    if ((corner >> i) & 1u) {
                        wt *= w[i];
                        off += stride[i];
                    } else {
                        wt *= 1.0f - w[i];
                    }
                }
            }
            __global const float4 *e = e0 + (size_t)off * NT;
            for (int t = 0; t < NT; ++t)
                acc[t] += wt * e[t];
        }
    }
#if OVER_RGB
    /* tables: Rt, Rb, T, T2 */
    const float3 g = vload3(p, rg);
    const float3 R = acc[3].xyz * g / (1.0f - acc[1].xyz * g) + acc[0].xyz;
    vstore3(R, p, out);
    vstore3(acc[2].xyz, p, out2);
#else
    for (int t = 0; t < NT; ++t)
        vstore3(acc[t].xyz, (size_t)t * P + p, out);
#endif
}
