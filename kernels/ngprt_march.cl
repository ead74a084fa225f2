/* NGP-RT ray marching (docs/ngprt.md "The march, per ray").
 *
 * Each work-item marches RAYS neighbouring pixels of one row (-D RAYS = 1, 2, 4, 8 or
 * 16), one ray per lane of a vector, in lockstep like the numpy reference
 * (clrender/ngprt/render_ref.py:march_reference): every pass of the loop places the
 * current lattice point t_k (k * s, or S^-1(k * s) unbounded) of all lanes at once and reads one ushort
 * per lane, the exit code of its finest cell (render_cl.exit_codes: low byte 0 occupied,
 * else 1 + the exit level, as the mip is a max-pool and the finest cell decides every
 * level; high byte G where it is read, G_IN_CODE), skips empty space with the mip and
 * (USE_G) the occupancy distance grid G (paper §4.3, Eq. 9),
 * and composites the 8 fused features of the occupied lanes (Eq. 5-8) until T < T_STOP
 * (S2.5): corner indices and trilinear weights for all lanes at once, then each sample's
 * gathers back to back, then density and alpha as vectors. Lanes advance independently;
 * a finished lane idles. The lanes give a CPU driver SIMD and independent work to
 * overlap; GPUs take RAYS = 1, one ray per work-item (render_cl.lane_width).
 *
 * Outputs per pixel n = py * width + px:
 *   feat[8n .. 8n+7] = (acc[0..6], opacity): diffuse rgb (3), specular (4), opacity
 *   depth[n]                         depth_acc / opacity, 0 where opacity is 0
 *   n_march[n], n_occ[n]             marching points and occupied samples
 */
#include "camera.h"
#include "ngprt_common.h"

#if !defined(G_IN_CODE)
#error "ngprt_march.cl needs -D G_IN_CODE (render_cl.kernel_defines)"
#endif

/* ---- empty-space skipping ------------------------------------------------------ */

/* The distance grid value (G-voxels) of the lanes in `read`, else 0 (paper §4.3: read
 * only when the exit level is coarser than G): from the exit code's high byte
 * (G_IN_CODE, render_cl.exit_codes) or from G. */
inline vint v_g_distance(vpoint u, vint read, vint g_code, __global const uchar *G)
{
#if USE_G && G_IN_CODE
    return select((vint)(0), g_code, read);      /* exit_codes put it there */
#elif USE_G
    if (any(read)) return v_gather_u8(G, v_flat(v_cell(u, (vint)(G_RES)), (vint)(G_RES)), read);
#endif
    return (vint)(0);
}

#if !UNBOUNDED
/* Lattice point k (t_k = k * s) lies in cell `cell` at resolution res (one lane). */
inline bool ngp_in_cell(int k, float s, float3 o, float3 d, int res, int3 cell)
{
    const int3 c = ngp_cell(ngp_point_u(o, d, (float)k * s), res);
    return c.x == cell.x && c.y == cell.y && c.z == cell.z;
}

/* First lattice point outside `cell` in (k_in, k_out]: k_in is inside, k_out outside.
 * Per axis the cell of t_k is monotone in k, so the points inside form one run. */
inline int ngp_first_outside(int k_in, int k_out, float s, float3 o, float3 d, int res,
                             int3 cell)
{
    while (k_out - k_in > 1) {
        const int mid = k_in + (k_out - k_in) / 2;
        if (ngp_in_cell(mid, s, o, d, res, cell)) k_in = mid; else k_out = mid;
    }
    return k_out;
}

/* Bounded skip of the lanes in `empty`: closed form, rays are straight in u space.
 * Always > k. The float exit distance is off by up to ~1e-7 / |d_a| world units (many
 * steps for a tiny direction component), so the candidate is checked: if point
 * k_next - 1 has left the empty cell, bisect for the first point outside it.
 * render_ref.skip_bounded. */
