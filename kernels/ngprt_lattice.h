/* The unbounded step lattice and MERF's contraction, per lane (clrender/ngprt/space.py,
 * docs/ngprt.md "Step lattice"). A bounded scene has no table: t_k = k * s. */
#ifndef CLRENDER_NGPRT_LATTICE_H
#define CLRENDER_NGPRT_LATTICE_H
#pragma OPENCL FP_CONTRACT OFF
#include "ngprt_lanes.h"

#if UNBOUNDED
/* The unbounded step lattice of RAYS rays, one per lane (space.lattice_table, docs/ngprt.md
 * "Step lattice"): the contracted arc length S(t) from the ray's start, in closed form on
 * the pieces between LATTICE_BREAKS sorted breakpoints; lattice point k sits at
 * t_k = S^-1(k * s). Per lane the same float32 operations as the reference; held as
 * vectors so that placing a point costs a few vector selects and one division. */
typedef struct {
    vfloat brk[LATTICE_BREAKS], cum[LATTICE_BREAKS];
    vfloat A[LATTICE_BREAKS - 1], B[LATTICE_BREAKS - 1], K[LATTICE_BREAKS - 1];
#if MARCH_PAPER && USE_G
    vint jumps;            /* bit q: breakpoint q is a jump of the path (space.lattice_jumps) */
#endif
} Lattice;

/* A candidate breakpoint: c where t0 < c < t1 (false for NaN), else t1. */
inline vfloat candidate(vfloat c, vfloat t0, vfloat t1)
{
    return select(t1, c, VMASK(c > t0) & VMASK(c < t1));
}

/* x, y or z of a point: the one of axis isx ? 0 : (isy ? 1 : 2). */
inline vfloat axis_value(vfloat x, vfloat y, vfloat z, vint isx, vint isy)
{
    return select(select(z, y, isy), x, isx);
}

/* Each lane's lattice table over [near, far] into *lt (space.lattice_table; the paper's
 * march with G also marks the jumps, space.lattice_jumps). */
