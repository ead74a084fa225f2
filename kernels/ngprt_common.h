/* NGP-RT device helpers of ngprt_march.cl.
 *
 * Mirrors clrender/ngprt/space.py, encoding.py and render_ref.py operation for
 * operation (docs/ngprt.md is the contract). The exact build (device.EXACT_OPTIONS) keeps
 * FP contraction off and asks for correctly rounded division and sqrt, so positions,
 * cells and lattice indices are bit-identical to the numpy reference; exp-based values
 * may differ by a few ulps. The fast build (-D FAST_MATH=1, device.FAST_OPTIONS) takes
 * exp and the sigmoid's reciprocal from native_exp / native_recip; positions, cells and
 * lattice indices are computed by the same operations in both builds.
 *
 * Every constant comes as a -D define from clrender/ngprt/render_cl.py:kernel_defines,
 * so Python and OpenCL share one definition (clrender/ngprt/config.py):
 *   shared constants (config.kernel_constants): T_STOP, N_MIP, FEATURES, FUSION_HIDDEN
 *     and the variant codes VARIANT_SUM .. VARIANT_SEPARATE_V (config.VARIANT_CODES);
 *     SH_DIM and DEFERRED_HIDDEN come too, for the deferred MLP;
 *   per model: L, L_C, LOG2_T, COARSE_BLOCK, G_RES, N_ATT (attention channels in the
 *     coarse grid), N_INV (spatially invariant logits), VARIANT, UNBOUNDED, USE_G;
 *   per device: RAYS (rays per work-item in vector lanes), FAST_MATH; the march also
 *     takes G_IN_CODE (render_cl.g_in_codes).
 * A missing define fails the build: an undefined name is 0 in #if, which would
 * silently pick VARIANT_SUM's code or a zero T_STOP.
 */
#ifndef CLRENDER_NGPRT_COMMON_H
#define CLRENDER_NGPRT_COMMON_H
#pragma OPENCL FP_CONTRACT OFF

#if !defined(T_STOP) || !defined(N_MIP) || !defined(FEATURES) || !defined(FUSION_HIDDEN) || \
    !defined(LATTICE_BREAKS)
#error "ngprt kernels need -D T_STOP N_MIP FEATURES FUSION_HIDDEN LATTICE_BREAKS (config.kernel_constants)"
#endif
/* The lattice table holds the ray's start, 12 candidates and its end (v_lattice_build). */
#if LATTICE_BREAKS != 14
#error "LATTICE_BREAKS must be 14: the start, 12 candidate breakpoints, the end"
#endif
#if !defined(VARIANT_SUM) || !defined(VARIANT_MLP) || !defined(VARIANT_SHARED_INV) || \
    !defined(VARIANT_SEPARATE_INV) || !defined(VARIANT_SHARED_V) || !defined(VARIANT_SEPARATE_V)
#error "ngprt kernels need -D VARIANT_SUM .. VARIANT_SEPARATE_V (config.VARIANT_CODES)"
#endif
#if !defined(L) || !defined(L_C) || !defined(LOG2_T) || !defined(COARSE_BLOCK) || \
    !defined(G_RES) || !defined(N_ATT) || !defined(N_INV) || !defined(VARIANT) || \
    !defined(UNBOUNDED) || !defined(USE_G)
#error "ngprt kernels need -D L L_C LOG2_T COARSE_BLOCK G_RES N_ATT N_INV VARIANT UNBOUNDED USE_G"
#endif
/* The code's shape fixes this: features travel as float8 (the mlp fusion also runs
 * its hidden layer in float8 lanes). */
#if FEATURES != 8
#error "FEATURES must be 8: features are held in float8"
#endif
#include "ngprt_math.h"
#if FUSION_HIDDEN % 8 != 0
#error "FUSION_HIDDEN must be a multiple of 8"
#endif

#define TABLE_MASK ((1u << LOG2_T) - 1u)
/* A coarse corner holds 8 + N_ATT channels; the renderer pads each corner to a
 * multiple of 8 floats (COARSE_STRIDE) so every read is an aligned float8. */
#define ATT_VEC ((N_ATT + 7) / 8)                 /* float8 chunks of attention logits */
#define INV_VEC ((N_INV + 7) / 8)                 /* float8 chunks of invariant logits */
/* float8 chunks of attention weights (sigmoids) a sample's fusion reads: from the coarse
 * grid (-v variants) or from the invariant logits (-inv), at least one. */
