/* RatioImage — a / max(b, eps), per channel (Paris, Sillion, Quan 2003, §3).
 *
 * a and b are float32 H×W×C arrays in row-major (pixel-interleaved) order.  b has either
 * the same number of channels as a, or one channel that is used for every channel of a.
 * One work item per element of a.  Build with -cl-fp32-correctly-rounded-divide-sqrt so
 * the division rounds like numpy's (the reference, nodes/paris/ratio.py:ratio).
 *
 * The floor is written as a comparison, not fmax(): like np.maximum, a NaN in b stays NaN.
 */
__kernel void ratio(__global const float *a,
                    __global const float *b,
                    __global float *out,
                    const ulong n,           /* elements of a: H*W*channels_a */
                    const uint channels_a,
                    const uint channels_b,   /* 1 or channels_a */
                    const float eps)
{
    const size_t i = get_global_id(0);
    if (i >= n)
        return;
    const size_t j = (channels_b == 1u) ? i / channels_a : i;
    const float d = b[j];
    out[i] = a[i] / ((d < eps) ? eps : d);
}