inline void lattice_table(float3 o3, Point3 dv, float near, float far, Lattice *lt)
{
    const vfloat t0 = (vfloat)(near), t1 = (vfloat)(far);
    const float o[3] = {o3.x, o3.y, o3.z};
    const vfloat d[3] = {dv.x, dv.y, dv.z};
    vfloat c[12];
    int n = 0;
    for (int i = 0; i < 2; ++i)
        for (int j = i + 1; j < 3; ++j) {
            c[n++] = candidate((o[j] - o[i]) / (d[i] - d[j]), t0, t1);
            c[n++] = candidate(-(o[i] + o[j]) / (d[i] + d[j]), t0, t1);
        }
    for (int i = 0; i < 3; ++i) {
        c[n++] = candidate((1.0f - o[i]) / d[i], t0, t1);
        c[n++] = candidate((-1.0f - o[i]) / d[i], t0, t1);
    }
    /* Sorting network (no NaN, no zero: min/max give the sorted values, as np.sort). */
    for (int i = 0; i < 11; ++i)
        for (int j = 0; j < 11 - i; ++j) {
            const vfloat lo = lane_min(c[j], c[j + 1]), hi = lane_max(c[j], c[j + 1]);
            c[j] = lo;
            c[j + 1] = hi;
        }
    lt->brk[0] = t0;
    for (int i = 0; i < 12; ++i) lt->brk[i + 1] = c[i];
    lt->brk[LATTICE_BREAKS - 1] = t1;
    lt->cum[0] = (vfloat)(0.0f);
#if MARCH_PAPER && USE_G
    vint region_before = (vint)(-1);
    lt->jumps = (vint)(0);
#endif
    for (int q = 0; q < LATTICE_BREAKS - 1; ++q) {
        const vfloat ta = lt->brk[q], tb = lt->brk[q + 1];
        const vfloat tm = ta + (tb - ta) * 0.5f;
        const vfloat x0 = o[0] + tm * d[0], x1 = o[1] + tm * d[1], x2 = o[2] + tm * d[2];
        const vfloat ax = lane_abs(x0), ay = lane_abs(x1), az = lane_abs(x2);
        const vfloat mm = lane_max(lane_max(ax, ay), az);
        const vint isx = VMASK(ax == mm), isy = VMASK(ay == mm);
        const vfloat sg = select((vfloat)(-1.0f), (vfloat)(1.0f),
                                 VMASK(axis_value(x0, x1, x2, isx, isy) > 0.0f));
        const vfloat p0 = o[0] + ta * d[0], p1 = o[1] + ta * d[1], p2 = o[2] + ta * d[2];
        const vfloat ma = sg * axis_value(p0, p1, p2, isx, isy);
        const vfloat b = sg * axis_value(d[0], d[1], d[2], isx, isy);
        const vfloat e0 = d[0] * ma - p0 * b, e1 = d[1] * ma - p1 * b, e2 = d[2] * ma - p2 * b;
        const vfloat K = sqrt(e0 * e0 + e1 * e1 + e2 * e2 + b * b);
        const vint inner = VMASK(mm <= 1.0f);
#if MARCH_PAPER && USE_G
        /* The piece's region: -1 inside the cube, else 2 * axis + (x_axis > 0). */
        const vint region = select(select(select((vint)(4), (vint)(2), isy), (vint)(0), isx)
                                   + select((vint)(0), (vint)(1), VMASK(sg > 0.0f)),
                                   (vint)(-1), inner);
        if (q > 0)
            lt->jumps |= select((vint)(0), (vint)(1 << q), VMASK(region_before >= 0)
                                & VMASK(region >= 0) & VMASK(region_before != region));
        region_before = region;
#endif
        lt->A[q] = select(ma * ma, (vfloat)(1.0f), inner);
        lt->B[q] = select(ma * b, (vfloat)(0.0f), inner);
        lt->K[q] = select(K, (vfloat)(1.0f), inner);
        const vfloat tau = tb - ta;
        lt->cum[q + 1] = lt->cum[q] + lt->K[q] * tau / (lt->A[q] + lt->B[q] * tau);
    }
}

/* S^-1(sigma) for 0 <= sigma < S(t_end) (space.lattice_t): piece j = the last q with
 * cum_q <= sigma. */
inline vfloat lattice_t(const Lattice *lt, vfloat sigma)
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
    return select(tb, lane_min(ta + A * r / den, tb), VMASK(den > 0.0f));
}

/* S(t) for t >= t_start, clamped to t_end (space.lattice_s): piece j = the last q with
 * brk_q <= t. */
inline vfloat lattice_s(const Lattice *lt, vfloat t)
{
    t = lane_min(t, lt->brk[LATTICE_BREAKS - 1]);
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

/* MERF contraction into [-2, 2]^3 per lane (space.contract). */
inline Point3 contract(Point3 x)
{
    const vfloat ax = lane_abs(x.x), ay = lane_abs(x.y), az = lane_abs(x.z);
    const vfloat m = lane_max(lane_max(ax, ay), az);
    const vfloat m_safe = lane_max(m, 1.0f);
    const vfloat sx = x.x / m_safe, sy = x.y / m_safe, sz = x.z / m_safe;
    const vfloat scale = 2.0f - 1.0f / m_safe;
    const vint inner = VMASK(m <= 1.0f);
    Point3 c;
    c.x = select(select(sx, sx * scale, VMASK(ax == m)), x.x, inner);
    c.y = select(select(sy, sy * scale, VMASK(ay == m)), x.y, inner);
    c.z = select(select(sz, sz * scale, VMASK(az == m)), x.z, inner);
    return c;
}
#else
typedef struct { int unused; } Lattice;     /* bounded: t_k = k * s, no table */
#endif

#endif