#define SIG_LEN (ATT_VEC > INV_VEC ? ATT_VEC : (INV_VEC > 0 ? INV_VEC : 1))
#define COARSE_STRIDE (FEATURES * (1 + ATT_VEC))  /* floats per coarse corner */
#define COARSE_BLOCKS_PER_AXIS (L_C / COARSE_BLOCK)
#define COARSE_CORNERS (COARSE_BLOCK + 1)

#if UNBOUNDED
#define EXTENT 2.0f
#else
#define EXTENT 1.0f
#endif

/* PoCL lowers floor/clamp/fmax and the vector conversions to library calls that cost
 * ~10 ns each on the CPU; these comparisons and casts compile to a few instructions and
 * give identical results for the finite values used here (NaN never reaches them). */
inline float ngp_maxf(float a, float b) { return a > b ? a : b; }
inline float ngp_minf(float a, float b) { return a < b ? a : b; }
inline float ngp_absf(float a) { return a < 0.0f ? -a : a; }

/* ceil(x) as an int, for |x| < 2^31. */
inline int ngp_ceil_i(float x)
{
    const int i = (int)x;
    return (float)i < x ? i + 1 : i;
}

/* ---- space.py ------------------------------------------------------------------ */

/* MERF contraction into [-2, 2]^3 (space.contract). */
inline float3 ngp_contract(float3 x)
{
    const float3 ax = (float3)(ngp_absf(x.x), ngp_absf(x.y), ngp_absf(x.z));
    const float m = ngp_maxf(ngp_maxf(ax.x, ax.y), ax.z);
    if (m <= 1.0f) return x;
    const float m_safe = ngp_maxf(m, 1.0f);
    const float3 s = x / m_safe;
    const float3 scaled = s * (2.0f - 1.0f / m_safe);
    return (float3)(ax.x == m ? scaled.x : s.x,
                    ax.y == m ? scaled.y : s.y,
                    ax.z == m ? scaled.z : s.z);
}


/* Grid coordinates u in [0, 1]^3 of a world point (space.to_grid). */
inline float3 ngp_to_grid(float3 p)
{
#if UNBOUNDED
    const float3 c = ngp_contract(p);
#else
    const float3 c = p;
#endif
    return (c + EXTENT) / (2.0f * EXTENT);
}

/* u of the lattice point at distance t along the ray: to_grid(o + t * d). */
inline float3 ngp_point_u(float3 o, float3 d, float t)
{
    return ngp_to_grid(o + t * d);
}

/* Cell of u at resolution res, clamped to the grid (space.cell_index). Clamping the
 * float to [0, res-1] before flooring gives the same cell as clamping floor(u * res),
 * and the clamped value is non-negative, so floor is the int conversion. */
inline int ngp_cell1(float v, int res)
{
    const float hi = (float)(res - 1);
    return (int)(v < 0.0f ? 0.0f : (v > hi ? hi : v));
}

inline int3 ngp_cell(float3 u, int res)
{
    const float r = (float)res;
    return (int3)(ngp_cell1(u.x * r, res), ngp_cell1(u.y * r, res), ngp_cell1(u.z * r, res));
}

/* ---- encoding.py --------------------------------------------------------------- */

/* Attention weights of 8 logits at once: one vector exp (Eq. 7-8). */
inline float8 ngp_sigmoid8(float8 x)
{
    return NGP_RECIP(1.0f + NGP_EXP(-x));
}

/* ---- features at a sample (docs/ngprt.md, Eq. 6-8) ----------------------------- */

/* The `mlp` fusion: relu([f^0 .. f^{L-1}] @ w0 + b0) @ w1 + b1; params packed as
 * [w0 (8L, 64), b0 (64), w1 (64, 8), b1 (8)], every part a multiple of 8 floats, so
 * the hidden layer runs as 8 float8 lanes of 8 units each with aligned reads. */
inline float8 ngp_fuse_mlp(const float8 *fl, __global const float *p)
{
    __global const float8 *w0 = (__global const float8 *)p;
    __global const float8 *b0 = w0 + L * FUSION_HIDDEN;
    __global const float8 *w1 = b0 + FUSION_HIDDEN / 8, *b1 = w1 + FUSION_HIDDEN;
    float8 h[FUSION_HIDDEN / 8];
    for (int jj = 0; jj < FUSION_HIDDEN / 8; ++jj) h[jj] = (float8)(0.0f);
    for (int l = 0; l < L; ++l) {
        const float *x = (const float *)&fl[l];
        for (int c = 0; c < FEATURES; ++c) {
            __global const float8 *row = w0 + (l * FEATURES + c) * (FUSION_HIDDEN / 8);
            for (int jj = 0; jj < FUSION_HIDDEN / 8; ++jj) h[jj] = h[jj] + x[c] * row[jj];
        }
    }
    float8 out = (float8)(0.0f);
    for (int jj = 0; jj < FUSION_HIDDEN / 8; ++jj) {
        const float8 a = h[jj] + b0[jj];
        const float8 r = a > 0.0f ? a : (float8)(0.0f);
        const float *rj = (const float *)&r;
        for (int q = 0; q < 8; ++q) out = out + rj[q] * w1[8 * jj + q];
    }
    return out + b1[0];
}