inline vint v_skip(vint k, vfloat t, float3 o, vpoint d, vpoint u, vcell c0, vint empty,
                   vint lev, vint g_code, float s, vfloat g_end, __global const uchar *G,
                   const v_lattice *lt)
{
    const vint res = (vint)(L_C) >> lev;
    /* 2 / res: L_C >> lev = L_C / 2^lev exactly, and scaling by 2^lev is exact. */
    const vfloat h = (2.0f / (float)L_C) * VF((vint)(1) << lev);
    vcell i;
    i.x = c0.x >> lev;
    i.y = c0.y >> lev;
    i.z = c0.z >> lev;
    const vfloat lo_x = VF(i.x) * h - 1.0f, lo_y = VF(i.y) * h - 1.0f, lo_z = VF(i.z) * h - 1.0f;
    const vfloat hi_x = lo_x + h, hi_y = lo_y + h, hi_z = lo_z + h;
    vfloat t_exit = (vfloat)(INFINITY);
    t_exit = select(t_exit, v_min(t_exit, (select(lo_x, hi_x, VMASK(d.x > 0.0f)) - o.x) / d.x),
                    VMASK(d.x != 0.0f));
    t_exit = select(t_exit, v_min(t_exit, (select(lo_y, hi_y, VMASK(d.y > 0.0f)) - o.y) / d.y),
                    VMASK(d.y != 0.0f));
    t_exit = select(t_exit, v_min(t_exit, (select(lo_z, hi_z, VMASK(d.z > 0.0f)) - o.z) / d.z),
                    VMASK(d.z != 0.0f));
    /* Past the end of the ray any k is as good as another: clamp before converting. */
    const vfloat lim = g_end / s + 2.0f;
    vint k_next = max(k + 1, v_ceil_i(v_min(t_exit / s - 1e-3f, lim)));
    const vint check = empty & VMASK(k_next - 1 > k);
    if (any(check)) {
        const vint k_last = select(k, k_next - 1, check);
        const vint outside = check & ~v_same_cell(v_cell(v_point_u(o, d, VF(k_last) * s), res), i);
        FOR_LANES(j) {
            if (!LANE_I(outside, j)) continue;
            const float3 dj = (float3)(LANE_F(d.x, j), LANE_F(d.y, j), LANE_F(d.z, j));
            const int3 ij = (int3)(LANE_I(i.x, j), LANE_I(i.y, j), LANE_I(i.z, j));
            LANE_I(k_next, j) = ngp_first_outside(LANE_I(k, j), LANE_I(k_last, j), s, o, dj,
                                                  LANE_I(res, j), ij);
        }
    }
    const vint g = v_g_distance(u, empty & VMASK(res < G_RES), g_code, G);
    if (!any(VMASK(g > 0))) return k_next;
    const vfloat r = 2.0f * VF(g) / (float)G_RES;
    const vint k_g = v_floor_i(v_min((t + r) / s, lim));
    return select(k_next, max(k_next, k_g), VMASK(g > 0));
}
#else
/* Unbounded skip, closed form (render_ref._box_exit, skip_unbounded): a box is shrunk
 * by 1/64 of its grid cell on every face; the outer regions of the contraction keep
 * 2^-10 |x|_inf away from the planes |x_b| = |x_a| where it switches axis (a jump); the
 * cube inscribed in G's ball has half-side CUBE (< 1/sqrt(3)) of its radius. */
#define BOX_MARGIN (1.0f / 64.0f)
#define REGION_SCALE (1.0f - 1.0f / 1024.0f)
#define CUBE 0.57735f

/* A face f + beta (t' - t) >= 0 of a box (where `on`): the point at t must satisfy it,
 * and it bounds t' - t by f / -beta when beta < 0. */
inline void ngp_face(float f, float beta, bool on, float *dt, bool *inside)
{
    if (!on) return;
    *inside = *inside && f >= 0.0f;
    if (beta < 0.0f) *dt = ngp_minf(*dt, f / -beta);
}

/* The largest t' >= t such that the ray stays in the box [lo, hi] (contracted space)
 * over [t, t'] within the projective region of the contraction it is in at t; t when
 * the point at t is outside. Inside |x|_inf <= 1, c = x; outside, with a the axis of
 * |x|_inf = sg * x_a = m, c_b = x_b / m and sg * c_a = 2 - 1/m: every face is linear in
 * t' there. */
