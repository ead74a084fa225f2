/* The paper's march (-D MARCH_PAPER=1; docs/ngprt.md "The marches", paper §4.3, Fig. 3,
 * Eq. 9; clrender/ngprt/marches.py): the occupancy levels read coarse to fine until one
 * is empty, and with G (USE_G) G's step replacing the mip's where G > 0.
 *
 * The occupancy buffer holds the N_MIP levels as bytes, finest first (level lev at
 * MIP_OFFSET(lev), (OCC_RES >> lev)^3 cells, C order; render_cl.mip_levels).
 */
#ifndef CLRENDER_NGPRT_PAPER_H
#define CLRENDER_NGPRT_PAPER_H
#pragma OPENCL FP_CONTRACT OFF
#include "ngprt_skip.h"
#if MARCH_PAPER

/* First byte of level lev in the concatenated mip (render_cl.mip_levels). */
inline int mip_offset(int lev)
{
    int off = 0;
    for (int l = 0; l < lev; ++l) off += (OCC_RES >> l) * (OCC_RES >> l) * (OCC_RES >> l);
    return off;
}

/* The exit code of each lane in `active` as render_cl.exit_codes' low byte (0: occupied
 * at every level, a sample; else 1 + the first empty level, coarse to fine), from one
 * byte read per level until one is empty (render_ref.exit_level). The cell of level lev
 * is the finest cell shifted right by lev (scaling by 2^lev is exact). */
inline vint exit_code(__global const uchar *mip, Cell3 cell, vint active)
{
    vint code = (vint)(0), undecided = active;
    for (int lev = N_MIP - 1; lev >= 0 && any(undecided); --lev) {
        Cell3 c;
        c.x = cell.x >> lev;
        c.y = cell.y >> lev;
        c.z = cell.z >> lev;
        const vint occ = lane_gather_u8(mip + mip_offset(lev),
                                        flat_index(c, (vint)(OCC_RES >> lev)), undecided);
        const vint empty = undecided & VMASK(occ == 0);
        code = select(code, (vint)(1 + lev), empty);
        undecided = undecided & ~empty;
    }
    return code;
}

#if USE_G
#if !UNBOUNDED
/* Eq. 9, bounded (marches.paper_g_step_bounded): the last lattice point within v * g of
 * t (v = SIDE_F / G_RES world units), at least k + 1. */
inline vint paper_g_step_bounded(const Rays *r, const MarchPoint *p, vint g)
{
    const vfloat radius = SIDE_F * VF(g) / (float)G_RES;
    return max(r->k + 1, lane_floor_i(lane_min((p->t + radius) / r->s, k_limit(r))));
}
#else
/* Eq. 9, unbounded, in contracted arc length (marches.paper_g_step_unbounded):
 * k + floor(4 g / G_RES / s) lattice steps, at least k + 1, at most the first lattice
 * point at or past the next jump of the lane's contracted path (across a jump arc length
 * bounds no distance; docs/ngprt.md "The paper's step with G"); k + 1 from the first
 * lattice point at or past a jump (it may lie on the jump itself). cum is nondecreasing,
 * so the last jump met from the end is the next one ahead. */
inline vint paper_g_step_unbounded(const Rays *r, vint g)
{
    const vint n = lane_floor_i(4.0f * VF(g) / (float)G_RES / r->s);
    const vfloat sigma = lattice_g(r, r->k), prev = lattice_g(r, r->k - 1);
    vfloat end = sigma;
    vint ahead = (vint)(0), first = (vint)(0);
    for (int q = LATTICE_BREAKS - 2; q >= 1; --q) {
        const vint jump = VMASK((r->lt->jumps & (vint)(1 << q)) != 0);
        const vfloat c = r->lt->cum[q];
        first |= jump & VMASK(c > prev) & VMASK(c <= sigma);
        const vint past = jump & VMASK(c > sigma);
        end = select(end, c, past);
        ahead |= past;
    }
    vint k_p = lane_ceil_i(end / r->s);
    k_p = select(k_p, k_p - 1, VMASK(lattice_g(r, k_p - 1) >= end));
    const vint step = select(r->k + n, min(r->k + n, k_p), ahead);
    return select(max(r->k + 1, step), r->k + 1, first);
}
#endif
#endif

/* Next lattice index (> k) of the lanes in `empty`, whose exit code is `code`: with G,
 * G's step where G is read (exit level coarser than G) and g > 0, else the mip's
 * (skip, which reads no G in this build: ngprt_skip.h); render_ref._skip, march "paper". */
inline vint paper_skip(const Model *m, const Rays *r, const MarchPoint *p,
                       vint empty, vint code)
{
#if USE_G
    const vint lev = code - 1;
    const vint read = empty & VMASK(((vint)(OCC_RES) >> lev) < G_RES);
    vint g = (vint)(0);
    if (any(read))
        g = lane_gather_u8(m->G, flat_index(cells(p->u, (vint)(G_RES)), (vint)(G_RES)), read);
    const vint jump = read & VMASK(g > 0), mip = empty & ~jump;
    vint k = r->k;
    if (any(mip)) k = select(k, skip(m, r, p, mip, code), mip);
#if UNBOUNDED
    if (any(jump)) k = select(k, paper_g_step_unbounded(r, g), jump);
#else
    if (any(jump)) k = select(k, paper_g_step_bounded(r, p, g), jump);
#endif
    return k;
#else
    return skip(m, r, p, empty, code);
#endif
}
#endif  /* MARCH_PAPER */
#endif