/* Fusion of the fine features by VARIANT (docs/ngprt.md "Fusion"): sig holds the
 * attention weights sigmoid(logit) in logit order, from the coarse attention channels
 * (-v) or the invariant parameters (-inv); unused by sum and mlp. */
inline float8 ngp_fuse(const float8 *fl, const float8 *sig, __global const float *params)
{
#if VARIANT == VARIANT_MLP
    return ngp_fuse_mlp(fl, params);
#else
    float8 out = (float8)(0.0f);
    const float *a = (const float *)sig;
    for (int l = 0; l < L; ++l) {
#if VARIANT == VARIANT_SUM
        out = out + fl[l];
#elif VARIANT == VARIANT_SHARED_V || VARIANT == VARIANT_SHARED_INV
        out = out + a[l] * fl[l];
#else
        /* Eq. 7-8: omega weighs the density channel, beta the 7 colour channels. */
        out = out + select((float8)(a[2 * l + 1]), (float8)(a[2 * l]),
                           (int8)(-1, 0, 0, 0, 0, 0, 0, 0)) * fl[l];
#endif
    }
    return out;
#endif
}
/* ---- lanes: RAYS rays at once (ngprt_march.cl) ---------------------------------- */
#if !defined(RAYS)
#error "ngprt kernels need -D RAYS (rays per work-item: 1, 2, 4, 8 or 16)"
#endif

/* Vectors of RAYS lanes. Masks are -1 (true) / 0 in every lane, as vector comparisons
 * give them; VMASK turns a scalar comparison (1 / 0) into the same. */
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
#define LANE_F(v, j) (((float *)&(v))[j])
#define LANE_I(v, j) (((int *)&(v))[j])
#define FOR_LANES(j) for (int j = 0; j < RAYS; ++j)

/* Three coordinates of RAYS points. */
typedef struct { vfloat x, y, z; } vpoint;
typedef struct { vint x, y, z; } vcell;

inline vfloat v_min(vfloat a, vfloat b) { return select(b, a, VMASK(a < b)); }
inline vfloat v_max(vfloat a, vfloat b) { return select(b, a, VMASK(a > b)); }
inline vfloat v_abs(vfloat a) { return select(a, -a, VMASK(a < 0.0f)); }

/* floor / ceil as ints, for |x| < 2^31 (ngp_ceil_i per lane). */
inline vint v_floor_i(vfloat x)
{
    const vint i = VI(x);
    return i + VMASK(VF(i) > x);
}

inline vint v_ceil_i(vfloat x)
{
    const vint i = VI(x);
    return i - VMASK(VF(i) < x);
}

/* ---- per lane: space.py and the ray (the functions above, camera.h) ------------- */

/* camera_ray_dir of pixels (px, py), the same operations in the same order. */
inline vpoint v_ray_dir(__global const float *cam, vint px, int py)
{
    const vfloat a = (VF(px) + 0.5f - cam[2]) / cam[0];
    const float b = -(((float)py + 0.5f - cam[3]) / cam[1]);
    vpoint d;
    d.x = cam[4] * a + cam[5] * b - cam[6];
    d.y = cam[7] * a + cam[8] * b - cam[9];
    d.z = cam[10] * a + cam[11] * b - cam[12];
    const vfloat norm = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    d.x = d.x / norm;
    d.y = d.y / norm;
    d.z = d.z / norm;
    return d;
}

#if UNBOUNDED
/* The unbounded step lattice of RAYS rays, one per lane (space.lattice_table, docs/ngprt.md
 * "Step lattice"): the contracted arc length S(t) from the ray's start, in closed form on
 * the pieces between LATTICE_BREAKS sorted breakpoints; lattice point k sits at
 * t_k = S^-1(k * s). Per lane the same float32 operations as the reference; held as
 * vectors so that placing a point costs a few vector selects and one division. */
typedef struct {
    vfloat brk[LATTICE_BREAKS], cum[LATTICE_BREAKS];
    vfloat A[LATTICE_BREAKS - 1], B[LATTICE_BREAKS - 1], K[LATTICE_BREAKS - 1];
} v_lattice;