inline float ngp_box_exit(float3 o, float3 d3, float t, float3 lo3, float3 hi3)
{
    const float3 p3 = o + t * d3;
    const float p[3] = {p3.x, p3.y, p3.z}, d[3] = {d3.x, d3.y, d3.z};
    const float lo[3] = {lo3.x, lo3.y, lo3.z}, hi[3] = {hi3.x, hi3.y, hi3.z};
    const float ax = ngp_absf(p[0]), ay = ngp_absf(p[1]), az = ngp_absf(p[2]);
    const float m = ngp_maxf(ngp_maxf(ax, ay), az);
    const int a = ax == m ? 0 : (ay == m ? 1 : 2);
    const float sg = p[a] > 0.0f ? 1.0f : -1.0f;
    const float ms = sg * p[a], dm = sg * d[a];
    const bool inner = m <= 1.0f;
    float dt = INFINITY;
    bool inside = true;
    for (int b = 0; b < 3; ++b) {
        ngp_face(p[b] - lo[b], d[b], inner, &dt, &inside);
        ngp_face(hi[b] - p[b], -d[b], inner, &dt, &inside);
        ngp_face(1.0f - p[b], -d[b], inner, &dt, &inside);
        ngp_face(1.0f + p[b], d[b], inner, &dt, &inside);
        const bool other = !inner && a != b;
        ngp_face(ms * REGION_SCALE - p[b], dm * REGION_SCALE - d[b], other, &dt, &inside);
        ngp_face(ms * REGION_SCALE + p[b], dm * REGION_SCALE + d[b], other, &dt, &inside);
        ngp_face(p[b] - lo[b] * ms, d[b] - lo[b] * dm, other, &dt, &inside);
        ngp_face(hi[b] * ms - p[b], hi[b] * dm - d[b], other, &dt, &inside);
    }
    if (!inner) {
        ngp_face(ms - 1.0f, dm, true, &dt, &inside);
        const float lo_a = sg > 0.0f ? lo[a] : -hi[a], hi_a = sg > 0.0f ? hi[a] : -lo[a];
        if (lo_a < 2.0f) ngp_face(ms - 1.0f / (2.0f - lo_a), dm, true, &dt, &inside);
        else inside = false;
        if (hi_a < 2.0f) ngp_face(1.0f / (2.0f - hi_a) - ms, -dm, true, &dt, &inside);
    }
    return inside ? t + dt : t;
}

/* Lane j of three vectors. */
inline float3 ngp_lane3(vfloat x, vfloat y, vfloat z, int j)
{
    return (float3)(LANE_F(x, j), LANE_F(y, j), LANE_F(z, j));
}

/* Unbounded skip of the lanes in `empty` (no memory read but G): the first lattice point
 * outside both the empty mip cell and, when G was read, the ball of radius g / G_RES (u
 * units) about u, as a walk point by point finds it, jumping in closed form over the
 * points in the shrunk cell or in the shrunk cube inscribed in the ball (ngp_box_exit);
 * the point after a jump is tested, and the lane goes on from it while it is inside.
 * render_ref.skip_unbounded. */
inline vint v_skip(vint k, vfloat t, float3 o, vpoint d, vpoint u, vcell c0, vint empty,
                   vint lev, vint g_code, float s, vfloat g_end, __global const uchar *G,
                   const v_lattice *lt)
{
    const vint res = (vint)(L_C) >> lev;
    vcell cell;
    cell.x = c0.x >> lev;
    cell.y = c0.y >> lev;
    cell.z = c0.z >> lev;
    const vint g = v_g_distance(u, empty & VMASK(res < G_RES), g_code, G);
    const vfloat radius = VF(g) / (float)G_RES;   /* u is in [0, 1]^3 */
    const vfloat size = 4.0f / VF(res);           /* a cell, in contracted units */
    const vfloat margin = size * BOX_MARGIN;
    const vfloat half_side = 4.0f * radius * CUBE - 4.0f / (float)G_RES * BOX_MARGIN;
    const vint cube = VMASK(g > 0) & VMASK(half_side > 0.0f);
    const vfloat lim = g_end / s + 2.0f;
    vint walking = empty;
    vfloat tk = v_lattice_t(lt, VF(k) * s);
    while (any(walking)) {
        vfloat T = tk;
        FOR_LANES(j) {
            if (!LANE_I(walking, j)) continue;
            const float sz = LANE_F(size, j), mg = LANE_F(margin, j), hf = LANE_F(half_side, j);
            const float3 i = (float3)((float)LANE_I(cell.x, j), (float)LANE_I(cell.y, j),
                                      (float)LANE_I(cell.z, j));
            const float3 dj = ngp_lane3(d.x, d.y, d.z, j);
            const float3 cj = ngp_lane3(u.x, u.y, u.z, j) * 4.0f - 2.0f;
            const float tj = LANE_F(tk, j);
            float Tj = ngp_box_exit(o, dj, tj, i * sz - 2.0f + mg, (i + 1.0f) * sz - 2.0f - mg);
            if (LANE_I(cube, j)) Tj = ngp_maxf(Tj, ngp_box_exit(o, dj, tj, cj - hf, cj + hf));
            LANE_F(T, j) = Tj;
        }
        const vint jump = v_ceil_i(v_min(v_lattice_s(lt, T) / s - 1e-3f, lim));
        k = select(k, max(k + 1, jump), walking);
        tk = v_lattice_t(lt, VF(k) * s);
        const vpoint uk = v_point_u(o, d, tk);
        const vfloat dx = uk.x - u.x, dy = uk.y - u.y, dz = uk.z - u.z;
        const vint stay = v_same_cell(v_cell(uk, res), cell)
                          | (VMASK(g > 0) & VMASK(sqrt(dx * dx + dy * dy + dz * dz) < radius));
        walking = walking & stay & VMASK(VF(k) * s < g_end);
    }
    return k;
}
#endif

