/* Fusion of a sample's fine features by the aggregation variant (-D VARIANT, Table 3;
 * docs/ngprt.md "Fusion", Eq. 6-8; render_ref.fuse). */
#ifndef CLRENDER_NGPRT_FUSION_H
#define CLRENDER_NGPRT_FUSION_H
#pragma OPENCL FP_CONTRACT OFF
#include "ngprt_math.h"
#include "ngprt_model.h"

/* Attention weights of 8 logits at once (render_ref._sigmoid): one vector exp (Eq. 7-8). */
inline float8 sigmoid(float8 x)
{
    return RECIP(1.0f + EXP(-x));
}

/* The `mlp` fusion: relu([f^0 .. f^{L-1}] @ w0 + b0) @ w1 + b1; params packed as
 * [w0 (8L, 64), b0 (64), w1 (64, 8), b1 (8)], every part a multiple of 8 floats, so
 * the hidden layer runs as 8 float8 lanes of 8 units each with aligned reads. */
inline float8 fuse_mlp(const float8 *fl, __global const float *p)
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
inline float8 fuse(const float8 *fl, const float8 *sig, __global const float *params)
{
#if VARIANT == VARIANT_MLP
    return fuse_mlp(fl, params);
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

/* The attention weights of the -inv variants, sigmoid of the invariant logits (N_INV
 * of fusion, padded to float8 chunks); zeros for the other variants. */
inline void inv_sigmoids(__global const float *fusion, float8 *inv_sig)
{
#if INV_VEC > 0
    for (int a = 0; a < INV_VEC; ++a) {
        float8 logit = (float8)(0.0f);
        for (int q = 0; q < 8 && 8 * a + q < N_INV; ++q) ((float *)&logit)[q] = fusion[8 * a + q];
        inv_sig[a] = sigmoid(logit);
    }
#else
    inv_sig[0] = (float8)(0.0f);
#endif
}
#endif
