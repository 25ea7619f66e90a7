/* RatioImage — a / max(b, eps), per channel (Paris, Sillion, Quan 2003, §3).
 *
 * a and b are float32 H×W×C arrays in row-major, pixel-interleaved order.  b has either the
 * same number of channels as a (kernel `ratio`, one work item per element) or one channel
 * that serves every channel of a (kernel `ratio_broadcast`, one work item per pixel).
 *
 * The host builds this with -cl-fp32-correctly-rounded-divide-sqrt so the division rounds
 * like numpy's (the reference: nodes/paris/ratio.py, function `ratio`).  The floor is a
 * comparison rather than fmax() so that, as with np.maximum, a NaN in b stays NaN.
 * The global size may be rounded up to a multiple of the work-group size: hence the bounds
 * checks.
 */
__kernel void ratio(__global const float *a,
                    __global const float *b,
                    __global float *out,
                    const ulong n,          /* elements of a (= of b): H*W*C */
                    const float eps)
{
    const size_t i = get_global_id(0);
    if (i >= n)
        return;
    const float d = b[i];
    out[i] = a[i] / ((d < eps) ? eps : d);
}

__kernel void ratio_broadcast(__global const float *a,
                              __global const float *b,   /* H*W, one channel */
                              __global float *out,
                              const ulong pixels,        /* H*W */
                              const uint channels,       /* channels of a */
                              const float eps)
{
    const size_t p = get_global_id(0);
    if (p >= pixels)
        return;
    const float d = b[p];
    const float m = (d < eps) ? eps : d;
    const size_t base = p * channels;
    for (uint c = 0; c < channels; ++c)
        out[base + c] = a[base + c] / m;
}