/* ---- samples (Eq. 6-8) --------------------------------------------------------- */

/* Corners a sample reads: 8 of the coarse cell, then 8 per fine level. */
#define N_CORNERS (8 * (1 + L))

/* Trilinear weights of the 8 corners into wt[0..7], corner c = (cx << 2) | (cy << 1) | cz
 * (render_ref._trilinear_weights). */
inline void v_trilinear_weights(vfloat wx, vfloat wy, vfloat wz, vfloat *wt)
{
    for (int c = 0; c < 8; ++c)
        wt[c] = ((c & 4) ? wx : 1.0f - wx) * ((c & 2) ? wy : 1.0f - wy)
                * ((c & 1) ? wz : 1.0f - wz);
}

/* Where the sample of each lane in `sample` (at u, coarse cell c0) reads, and with which
 * trilinear weights, computed for all lanes at once: corners 0..7 of the coarse cell
 * (idx: the corner's first float8 in blocks; weight 0 and idx 0 where the block is
 * absent, never for an occupied cell) and 8 corners per fine level l (idx: the entry
 * in tables, level l's table first); render_ref.coarse_features and fine_features. */
inline void v_corners(vpoint u, vcell c0, vint sample, __global const int *block_index,
                      int n_blocks, vint *idx, vfloat *wt)
{
    vcell bi, r;
    bi.x = c0.x / COARSE_BLOCK;
    bi.y = c0.y / COARSE_BLOCK;
    bi.z = c0.z / COARSE_BLOCK;
    r.x = c0.x - bi.x * COARSE_BLOCK;
    r.y = c0.y - bi.y * COARSE_BLOCK;
    r.z = c0.z - bi.z * COARSE_BLOCK;
    const vint b = v_gather_i32(block_index, v_flat(bi, (vint)(COARSE_BLOCKS_PER_AXIS)), sample);
    const vint present = sample & VMASK(b >= 0) & VMASK(b < n_blocks);
    const vint base = select((vint)(0), (((b * COARSE_CORNERS + r.x) * COARSE_CORNERS + r.y)
                                         * COARSE_CORNERS + r.z) * (1 + ATT_VEC), present);
    v_trilinear_weights(u.x * (float)L_C - VF(c0.x), u.y * (float)L_C - VF(c0.y),
                        u.z * (float)L_C - VF(c0.z), wt);
    for (int c = 0; c < 8; ++c) {
        const int corner = ((((c >> 2) & 1) * COARSE_CORNERS + ((c >> 1) & 1)) * COARSE_CORNERS
                            + (c & 1)) * (1 + ATT_VEC);
        idx[c] = base + corner;
        wt[c] = select((vfloat)(0.0f), wt[c], present);
    }
    for (int l = 0; l < L; ++l) {
        const float res = (float)(L_C << (l + 1));
        const vfloat px = u.x * res, py = u.y * res, pz = u.z * res;
        const vint ix = v_floor_i(px), iy = v_floor_i(py), iz = v_floor_i(pz);
        v_trilinear_weights(px - VF(ix), py - VF(iy), pz - VF(iz), wt + 8 * (l + 1));
        for (int c = 0; c < 8; ++c) {
            /* encoding.hash_corner of corner i + c */
            const vuint h = (AS_VU(ix + ((c >> 2) & 1)) * 1u)
                            ^ (AS_VU(iy + ((c >> 1) & 1)) * 2654435761u)
                            ^ (AS_VU(iz + (c & 1)) * 805459861u);
            idx[8 * (l + 1) + c] = AS_VI(h & TABLE_MASK) + l * (1 << LOG2_T);
        }
    }
}

