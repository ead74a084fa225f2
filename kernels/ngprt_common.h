/* NGP-RT device helpers of ngprt_march.cl.
 *
 * Mirrors clrender/ngprt/space.py, encoding.py and render_ref.py operation for
 * operation (docs/ngprt.md is the contract): FP contraction is off and the build asks
 * for correctly rounded division and sqrt, so positions, cells and lattice indices are
 * bit-identical to the numpy reference; exp-based values may differ by a few ulps.
 *
 * Every constant comes as a -D define from clrender/ngprt/render_cl.py:kernel_defines,
 * so Python and OpenCL share one definition (clrender/ngprt/config.py):
 *   shared constants (config.kernel_constants): T_STOP, N_MIP, FEATURES, FUSION_HIDDEN
 *     and the variant codes VARIANT_SUM .. VARIANT_SEPARATE_V (config.VARIANT_CODES);
 *     SH_DIM and DEFERRED_HIDDEN come too, for the deferred MLP;
 *   per model: L, L_C, LOG2_T, COARSE_BLOCK, G_RES, N_ATT (attention channels in the
 *     coarse grid), N_INV (spatially invariant logits), VARIANT, UNBOUNDED, USE_G.
 * A missing define fails the build: an undefined name is 0 in #if, which would
 * silently pick VARIANT_SUM's code or a zero T_STOP.
 */
#ifndef CLRENDER_NGPRT_COMMON_H
#define CLRENDER_NGPRT_COMMON_H
#pragma OPENCL FP_CONTRACT OFF

#if !defined(T_STOP) || !defined(N_MIP) || !defined(FEATURES) || !defined(FUSION_HIDDEN)
#error "ngprt kernels need -D T_STOP N_MIP FEATURES FUSION_HIDDEN (config.kernel_constants)"
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
/* The code's shape fixes these: features travel as float8, the mip offsets below
 * spell out 5 levels, the mlp fusion runs its hidden layer in float8 lanes. */
#if FEATURES != 8
#error "FEATURES must be 8: features are held in float8"
#endif
#if N_MIP != 5
#error "N_MIP must be 5: OCC_OFFSET spells out five levels"
#endif
#if FUSION_HIDDEN % 8 != 0
#error "FUSION_HIDDEN must be a multiple of 8"
#endif

#define TABLE_MASK ((1u << LOG2_T) - 1u)
/* A coarse corner holds 8 + N_ATT channels; the renderer pads each corner to a
 * multiple of 8 floats (COARSE_STRIDE) so every read is an aligned float8. */
#define ATT_VEC ((N_ATT + 7) / 8)                 /* float8 chunks of attention logits */
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

/* floor(x) as an int, for |x| < 2^31. */
inline int ngp_floor_i(float x)
{
    const int i = (int)x;
    return (float)i > x ? i - 1 : i;
}

/* ceil(x) as an int, for |x| < 2^31. */
inline int ngp_ceil_i(float x)
{
    const int i = (int)x;
    return (float)i < x ? i + 1 : i;
}

/* Occupancy mip level `lev` (resolution L_C >> lev) starts at OCC_OFFSET(lev) in the
 * concatenated uint8 buffer. */
#define OCC_VOX(lev) ((L_C >> (lev)) * (L_C >> (lev)) * (L_C >> (lev)))
#define OCC_OFFSET(lev) (((lev) > 0 ? OCC_VOX(0) : 0) + ((lev) > 1 ? OCC_VOX(1) : 0) \
                         + ((lev) > 2 ? OCC_VOX(2) : 0) + ((lev) > 3 ? OCC_VOX(3) : 0))

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

/* Warped distance g(t) and its inverse (space.warp / space.unwarp). */
inline float ngp_warp(float t)
{
#if UNBOUNDED
    return t <= 1.0f ? t : 2.0f - 1.0f / ngp_maxf(t, 1.0f);
#else
    return t;
#endif
}