/* A candidate breakpoint: c where t0 < c < t1 (false for NaN), else t1. */
inline vfloat v_cand(vfloat c, vfloat t0, vfloat t1)
{
    return select(t1, c, VMASK(c > t0) & VMASK(c < t1));
}

/* x, y or z of a point: the one of axis isx ? 0 : (isy ? 1 : 2). */
inline vfloat v_axis(vfloat x, vfloat y, vfloat z, vint isx, vint isy)
{
    return select(select(z, y, isy), x, isx);
}

inline void v_lattice_build(float3 o3, vpoint dv, float near, float far, v_lattice *lt)
{
    const vfloat t0 = (vfloat)(near), t1 = (vfloat)(far);
    const float o[3] = {o3.x, o3.y, o3.z};
    const vfloat d[3] = {dv.x, dv.y, dv.z};
    vfloat c[12];
    int n = 0;
    for (int i = 0; i < 2; ++i)
        for (int j = i + 1; j < 3; ++j) {
            c[n++] = v_cand((o[j] - o[i]) / (d[i] - d[j]), t0, t1);
            c[n++] = v_cand(-(o[i] + o[j]) / (d[i] + d[j]), t0, t1);
        }
    for (int i = 0; i < 3; ++i) {
        c[n++] = v_cand((1.0f - o[i]) / d[i], t0, t1);
        c[n++] = v_cand((-1.0f - o[i]) / d[i], t0, t1);
    }
    /* Sorting network (no NaN, no zero: min/max give the sorted values, as np.sort). */
    for (int i = 0; i < 11; ++i)
        for (int j = 0; j < 11 - i; ++j) {
            const vfloat lo = v_min(c[j], c[j + 1]), hi = v_max(c[j], c[j + 1]);
            c[j] = lo;
            c[j + 1] = hi;
        }
    lt->brk[0] = t0;
    for (int i = 0; i < 12; ++i) lt->brk[i + 1] = c[i];
    lt->brk[LATTICE_BREAKS - 1] = t1;
    lt->cum[0] = (vfloat)(0.0f);
    for (int q = 0; q < LATTICE_BREAKS - 1; ++q) {
        const vfloat ta = lt->brk[q], tb = lt->brk[q + 1];
        const vfloat tm = ta + (tb - ta) * 0.5f;
        const vfloat x0 = o[0] + tm * d[0], x1 = o[1] + tm * d[1], x2 = o[2] + tm * d[2];
        const vfloat ax = v_abs(x0), ay = v_abs(x1), az = v_abs(x2);
        const vfloat mm = v_max(v_max(ax, ay), az);
        const vint isx = VMASK(ax == mm), isy = VMASK(ay == mm);
        const vfloat sg = select((vfloat)(-1.0f), (vfloat)(1.0f),
                                 VMASK(v_axis(x0, x1, x2, isx, isy) > 0.0f));
        const vfloat p0 = o[0] + ta * d[0], p1 = o[1] + ta * d[1], p2 = o[2] + ta * d[2];
        const vfloat ma = sg * v_axis(p0, p1, p2, isx, isy);
        const vfloat b = sg * v_axis(d[0], d[1], d[2], isx, isy);
        const vfloat e0 = d[0] * ma - p0 * b, e1 = d[1] * ma - p1 * b, e2 = d[2] * ma - p2 * b;
        const vfloat K = sqrt(e0 * e0 + e1 * e1 + e2 * e2 + b * b);
        const vint inner = VMASK(mm <= 1.0f);
        lt->A[q] = select(ma * ma, (vfloat)(1.0f), inner);
        lt->B[q] = select(ma * b, (vfloat)(0.0f), inner);
        lt->K[q] = select(K, (vfloat)(1.0f), inner);
        const vfloat tau = tb - ta;
        lt->cum[q + 1] = lt->cum[q] + lt->K[q] * tau / (lt->A[q] + lt->B[q] * tau);
    }
}

/* S^-1(sigma) for 0 <= sigma < S(t_end) (space.lattice_t): piece j = the last q with
 * cum_q <= sigma. */
inline vfloat v_lattice_t(const v_lattice *lt, vfloat sigma)
{
    vfloat c = lt->cum[0], ta = lt->brk[0], tb = lt->brk[1];
    vfloat A = lt->A[0], B = lt->B[0], K = lt->K[0];
    for (int q = 1; q < LATTICE_BREAKS - 1; ++q) {
        const vint m = VMASK(lt->cum[q] <= sigma);
        c = select(c, lt->cum[q], m);
        ta = select(ta, lt->brk[q], m);
        tb = select(tb, lt->brk[q + 1], m);
        A = select(A, lt->A[q], m);
        B = select(B, lt->B[q], m);
        K = select(K, lt->K[q], m);
    }
    const vfloat r = sigma - c;
    const vfloat den = K - B * r;
    return select(tb, v_min(ta + A * r / den, tb), VMASK(den > 0.0f));
}