/* The 8 fused features of lane j's sample (Eq. 6): coarse + fuse(fine levels), from
 * the corners v_corners found, summed in the reference's order. The gathers depend on
 * nothing but idx, so a CPU issues them back to back. inv_sig: the attention weights
 * of the -inv variants (sigmoid of the invariant logits). */
inline float8 ngp_lane_features(int j, const vint *idx, const vfloat *wt,
                                __global const float8 *blocks, __global const float8 *tables,
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
    for (int a = 0; a < ATT_VEC; ++a) sig[a] = ngp_sigmoid8(sig[a]);
#else
    for (int a = 0; a < SIG_LEN; ++a) sig[a] = inv_sig[a];
#endif
    float8 fl[L];
    for (int l = 0; l < L; ++l) {
        fl[l] = (float8)(0.0f);
        for (int c = 8 * (l + 1); c < 8 * (l + 2); ++c)
            fl[l] = fl[l] + LANE_F(wt[c], j) * tables[LANE_I(idx[c], j)];
    }
    return coarse + ngp_fuse(fl, sig, fusion);
}

/* Alpha-composites the samples of the lanes in `sample` (at u, distance t, lattice
 * index k) into acc (per lane), *T, *opacity, *depth_acc (render_ref.composite): the
 * features lane by lane, density and alpha for all lanes at once (two vector exps). */
inline void v_composite(vint sample, vint k, vfloat t, vpoint u, vcell c0, float s,
                        vfloat g_end, const v_lattice *lt, float far,
                        __global const int *block_index,
                        __global const float8 *blocks, int n_blocks,
                        __global const float8 *tables, __global const float *fusion,
                        const float8 *inv_sig, float8 *acc, vfloat *T, vfloat *opacity,
                        vfloat *depth_acc)
{
    vint idx[N_CORNERS];
    vfloat wt[N_CORNERS];
    v_corners(u, c0, sample, block_index, n_blocks, idx, wt);
    float8 f[RAYS];
    float logit[RAYS];
    FOR_LANES(j) {
        logit[j] = 0.0f;
        if (LANE_I(sample, j)) {
            f[j] = ngp_lane_features(j, idx, wt, blocks, tables, fusion, inv_sig);
            logit[j] = f[j].s0;
        }
    }
    const vfloat sigma = NGP_EXP(VLOAD(logit));
#if UNBOUNDED
    /* The last interval ends at the ray's end. */
    const vfloat g_next = VF(k + 1) * s;
    const vfloat delta = select((vfloat)(far), v_lattice_t(lt, v_min(g_next, g_end)),
                                VMASK(g_next < g_end)) - t;
#else
    const vfloat delta = VF(k + 1) * s - t;
#endif
    const vfloat alpha = 1.0f - NGP_EXP(-sigma * delta);
    const vfloat w = *T * alpha;
    FOR_LANES(j) {
        if (LANE_I(sample, j)) acc[j] = acc[j] + LANE_F(w, j) * f[j];
    }
    *opacity = select(*opacity, *opacity + w, sample);
    *depth_acc = select(*depth_acc, *depth_acc + w * t, sample);
    *T = select(*T, *T * (1.0f - alpha), sample);
}

/* The ray range (ray_range): returns the lanes that hit (t_start <= t_end; not for a
 * missed box, nor inf/NaN from an axis-parallel ray outside it), with *g_end the end of
 * the lattice distance and *k the first lattice index: bounded t_end and ceil(t_start / s)
 * (0 where missed: ceil() of inf never reaches an int); unbounded S(far) and 0, the
 * lattice of each lane built into lt. */
inline vint v_ray_start(float3 o, vpoint d, float near, float far, float s, vfloat *g_end,
                        vint *k, v_lattice *lt)
{
#if UNBOUNDED
    v_lattice_build(o, d, near, far, lt);
    *g_end = lt->cum[LATTICE_BREAKS - 1];
    *k = (vint)(0);
    return (vint)(-1);
#else
    /* space.ray_box per lane; fmin/fmax drop the NaN of 0 * inf like numpy's. */
    const vfloat ix = 1.0f / d.x, iy = 1.0f / d.y, iz = 1.0f / d.z;
    const vfloat x0 = (-1.0f - o.x) * ix, x1 = (1.0f - o.x) * ix;
    const vfloat y0 = (-1.0f - o.y) * iy, y1 = (1.0f - o.y) * iy;
    const vfloat z0 = (-1.0f - o.z) * iz, z1 = (1.0f - o.z) * iz;
    const vfloat t_in = fmax(fmax(fmin(x0, x1), fmin(y0, y1)), fmin(z0, z1));
    const vfloat t_start = fmax((vfloat)(near), t_in);
    const vfloat t_end = fmin(fmin(fmax(x0, x1), fmax(y0, y1)), fmax(z0, z1));
    *g_end = t_end;
    const vint hit = VMASK(t_start <= t_end);
    *k = v_ceil_i(select((vfloat)(0.0f), t_start / s, hit));
    return hit;
#endif
}