inline float ngp_unwarp(float g)
{
#if UNBOUNDED
    return g <= 1.0f ? g : 1.0f / (2.0f - ngp_maxf(g, 1.0f));
#else
    return g;
#endif
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

/* Flat C-order index of cell i in a res^3 grid. */
inline int ngp_flat(int3 i, int res)
{
    return (i.x * res + i.y) * res + i.z;
}

/* Entry and exit distances of the ray with [-1, 1]^3 (space.ray_box); t_in > t_out
 * when the ray misses. fmin/fmax drop the NaN of 0 * inf like numpy's fmin/fmax. */
inline float2 ngp_ray_box(float3 o, float3 d)
{
    const float3 inv = 1.0f / d;
    const float3 t0 = (-1.0f - o) * inv;
    const float3 t1 = (1.0f - o) * inv;
    const float3 lo = fmin(t0, t1), hi = fmax(t0, t1);
    return (float2)(fmax(fmax(lo.x, lo.y), lo.z), fmin(fmin(hi.x, hi.y), hi.z));
}

/* ---- encoding.py --------------------------------------------------------------- */

/* Instant-NGP hash of an integer corner into [0, T) (encoding.hash_corner). */
inline uint ngp_hash(int3 c)
{
    return (((uint)c.x * 1u) ^ ((uint)c.y * 2654435761u) ^ ((uint)c.z * 805459861u))
           & TABLE_MASK;
}

inline float ngp_sigmoid(float x)
{
    return 1.0f / (1.0f + exp(-x));
}

/* ---- features at a sample (docs/ngprt.md, Eq. 6-8) ----------------------------- */

/* Trilinear weights of the 8 corners, corner index (cx << 2) | (cy << 1) | cz. */
inline void ngp_trilinear_weights(float3 w, float *wc)
{
    for (int c = 0; c < 8; ++c) {
        const float wx = (c & 4) ? w.x : 1.0f - w.x;
        const float wy = (c & 2) ? w.y : 1.0f - w.y;
        const float wz = (c & 1) ? w.z : 1.0f - w.z;
        wc[c] = wx * wy * wz;
    }
}

/* Coarse features (8) and attention logits (N_ATT, into att, padded to 8 * ATT_VEC)
 * at u from the sparse coarse grid; zeros when the block is absent (never for an
 * occupied cell). */
inline float8 ngp_coarse(float3 u, __global const int *block_index,
                         __global const float8 *blocks, int n_blocks, float8 *att)
{
    const int3 i = ngp_cell(u, L_C);
    const float3 w = u * (float)L_C - (float3)((float)i.x, (float)i.y, (float)i.z);
    const int3 bi = i / COARSE_BLOCK, r = i - bi * COARSE_BLOCK;
    const int b = block_index[ngp_flat(bi, COARSE_BLOCKS_PER_AXIS)];
    float8 f = (float8)(0.0f);
    for (int a = 0; a < ATT_VEC; ++a) att[a] = (float8)(0.0f);
    if (b < 0 || b >= n_blocks) return f;
    float wc[8];
    ngp_trilinear_weights(w, wc);
    for (int c = 0; c < 8; ++c) {
        const int3 j = r + (int3)((c >> 2) & 1, (c >> 1) & 1, c & 1);
        __global const float8 *corner = blocks + (((b * COARSE_CORNERS + j.x) * COARSE_CORNERS
                                                   + j.y) * COARSE_CORNERS + j.z) * (1 + ATT_VEC);
        f = f + wc[c] * corner[0];
        for (int a = 0; a < ATT_VEC; ++a) att[a] = att[a] + wc[c] * corner[1 + a];
    }
    return f;
}

/* Fine features of hash level l (resolution L_C * 2^(l+1)): 8 aligned float8 gathers. */
inline float8 ngp_fine(float3 u, int l, __global const float8 *tables)
{
    const float3 p = u * (float)(L_C << (l + 1));
    const int3 i = (int3)(ngp_floor_i(p.x), ngp_floor_i(p.y), ngp_floor_i(p.z));
    const float3 w = p - (float3)((float)i.x, (float)i.y, (float)i.z);
    float wc[8];
    ngp_trilinear_weights(w, wc);
    __global const float8 *table = tables + (size_t)l * (1u << LOG2_T);
    float8 f = (float8)(0.0f);
    for (int c = 0; c < 8; ++c) {
        const int3 j = i + (int3)((c >> 2) & 1, (c >> 1) & 1, c & 1);
        f = f + wc[c] * table[ngp_hash(j)];
    }
    return f;
}

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

/* Fusion of the fine features by VARIANT (docs/ngprt.md "Fusion"): logits come from
 * the coarse attention channels (-v) or the invariant parameters (-inv). */
inline float8 ngp_fuse(const float8 *fl, const float8 *att8, __global const float *params)
{
#if VARIANT == VARIANT_MLP
    return ngp_fuse_mlp(fl, params);
#else
    float8 out = (float8)(0.0f);
    for (int l = 0; l < L; ++l) {
#if VARIANT == VARIANT_SUM
        out = out + fl[l];
#else
#if VARIANT == VARIANT_SHARED_V || VARIANT == VARIANT_SEPARATE_V
        const float *logit = (const float *)att8;
#else
        float logit[N_INV];
        for (int a = 0; a < N_INV; ++a) logit[a] = params[a];
#endif
#if VARIANT == VARIANT_SHARED_V || VARIANT == VARIANT_SHARED_INV
        out = out + ngp_sigmoid(logit[l]) * fl[l];
#else
        /* Eq. 7-8: omega weighs the density channel, beta the 7 colour channels. */
        const float omega = ngp_sigmoid(logit[2 * l]), beta = ngp_sigmoid(logit[2 * l + 1]);
        out = out + select((float8)(beta), (float8)(omega), (int8)(-1, 0, 0, 0, 0, 0, 0, 0))
                    * fl[l];
#endif
#endif
    }
    return out;
#endif
}
#endif