/* S(t) for t >= t_start, clamped to t_end (space.lattice_s): piece j = the last q with
 * brk_q <= t. */
inline vfloat v_lattice_s(const v_lattice *lt, vfloat t)
{
    t = v_min(t, lt->brk[LATTICE_BREAKS - 1]);
    vfloat c = lt->cum[0], ta = lt->brk[0], A = lt->A[0], B = lt->B[0], K = lt->K[0];
    for (int q = 1; q < LATTICE_BREAKS - 1; ++q) {
        const vint m = VMASK(lt->brk[q] <= t);
        c = select(c, lt->cum[q], m);
        ta = select(ta, lt->brk[q], m);
        A = select(A, lt->A[q], m);
        B = select(B, lt->B[q], m);
        K = select(K, lt->K[q], m);
    }
    const vfloat tau = t - ta;
    return c + K * tau / (A + B * tau);
}

/* ngp_contract per lane. */
inline vpoint v_contract(vpoint x)
{
    const vfloat ax = v_abs(x.x), ay = v_abs(x.y), az = v_abs(x.z);
    const vfloat m = v_max(v_max(ax, ay), az);
    const vfloat m_safe = v_max(m, 1.0f);
    const vfloat sx = x.x / m_safe, sy = x.y / m_safe, sz = x.z / m_safe;
    const vfloat scale = 2.0f - 1.0f / m_safe;
    const vint inner = VMASK(m <= 1.0f);
    vpoint c;
    c.x = select(select(sx, sx * scale, VMASK(ax == m)), x.x, inner);
    c.y = select(select(sy, sy * scale, VMASK(ay == m)), x.y, inner);
    c.z = select(select(sz, sz * scale, VMASK(az == m)), x.z, inner);
    return c;
}
#else
typedef struct { int unused; } v_lattice;   /* bounded: t_k = k * s, no table */
#endif

/* u = to_grid(o + t * d) per lane (ngp_point_u). */
inline vpoint v_point_u(float3 o, vpoint d, vfloat t)
{
    vpoint p;
    p.x = o.x + t * d.x;
    p.y = o.y + t * d.y;
    p.z = o.z + t * d.z;
#if UNBOUNDED
    p = v_contract(p);
#endif
    p.x = (p.x + EXTENT) / (2.0f * EXTENT);
    p.y = (p.y + EXTENT) / (2.0f * EXTENT);
    p.z = (p.z + EXTENT) / (2.0f * EXTENT);
    return p;
}

/* ngp_cell1 per lane, with a per-lane resolution. */
inline vint v_cell1(vfloat v, vint res)
{
    const vfloat hi = VF(res - 1);
    return VI(select(select(v, hi, VMASK(v > hi)), 0.0f, VMASK(v < 0.0f)));
}

inline vcell v_cell(vpoint u, vint res)
{
    const vfloat r = VF(res);
    vcell c;
    c.x = v_cell1(u.x * r, res);
    c.y = v_cell1(u.y * r, res);
    c.z = v_cell1(u.z * r, res);
    return c;
}

inline vint v_flat(vcell i, vint res)
{
    return (i.x * res + i.y) * res + i.z;
}

inline vint v_same_cell(vcell a, vcell b)
{
    return VMASK(a.x == b.x) & VMASK(a.y == b.y) & VMASK(a.z == b.z);
}

/* bytes[idx] of the lanes in mask, 0 elsewhere (the other lanes read bytes[0]: their idx
 * may be out of range). */
inline vint v_gather_u8(__global const uchar *bytes, vint idx, vint mask)
{
    const vint i = select((vint)(0), idx, mask);
    return select((vint)(0), GATHER(bytes, i), mask);
}

/* shorts[idx] of the lanes in mask, 0 elsewhere. */
inline vint v_gather_u16(__global const ushort *shorts, vint idx, vint mask)
{
    const vint i = select((vint)(0), idx, mask);
    return select((vint)(0), GATHER(shorts, i), mask);
}

/* ints[idx] of the lanes in mask, 0 elsewhere. */
inline vint v_gather_i32(__global const int *ints, vint idx, vint mask)
{
    const vint i = select((vint)(0), idx, mask);
    return select((vint)(0), GATHER(ints, i), mask);
}

#endif
