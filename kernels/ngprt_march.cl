/* NGP-RT ray marching, one work-item per pixel (docs/ngprt.md "The march, per ray").
 *
 * Generates the pixel's ray (camera.h), walks the step lattice t_k = unwarp(k * s),
 * skips empty space with the occupancy mip and (USE_G) the occupancy distance grid G
 * (paper §4.3, Eq. 9), composites the 8 fused features of occupied samples (Eq. 5-8)
 * and stops at T < 2e-3 (S2.5). Mirrors clrender/ngprt/render_ref.py:march_reference.
 *
 * Outputs per pixel n = py * width + px:
 *   feat[8n .. 8n+7] = (acc[0..6], opacity): diffuse rgb (3), specular (4), opacity
 *   depth[n]                         depth_acc / opacity, 0 where opacity is 0
 *   n_march[n], n_occ[n]             marching points and occupied samples
 */
#include "camera.h"
#include "ngprt_common.h"

#define ATT_LEN (ATT_VEC > 0 ? ATT_VEC : 1)

/* Finest level lev (4 .. 0, coarse to fine) at which u is empty, or -1 if occupied at
 * every level. */
inline int ngp_exit_level(float3 u, __global const uchar *occ)
{
    for (int lev = N_MIP - 1; lev >= 0; --lev) {
        const int res = L_C >> lev;
        if (occ[OCC_OFFSET(lev) + ngp_flat(ngp_cell(u, res), res)] == 0) return lev;
    }
    return -1;
}

/* The distance grid value at u (in G-voxels), or 0 when G is not consulted: only for
 * an exit level coarser than G (paper §4.3). */
inline int ngp_g_distance(float3 u, int exit_lev, __global const uchar *G)
{
#if USE_G
    if ((L_C >> exit_lev) < G_RES) return G[ngp_flat(ngp_cell(u, G_RES), G_RES)];
#endif
    return 0;
}

#if !UNBOUNDED
/* Lattice point k (t_k = k * s) lies in cell `cell` at resolution res. */
inline bool ngp_in_cell(int k, float s, float3 o, float3 d, int res, int3 cell)
{
    const int3 c = ngp_cell(ngp_point_u(o, d, (float)k * s), res);
    return c.x == cell.x && c.y == cell.y && c.z == cell.z;
}

/* Bounded skip: closed form, rays are straight in u space. Always returns > k.
 * The float exit distance is off by up to ~1e-7 / |d_a| world units (many steps for a
 * tiny direction component), so the candidate is checked: if point k_next - 1 has left
 * the empty cell, bisect for the first point outside it (per axis the cell of t_k is
 * monotone in k, so the points inside form one run). render_ref.skip_bounded. */
inline int ngp_skip(int k, float t, float3 o, float3 d, float3 u, int exit_lev, int g,
                    float s, float g_end)
{
    const int res = L_C >> exit_lev;
    const float h = 2.0f / (float)res;
    const int3 i = ngp_cell(u, res);
    const float3 lo = (float3)((float)i.x, (float)i.y, (float)i.z) * h - 1.0f;
    const float3 hi = lo + h;
    float t_exit = INFINITY;
    if (d.x != 0.0f) t_exit = ngp_minf(t_exit, ((d.x > 0.0f ? hi.x : lo.x) - o.x) / d.x);
    if (d.y != 0.0f) t_exit = ngp_minf(t_exit, ((d.y > 0.0f ? hi.y : lo.y) - o.y) / d.y);
    if (d.z != 0.0f) t_exit = ngp_minf(t_exit, ((d.z > 0.0f ? hi.z : lo.z) - o.z) / d.z);
    /* Past the end of the ray any k is as good as another: clamp before converting. */
    const float lim = g_end / s + 2.0f;
    int k_next = max(k + 1, ngp_ceil_i(ngp_minf(t_exit / s - 1e-3f, lim)));
    if (k_next - 1 > k && !ngp_in_cell(k_next - 1, s, o, d, res, i)) {
        int k_in = k, k_out = k_next - 1;
        while (k_out - k_in > 1) {
            const int mid = k_in + (k_out - k_in) / 2;
            if (ngp_in_cell(mid, s, o, d, res, i)) k_in = mid; else k_out = mid;
        }
        k_next = k_out;
    }
    if (g > 0) {
        const float r = 2.0f * (float)g / (float)G_RES;
        k_next = max(k_next, ngp_floor_i(ngp_minf((t + r) / s, lim)));
    }
    return k_next;
}
#else
/* Unbounded skip: the contraction bends rays in u space, so walk the lattice with
 * arithmetic only while the point stays in the empty mip cell or in G's empty ball. */