/* The attention weights of the -inv variants, sigmoid of the invariant logits (N_INV
 * of fusion, padded to float8 chunks); zeros for the other variants. */
inline void ngp_inv_sigmoids(__global const float *fusion, float8 *inv_sig)
{
#if INV_VEC > 0
    for (int a = 0; a < INV_VEC; ++a) {
        float8 logit = (float8)(0.0f);
        for (int q = 0; q < 8 && 8 * a + q < N_INV; ++q) ((float *)&logit)[q] = fusion[8 * a + q];
        inv_sig[a] = ngp_sigmoid8(logit);
    }
#else
    inv_sig[0] = (float8)(0.0f);
#endif
}

__kernel void ngprt_march(__global const float *cam, const int width, const int height,
                          const float s, const float near, const float far,
                          __global const ushort *exit_code, __global const uchar *G,
                          __global const int *block_index, __global const float8 *blocks,
                          const int n_blocks, __global const float8 *tables,
                          __global const float *fusion,
                          __global float *feat, __global float *depth,
                          __global int *n_march_out, __global int *n_occ_out)
{
    const int px0 = (int)get_global_id(0) * RAYS, py = get_global_id(1);
    if (px0 >= width || py >= height) return;
    const vint px = px0 + LANE_IDS;
    const float3 o = camera_ray_origin(cam);
    const vpoint d = v_ray_dir(cam, px, py);
    vfloat g_end;
    vint k;
    v_lattice lattice;
    const v_lattice *lt = &lattice;
    const vint hit = v_ray_start(o, d, near, far, s, &g_end, &k, &lattice) & VMASK(px < width);
    k = select((vint)(0), k, hit);
    vint n_march = (vint)(0), n_occ = (vint)(0);
    vfloat T = (vfloat)(1.0f), opacity = (vfloat)(0.0f), depth_acc = (vfloat)(0.0f);
    float8 acc[RAYS];
    FOR_LANES(j) acc[j] = (float8)(0.0f);
    float8 inv_sig[SIG_LEN];
    ngp_inv_sigmoids(fusion, inv_sig);
    vint active = hit & VMASK(VF(k) * s < g_end);
    while (any(active)) {
        n_march -= active;
#if UNBOUNDED
        const vfloat t = v_lattice_t(lt, VF(k) * s);
#else
        const vfloat t = VF(k) * s;
#endif
        const vpoint u = v_point_u(o, d, t);
        const vcell c0 = v_cell(u, (vint)(L_C));
        const vint code = v_gather_u16(exit_code, v_flat(c0, (vint)(L_C)), active);
        const vint sample = active & VMASK((code & 0xff) == 0);
        const vint empty = active & ~sample;
        if (any(sample))
            v_composite(sample, k, t, u, c0, s, g_end, lt, far, block_index, blocks, n_blocks, tables,
                        fusion, inv_sig, acc, &T, &opacity, &depth_acc);
        if (any(empty))
            k = select(k, v_skip(k, t, o, d, u, c0, empty, (code & 0xff) - 1, code >> 8, s,
                                 g_end, G, lt), empty);
        n_occ -= sample;
        k -= sample;
        active = active & VMASK(VF(k) * s < g_end) & VMASK(T >= T_STOP);
    }
    FOR_LANES(j) {
        if (px0 + j >= width) break;
        const int n = py * width + px0 + j;
        /* acc.s0 accumulated w * sigma-logit; slot 7 carries the opacity instead. */
        __global float *out = feat + 8 * (size_t)n;
        out[0] = acc[j].s1; out[1] = acc[j].s2; out[2] = acc[j].s3; out[3] = acc[j].s4;
        const float op = LANE_F(opacity, j), dacc = LANE_F(depth_acc, j);
        out[4] = acc[j].s5; out[5] = acc[j].s6; out[6] = acc[j].s7; out[7] = op;
        depth[n] = op > 0.0f ? dacc / op : 0.0f;
        n_march_out[n] = LANE_I(n_march, j);
        n_occ_out[n] = LANE_I(n_occ, j);
    }
}
