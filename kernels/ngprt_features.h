/* The 8 features of a sample (docs/ngprt.md "Features", Eq. 6): trilinear coarse
 * features and attention from the sparse coarse grid, trilinear features of the L hash
 * levels, fused (ngprt_fusion.h); render_ref.features. Corner indices and weights are
 * computed for all lanes at once, the gathers lane by lane, back to back. */
#ifndef CLRENDER_NGPRT_FEATURES_H
#define CLRENDER_NGPRT_FEATURES_H
#pragma OPENCL FP_CONTRACT OFF
#include "ngprt_fusion.h"
#include "ngprt_space.h"

/* Corners a sample reads: 8 of the coarse cell, then 8 per fine level. Per lane, corner q
 * has an index idx[q] (coarse: the corner's first float8 in blocks; fine: the entry in
 * tables, level l's table first) and a trilinear weight wt[q]; two arrays, not a struct,
 * as they are read lane by lane at run time (ngprt_space.h, Rays). */
#define N_CORNERS (8 * (1 + L))

/* Trilinear weights of the 8 corners into wt[0..7], corner c = (cx << 2) | (cy << 1) | cz
 * (render_ref._trilinear_weights). */
inline void trilinear_weights(vfloat wx, vfloat wy, vfloat wz, vfloat *wt)
{
    for (int c = 0; c < 8; ++c)
        wt[c] = ((c & 4) ? wx : 1.0f - wx) * ((c & 2) ? wy : 1.0f - wy)
                * ((c & 1) ? wz : 1.0f - wz);
}

/* Corners 0..7 of the coarse cell of each lane in `sample` (render_ref.coarse_features):
 * an absent block (never for an occupied cell) gets weight 0 and index 0. The coarse cell
 * is the occupancy cell shifted right by OCC_SHIFT: floor(2^j x) >> j = floor(x) for
 * x >= 0, and scaling by 2^j is exact, clamping included. */
inline void coarse_corners(const Model *m, const MarchPoint *p, vint sample,
                           vint *idx, vfloat *wt)
{
    Cell3 c0, bi, r;
    c0.x = p->cell.x >> OCC_SHIFT;
    c0.y = p->cell.y >> OCC_SHIFT;
    c0.z = p->cell.z >> OCC_SHIFT;
    bi.x = c0.x / COARSE_BLOCK;
    bi.y = c0.y / COARSE_BLOCK;
    bi.z = c0.z / COARSE_BLOCK;
    r.x = c0.x - bi.x * COARSE_BLOCK;
    r.y = c0.y - bi.y * COARSE_BLOCK;
    r.z = c0.z - bi.z * COARSE_BLOCK;
    const vint b = lane_gather_i32(m->block_index,
                                   flat_index(bi, (vint)(COARSE_BLOCKS_PER_AXIS)), sample);
    const vint present = sample & VMASK(b >= 0) & VMASK(b < m->n_blocks);
    const vint base = select((vint)(0), (((b * COARSE_CORNERS + r.x) * COARSE_CORNERS + r.y)
                                         * COARSE_CORNERS + r.z) * (1 + ATT_VEC), present);
    const Point3 u = p->u;
    trilinear_weights(u.x * (float)L_C - VF(c0.x), u.y * (float)L_C - VF(c0.y),
                      u.z * (float)L_C - VF(c0.z), wt);
    for (int q = 0; q < 8; ++q) {
        const int corner = ((((q >> 2) & 1) * COARSE_CORNERS + ((q >> 1) & 1)) * COARSE_CORNERS
                            + (q & 1)) * (1 + ATT_VEC);
        idx[q] = base + corner;
        wt[q] = select((vfloat)(0.0f), wt[q], present);
    }
}

/* The 8 corners of each fine level l (resolution L_C * 2^(l+1); render_ref.fine_features)
 * into corners 8 (l + 1) .. 8 (l + 1) + 7, hashed (encoding.hash_corner). */
inline void fine_corners(const MarchPoint *p, vint *idx, vfloat *wt)
{
    const Point3 u = p->u;
    for (int l = 0; l < L; ++l) {
        const float res = (float)(L_C << (l + 1));
        const vfloat px = u.x * res, py = u.y * res, pz = u.z * res;
        const vint ix = lane_floor_i(px), iy = lane_floor_i(py), iz = lane_floor_i(pz);
        trilinear_weights(px - VF(ix), py - VF(iy), pz - VF(iz), wt + 8 * (l + 1));
        for (int q = 0; q < 8; ++q) {
            const vuint h = (AS_VU(ix + ((q >> 2) & 1)) * HASH_X)
                            ^ (AS_VU(iy + ((q >> 1) & 1)) * HASH_Y)
                            ^ (AS_VU(iz + (q & 1)) * HASH_Z);
            idx[8 * (l + 1) + q] = AS_VI(h & TABLE_MASK) + l * (1 << LOG2_T);
        }
    }
}

/* The 8 fused features of lane j's sample (Eq. 6, render_ref.features): coarse +
 * fuse(fine levels), from its corners, summed in the reference's order. The gathers depend
 * on nothing but the indices, so a CPU issues them back to back. inv_sig: the -inv
 * variants' attention weights (Model.inv_sig). */
inline float8 features(int j, const vint *idx, const vfloat *wt,
                       __global const float8 *blocks, __global const table_t *tables,
                       __global const float *fusion, const float8 *inv_sig)
{
    float8 coarse = (float8)(0.0f), sig[SIG_LEN];
    for (int a = 0; a < SIG_LEN; ++a) sig[a] = (float8)(0.0f);
    for (int c = 0; c < 8; ++c) {
        const float w = LANE_F(wt[c], j);
        __global const float8 *corner = blocks + LANE_I(idx[c], j);
        coarse = coarse + w * corner[0];
        for (int a = 0; a < ATT_VEC; ++a) sig[a] = sig[a] + w * corner[1 + a];
    }
#if ATT_VEC > 0
    for (int a = 0; a < ATT_VEC; ++a) sig[a] = sigmoid(sig[a]);
#else
    for (int a = 0; a < SIG_LEN; ++a) sig[a] = inv_sig[a];
#endif
    float8 fl[L];
    for (int l = 0; l < L; ++l) {
        fl[l] = (float8)(0.0f);
        for (int c = 8 * (l + 1); c < 8 * (l + 2); ++c)
            fl[l] = fl[l] + LANE_F(wt[c], j) * TABLE_ENTRY(tables, LANE_I(idx[c], j));
    }
    return coarse + fuse(fl, sig, fusion);
}
#endif