inline int ngp_skip(int k, float t, float3 o, float3 d, float3 u, int exit_lev, int g,
                    float s, float g_end)
{
    const int res = L_C >> exit_lev;
    const int3 cell = ngp_cell(u, res);
    const float radius = (float)g / (float)G_RES;   /* u is in [0, 1]^3 */
    for (k = k + 1; (float)k * s < g_end; ++k) {
        const float3 uk = ngp_point_u(o, d, ngp_unwarp((float)k * s));
        const int3 ck = ngp_cell(uk, res);
        if (ck.x == cell.x && ck.y == cell.y && ck.z == cell.z) continue;
        if (g > 0) {
            const float3 du = uk - u;
            if (sqrt(du.x * du.x + du.y * du.y + du.z * du.z) < radius) continue;
        }
        break;
    }
    return k;
}
#endif

/* The 8 fused features at u (Eq. 6): coarse + fuse(fine levels). */
inline float8 ngp_features(float3 u, __global const int *block_index,
                           __global const float8 *blocks, int n_blocks,
                           __global const float8 *tables, __global const float *fusion)
{
    float8 att[ATT_LEN];
    const float8 coarse = ngp_coarse(u, block_index, blocks, n_blocks, att);
    float8 fl[L];
    for (int l = 0; l < L; ++l) fl[l] = ngp_fine(u, l, tables);
    return coarse + ngp_fuse(fl, att, fusion);
}

__kernel void ngprt_march(__global const float *cam, const int width, const int height,
                          const float s, const float near, const float far,
                          __global const uchar *occ, __global const uchar *G,
                          __global const int *block_index, __global const float8 *blocks,
                          const int n_blocks, __global const float8 *tables,
                          __global const float *fusion,
                          __global float *feat, __global float *depth,
                          __global int *n_march_out, __global int *n_occ_out)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height) return;
    const int n = py * width + px;
    const float3 o = camera_ray_origin(cam), d = camera_ray_dir(cam, px, py);
#if UNBOUNDED
    const float t_start = near, t_end = far;
#else
    const float2 box = ngp_ray_box(o, d);
    const float t_start = fmax(near, box.x), t_end = box.y;
#endif
    const float g_end = ngp_warp(t_end);
    int k = 0;
    int n_march = 0, n_occ = 0;
    float T = 1.0f;
    float opacity = 0.0f, depth_acc = 0.0f;
    float8 acc = (float8)(0.0f);
    /* A missed box (t_start > t_end, or inf/NaN from an axis-parallel ray outside it)
     * has no lattice point; testing first also keeps ceil() of inf out of the int. */
    if (!(t_start <= t_end)) T = 0.0f;
    else k = (int)ceil(ngp_warp(t_start) / s);
    while ((float)k * s < g_end && T >= T_STOP) {
        n_march += 1;
        const float t = ngp_unwarp((float)k * s);
        const float3 u = ngp_point_u(o, d, t);
        const int exit_lev = ngp_exit_level(u, occ);
        if (exit_lev < 0) {
            n_occ += 1;
            const float8 f = ngp_features(u, block_index, blocks, n_blocks, tables, fusion);
            const float sigma = exp(f.s0);
#if UNBOUNDED
            /* unwarp is undefined at g >= 2: the last interval ends at the ray's end. */
            const float delta = ngp_unwarp(ngp_minf((float)(k + 1) * s, g_end)) - t;
#else
            const float delta = (float)(k + 1) * s - t;
#endif
            const float alpha = 1.0f - exp(-sigma * delta);
            const float w = T * alpha;
            acc = acc + w * f;
            opacity = opacity + w;
            depth_acc = depth_acc + w * t;
            T = T * (1.0f - alpha);
            k += 1;
            continue;
        }
        k = ngp_skip(k, t, o, d, u, exit_lev, ngp_g_distance(u, exit_lev, G), s, g_end);
    }
    /* acc.s0 accumulated w * sigma-logit; slot 7 carries the opacity instead. */
    __global float *out = feat + 8 * (size_t)n;
    out[0] = acc.s1; out[1] = acc.s2; out[2] = acc.s3; out[3] = acc.s4;
    out[4] = acc.s5; out[5] = acc.s6; out[6] = acc.s7; out[7] = opacity;
    depth[n] = opacity > 0.0f ? depth_acc / opacity : 0.0f;
    n_march_out[n] = n_march;
    n_occ_out[n] = n_occ;
}
