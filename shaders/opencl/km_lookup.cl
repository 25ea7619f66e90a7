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

/* Position of pixel p on the grid: the node below (its index), the weights along each axis
 * (0 on a node) and the mask of the axes off their node. */
inline uint cell(__global const float *restrict thick, const size_t p,
                 __constant float *restrict scale, __constant float *restrict last,
                 __constant int *restrict stride, float *w, int *base)
{
    uint live = 0;
    int b = 0;
    for (int i = 0; i < NL; ++i) {
        float f = fmin(thick[p * NL + i] * scale[i], last[i]);   /* ≥ 0 */
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
        b += (int)lo * stride[i];
        live |= (w[i] > 0.0f) ? (1u << i) : 0u;
    }
    *base = b;
    return live;
}

/* Multilinear interpolation from the node `base` along the live axes. */
inline void interpolate(__global const float4 *restrict table, const int base, const uint live,
                        const float *w, __constant int *restrict stride, float4 *acc)
{
    __global const float4 *e0 = table + (size_t)base * NT;
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

inline void store(const float4 *acc, const size_t p, const uint P, __global const float *restrict rg,
                  __global float *restrict out, __global float *restrict out2)
{
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

#define KM_ARGS __global const float *restrict thick,  /* P × NL, mm */                     \
                __global const float4 *restrict table, /* nodes × NT: RGB + 0 */            \
                __constant float *restrict scale,      /* NL: cells per mm (0: one node) */ \
                __constant float *restrict last,       /* NL: N_i − 1 */                    \
                __constant int *restrict stride,       /* NL: node-index stride of axis i */\
                __global const float *restrict rg,     /* P × 3 background (OVER_RGB) */    \
                __global float *restrict out,                                               \
                __global float *restrict out2,         /* P × 3: T (OVER_RGB) */            \
                const uint P

/* One pass, one pixel per work item (GPUs). */
__kernel void km_lookup(KM_ARGS)
{
    const uint p = get_global_id(0);
    if (p >= P)
        return;
    float w[NL];
    int base;
    const uint live = cell(thick, p, scale, last, stride, w, &base);
    float4 acc[NT];
    if (live == 0) {           /* on a node (binary maps): the entry itself, exactly */
        for (int t = 0; t < NT; ++t)
            acc[t] = table[(size_t)base * NT + t];
    } else {
        interpolate(table, base, live, w, stride, acc);
    }
    store(acc, p, P, rg, out, out2);
}

/* Two passes (CPUs, where a kernel with both paths runs at the speed of the slow one):
 * km_nodes, one work item per row, writes the pixels on a node and lists the others per row;
 * km_interp interpolates the listed pixels (work item (k, y): the k-th listed pixel of row y). */
__kernel void km_nodes(KM_ARGS, const int W, __global int *restrict list, __global int *restrict count)
{
    const int y = get_global_id(0);
    if ((size_t)y * W >= P)
        return;
    int n = 0;
    for (int x = 0; x < W; ++x) {
        const size_t p = (size_t)y * W + x;
        float w[NL];
        int base;
        if (cell(thick, p, scale, last, stride, w, &base)) {
            list[(size_t)y * W + n++] = x;
        } else {
            float4 acc[NT];
            for (int t = 0; t < NT; ++t)
                acc[t] = table[(size_t)base * NT + t];
            store(acc, p, P, rg, out, out2);
        }
    }
    count[y] = n;
}

__kernel void km_interp(KM_ARGS, const int W, __global const int *restrict list,
                        __global const int *restrict count)
{
    const int k = get_global_id(0), y = get_global_id(1);
    if (k >= count[y])
        return;
    const size_t p = (size_t)y * W + list[(size_t)y * W + k];
    float w[NL];
    int base;
    const uint live = cell(thick, p, scale, last, stride, w, &base);
    float4 acc[NT];
    interpolate(table, base, live, w, stride, acc);
    store(acc, p, P, rg, out, out2);
}
