/* SIMD lanes: RAYS rays at once, one per lane of a vector (-D RAYS = 1, 2, 4, 8 or 16;
 * render_cl.lane_width).
 *
 * Masks are -1 (true) / 0 in every lane, as vector comparisons give them; VMASK turns a
 * comparison into one at every width (a scalar comparison gives 1 / 0). Masks are only
 * combined with & | ~, tested with any() and consumed by select(): arithmetic on a mask
 * (n -= mask) is spelled with the named helpers below (lane_inc), built on select(). Oclgrind
 * 21.10 evaluates a vector mask turned into a number (-mask, mask & 1, mask ? 1 : 0) as
 * 255 per true lane; comparisons, & | ~, any(), all(), select() and as_int it gets right
 * (probed at widths 2-16), so the vector march runs under it as on a device.
 */
#ifndef CLRENDER_NGPRT_LANES_H
#define CLRENDER_NGPRT_LANES_H
#pragma OPENCL FP_CONTRACT OFF
#if !defined(RAYS)
#error "ngprt kernels need -D RAYS (rays per work-item: 1, 2, 4, 8 or 16)"
#endif

/* GATHER(b, i): (vint)(b[i lane 0], b[i lane 1], ...), built in registers (writing lanes
 * through memory and reading the vector back stalls store forwarding on a CPU). */
#if RAYS == 1
typedef float vfloat;
typedef int vint;
typedef uint vuint;
#define VF(x) convert_float(x)
#define VI(x) convert_int(x)
#define AS_VU(x) as_uint(x)
#define AS_VI(x) as_int(x)
#define VMASK(c) (-(int)(c))
#define LANE_IDS 0
#define GATHER(b, i) ((int)(b)[i])
#define VLOAD(p) (*(p))
#elif RAYS == 2
typedef float2 vfloat;
typedef int2 vint;
typedef uint2 vuint;
#define VF(x) convert_float2(x)
#define VI(x) convert_int2(x)
#define AS_VU(x) as_uint2(x)
#define AS_VI(x) as_int2(x)
#define VLOAD(p) vload2(0, p)
#define VMASK(c) (c)
#define LANE_IDS ((int2)(0, 1))
#define GATHER(b, i) ((int2)((b)[(i).s0], (b)[(i).s1]))
#elif RAYS == 4
typedef float4 vfloat;
typedef int4 vint;
typedef uint4 vuint;
#define VF(x) convert_float4(x)
#define VI(x) convert_int4(x)
#define AS_VU(x) as_uint4(x)
#define AS_VI(x) as_int4(x)
#define VLOAD(p) vload4(0, p)
#define VMASK(c) (c)
#define LANE_IDS ((int4)(0, 1, 2, 3))
#define GATHER(b, i) ((int4)((b)[(i).s0], (b)[(i).s1], (b)[(i).s2], (b)[(i).s3]))
#elif RAYS == 8
typedef float8 vfloat;
typedef int8 vint;
typedef uint8 vuint;
#define VF(x) convert_float8(x)
#define VI(x) convert_int8(x)
#define AS_VU(x) as_uint8(x)
#define AS_VI(x) as_int8(x)
#define VLOAD(p) vload8(0, p)
#define VMASK(c) (c)
#define LANE_IDS ((int8)(0, 1, 2, 3, 4, 5, 6, 7))
#define GATHER(b, i) ((int8)((b)[(i).s0], (b)[(i).s1], (b)[(i).s2], (b)[(i).s3], \
                             (b)[(i).s4], (b)[(i).s5], (b)[(i).s6], (b)[(i).s7]))
#elif RAYS == 16
typedef float16 vfloat;
typedef int16 vint;
typedef uint16 vuint;
#define VF(x) convert_float16(x)
#define VI(x) convert_int16(x)
#define AS_VU(x) as_uint16(x)
#define AS_VI(x) as_int16(x)
#define VLOAD(p) vload16(0, p)
#define VMASK(c) (c)
#define LANE_IDS ((int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define GATHER(b, i) ((int16)((b)[(i).s0], (b)[(i).s1], (b)[(i).s2], (b)[(i).s3], \
                              (b)[(i).s4], (b)[(i).s5], (b)[(i).s6], (b)[(i).s7], \
                              (b)[(i).s8], (b)[(i).s9], (b)[(i).sa], (b)[(i).sb], \
                              (b)[(i).sc], (b)[(i).sd], (b)[(i).se], (b)[(i).sf]))
#else
#error "RAYS must be 1, 2, 4, 8 or 16"
#endif
/* Lane j of a vector, to read or write (j < RAYS). */
#define LANE_F(v, j) (((float *)&(v))[j])
#define LANE_I(v, j) (((int *)&(v))[j])
#define FOR_LANES(j) for (int j = 0; j < RAYS; ++j)

/* Three coordinates of RAYS points (or directions), and of RAYS cells. */
typedef struct { vfloat x, y, z; } Point3;
typedef struct { vint x, y, z; } Cell3;

/* n + 1 in the lanes of mask, n elsewhere. */
inline vint lane_inc(vint n, vint mask) { return select(n, n + 1, mask); }

/* min / max / abs as selects: PoCL lowers fmin / fmax / fabs to library calls (~10 ns
 * each on the CPU); these give identical results for the finite values used here. */
inline vfloat lane_min(vfloat a, vfloat b) { return select(b, a, VMASK(a < b)); }
inline vfloat lane_max(vfloat a, vfloat b) { return select(b, a, VMASK(a > b)); }
inline vfloat lane_abs(vfloat a) { return select(a, -a, VMASK(a < 0.0f)); }

/* floor / ceil as ints, for |x| < 2^31. */
inline vint lane_floor_i(vfloat x)
{
    const vint i = VI(x);
    return select(i, i - 1, VMASK(VF(i) > x));
}

inline vint lane_ceil_i(vfloat x)
{
    const vint i = VI(x);
    return select(i, i + 1, VMASK(VF(i) < x));
}

/* b[idx] of the lanes in mask, 0 elsewhere (the other lanes read b[0]: their idx may be
 * out of range); bytes, shorts or ints. */
inline vint lane_gather_u8(__global const uchar *b, vint idx, vint mask)
{
    const vint i = select((vint)(0), idx, mask);
    return select((vint)(0), GATHER(b, i), mask);
}

inline vint lane_gather_u16(__global const ushort *b, vint idx, vint mask)
{
    const vint i = select((vint)(0), idx, mask);
    return select((vint)(0), GATHER(b, i), mask);
}

inline vint lane_gather_i32(__global const int *b, vint idx, vint mask)
{
    const vint i = select((vint)(0), idx, mask);
    return select((vint)(0), GATHER(b, i), mask);
}
#endif
