/* Empty-space skipping (docs/ngprt.md "skip", paper §4.3, Eq. 9): from an empty lattice
 * point to the next one that may be occupied, with the occupancy mip and (USE_G) the
 * occupancy distance grid G; render_ref.skip_bounded and skip_unbounded.
 *
 * Constants shared with clrender/ngprt/render_ref.py, as -D float literals
 * (render_cl.kernel_defines):
 *   K_BACKOFF   steps taken off a closed-form exit before rounding up to a lattice index
 *               (the float exit distance may overshoot);
 *   K_PAST_END  steps past the ray's end where a skip's index is clamped (any k past the
 *               end is as good as another, and the int stays small);
 *   unbounded: BOX_MARGIN (a box is shrunk by this fraction of its grid cell on every
 *   face), REGION_SCALE (the outer regions of the contraction keep 1 - REGION_SCALE of
 *   |x|_inf away from the planes |x_b| = |x_a| where it switches axis, a jump) and CUBE
 *   (half-side of the cube inscribed in G's ball over its radius, < 1/sqrt(3)).
 */
#ifndef CLRENDER_NGPRT_SKIP_H
#define CLRENDER_NGPRT_SKIP_H
#pragma OPENCL FP_CONTRACT OFF
#include "ngprt_space.h"

#if !defined(K_BACKOFF) || !defined(K_PAST_END) || !defined(BOX_MARGIN) || \
    !defined(REGION_SCALE) || !defined(CUBE)
#error "ngprt kernels need -D K_BACKOFF K_PAST_END BOX_MARGIN REGION_SCALE CUBE (render_ref)"
#endif

/* The distance grid value (G-voxels) of the lanes in `read`, else 0 (paper §4.3: read
 * only when the exit level is coarser than G): from the exit code's high byte
 * (G_IN_CODE, render_cl.exit_codes) or from G (render_ref.g_distance). */
inline vint g_distance(const Model *m, Point3 u, vint read, vint g_code)
{
#if MARCH_PAPER
    return (vint)(0);                            /* the paper's march reads G itself */
#elif USE_G && G_IN_CODE
    return select((vint)(0), g_code, read);      /* exit_codes put it there */
#elif USE_G
    if (any(read))
        return lane_gather_u8(m->G, flat_index(cells(u, (vint)(G_RES)), (vint)(G_RES)), read);
#endif
    return (vint)(0);
}

/* The last lattice index a skip may return: past the ray's end any k will do. */
inline vfloat k_limit(const Rays *r)
{
    return r->g_end / r->s + K_PAST_END;
}

/* ---- Bounded scenes: render_ref.skip_bounded, closed form -------------------------- */
#if !UNBOUNDED
/* One lane's ray, for the bisection of the bounded skip. */
typedef struct {
    float3 o, d;
    float s;
} Ray;

/* Lattice point k (t_k = k * s) lies in `cell` at resolution res (render_ref._in_cell;
 * one lane: the operations of point_u, bounded). */
inline bool in_cell(const Ray *r, int k, int res, int3 cell)
{
    const float3 u = (r->o + ((float)k * r->s) * r->d + EXTENT_F) / SIDE_F;
    const float hi = (float)(res - 1);
    const float3 v = u * (float)res;
    const int3 c = (int3)((int)(v.x < 0.0f ? 0.0f : (v.x > hi ? hi : v.x)),
                          (int)(v.y < 0.0f ? 0.0f : (v.y > hi ? hi : v.y)),
                          (int)(v.z < 0.0f ? 0.0f : (v.z > hi ? hi : v.z)));
    return c.x == cell.x && c.y == cell.y && c.z == cell.z;
}

/* First lattice point outside `cell` in (k_in, k_out]: k_in is inside, k_out outside
 * (render_ref._first_outside, a bisection). Per axis the cell of t_k is monotone in k, so
 * the points inside form one run. */
inline int first_outside(const Ray *r, int k_in, int k_out, int res, int3 cell)
{
    while (k_out - k_in > 1) {
        const int mid = k_in + (k_out - k_in) / 2;
        if (in_cell(r, mid, res, cell)) k_in = mid; else k_out = mid;
    }
    return k_out;
}

/* First lattice index after each lane's exit of the cell at u, at resolution res, in
 * closed form (rays are straight in u space): always > k. The float exit distance is
 * off by up to ~1e-7 / |d_a| world units (many steps for a tiny direction component),
 * so the candidate is checked: if point k_next - 1 has left the cell, bisect for the
 * first point outside it. */
inline vint cell_exit(const Rays *r, const MarchPoint *p, vint empty, vint lev)
{
    const float3 o = r->o;
    const Point3 d = r->d;
    const float s = r->s;
    const vint res = (vint)(OCC_RES) >> lev;
    /* SIDE_F / res: OCC_RES >> lev = OCC_RES / 2^lev exactly, and scaling by 2^lev is exact. */
    const vfloat h = (SIDE_F / (float)OCC_RES) * VF((vint)(1) << lev);
    Cell3 i;
    i.x = p->cell.x >> lev;
    i.y = p->cell.y >> lev;
    i.z = p->cell.z >> lev;
    const vfloat lo_x = VF(i.x) * h - 1.0f, lo_y = VF(i.y) * h - 1.0f, lo_z = VF(i.z) * h - 1.0f;
    const vfloat hi_x = lo_x + h, hi_y = lo_y + h, hi_z = lo_z + h;
    vfloat t_exit = (vfloat)(INFINITY);
    t_exit = select(t_exit, lane_min(t_exit, (select(lo_x, hi_x, VMASK(d.x > 0.0f)) - o.x) / d.x),
                    VMASK(d.x != 0.0f));
    t_exit = select(t_exit, lane_min(t_exit, (select(lo_y, hi_y, VMASK(d.y > 0.0f)) - o.y) / d.y),
                    VMASK(d.y != 0.0f));
    t_exit = select(t_exit, lane_min(t_exit, (select(lo_z, hi_z, VMASK(d.z > 0.0f)) - o.z) / d.z),
                    VMASK(d.z != 0.0f));
    const vint k = r->k;
    vint k_next = max(k + 1, lane_ceil_i(lane_min(t_exit / s - K_BACKOFF, k_limit(r))));
    const vint check = empty & VMASK(k_next - 1 > k);
    if (any(check)) {
        const vint k_last = select(k, k_next - 1, check);
        const vint outside = check & ~same_cell(cells(point_u(o, d, VF(k_last) * s), res), i);
        FOR_LANES(j) {
            if (!LANE_I(outside, j)) continue;
            const Ray rj = {o, (float3)(LANE_F(d.x, j), LANE_F(d.y, j), LANE_F(d.z, j)), s};
            const int3 ij = (int3)(LANE_I(i.x, j), LANE_I(i.y, j), LANE_I(i.z, j));
            LANE_I(k_next, j) = first_outside(&rj, LANE_I(k, j), LANE_I(k_last, j),
                                              LANE_I(res, j), ij);
        }
    }
    return k_next;
}

/* Next lattice index (> k) of the lanes in `empty`, whose exit code is `code`: past the
 * empty mip cell (cell_exit) and, where G is read, past G's empty ball of radius
 * 2 g / G_RES world units (render_ref.skip_bounded). */
inline vint skip_bounded(const Model *m, const Rays *r, const MarchPoint *p, vint empty,
                         vint code)
{
    const vint lev = CODE_LEVEL(code) - 1;
    const vint k_next = cell_exit(r, p, empty, lev);
    const vint g = g_distance(m, p->u, empty & VMASK(((vint)(OCC_RES) >> lev) < G_RES), CODE_G(code));
    if (!any(VMASK(g > 0))) return k_next;
    const vfloat radius = SIDE_F * VF(g) / (float)G_RES;
    const vint k_g = lane_floor_i(lane_min((p->t + radius) / r->s, k_limit(r)));
    return select(k_next, max(k_next, k_g), VMASK(g > 0));
}
#endif  /* !UNBOUNDED */

/* ---- Unbounded scenes: render_ref.skip_unbounded, a walk with closed-form jumps ------ */
#if UNBOUNDED
/* A face f + beta (t' - t) >= 0 of a box, in the lanes of `on` (render_ref._box_exit's
 * constraint): the point at t must satisfy it, and it bounds t' - t by f / -beta where
 * beta < 0. */
inline void constraint(vfloat f, vfloat beta, vint on, vfloat *dt, vint *inside)
{
    *inside = *inside & (~on | VMASK(f >= 0.0f));
    *dt = select(*dt, lane_min(*dt, f / -beta), on & VMASK(beta < 0.0f));
}

/* The faces of a box [lo_b, hi_b] on axis b (p_b, d_b: the point at t and the direction):
 * the box and the inner cube |x|_inf <= 1 where `inner`; elsewhere (`other`: outside the
 * cube, b not the axis of |x|_inf) the region's planes and the box's, linear in t' there. */
inline void axis_constraints(vfloat pb, vfloat db, vfloat lo, vfloat hi, vfloat ms, vfloat dm,
                             vint inner, vint other, vfloat *dt, vint *inside)
{
    constraint(pb - lo, db, inner, dt, inside);
    constraint(hi - pb, -db, inner, dt, inside);
    constraint(1.0f - pb, -db, inner, dt, inside);
    constraint(1.0f + pb, db, inner, dt, inside);
    constraint(ms * REGION_SCALE - pb, dm * REGION_SCALE - db, other, dt, inside);
    constraint(ms * REGION_SCALE + pb, dm * REGION_SCALE + db, other, dt, inside);
    constraint(pb - lo * ms, db - lo * dm, other, dt, inside);
    constraint(hi * ms - pb, hi * dm - db, other, dt, inside);
}

/* Per lane, the largest t' >= t such that the ray o + t' d stays in the box [lo, hi]
 * (contracted space) over [t, t'] within the projective region of the contraction it is
 * in at t; t where the point at t is outside. Inside |x|_inf <= 1, c = x; outside, with a
 * the axis of |x|_inf = sg * x_a = m, c_b = x_b / m and sg * c_a = 2 - 1/m: every face
 * is linear in t' there. All lanes at once, each computed as render_ref._box_exit
 * computes it. */
inline vfloat box_exit(float3 o, Point3 d, vfloat t, Point3 lo, Point3 hi)
{
    const vfloat px = o.x + t * d.x, py = o.y + t * d.y, pz = o.z + t * d.z;
    const vfloat ax = lane_abs(px), ay = lane_abs(py), az = lane_abs(pz);
    const vfloat m = lane_max(lane_max(ax, ay), az);
    const vint on_x = VMASK(ax == m), on_y = ~on_x & VMASK(ay == m), on_z = ~on_x & ~on_y;
    const vfloat pa = select(select(pz, py, on_y), px, on_x);
    const vfloat da = select(select(d.z, d.y, on_y), d.x, on_x);
    const vfloat sg = select((vfloat)(-1.0f), (vfloat)(1.0f), VMASK(pa > 0.0f));
    const vfloat ms = sg * pa, dm = sg * da;
    const vint inner = VMASK(m <= 1.0f), outer = ~inner;
    vfloat dt = (vfloat)(INFINITY);
    vint inside = (vint)(-1);
    axis_constraints(px, d.x, lo.x, hi.x, ms, dm, inner, outer & ~on_x, &dt, &inside);
    axis_constraints(py, d.y, lo.y, hi.y, ms, dm, inner, outer & ~on_y, &dt, &inside);
    axis_constraints(pz, d.z, lo.z, hi.z, ms, dm, inner, outer & ~on_z, &dt, &inside);
    const vfloat lo_axis = select(select(lo.z, lo.y, on_y), lo.x, on_x);
    const vfloat hi_axis = select(select(hi.z, hi.y, on_y), hi.x, on_x);
    const vint up = VMASK(sg > 0.0f);
    const vfloat lo_a = select(-hi_axis, lo_axis, up), hi_a = select(-lo_axis, hi_axis, up);
    constraint(ms - 1.0f, dm, outer, &dt, &inside);
    const vint lo_open = VMASK(lo_a < 2.0f);
    constraint(ms - 1.0f / (2.0f - lo_a), dm, outer & lo_open, &dt, &inside);
    inside = inside & ~(outer & ~lo_open);
    constraint(1.0f / (2.0f - hi_a) - ms, -dm, outer & VMASK(hi_a < 2.0f), &dt, &inside);
    return select(t, t + dt, inside);
}

/* The largest distance T of each lane in `walking` (tk elsewhere) to which its ray stays
 * in both boxes of its skip from tk: the empty mip cell shrunk by BOX_MARGIN and, where
 * `cube`, the cube inscribed in G's ball about u (box_exit). */
inline vfloat boxes_exit(const Rays *r, vfloat tk, vint walking, Cell3 cell, vint res,
                         Point3 u, vint cube, vfloat half_side)
{
    const vfloat size = SIDE_F / VF(res);         /* a cell, in contracted units */
    const vfloat margin = size * BOX_MARGIN;
    const vfloat ix = VF(cell.x), iy = VF(cell.y), iz = VF(cell.z);
    const Point3 lo = {ix * size - EXTENT_F + margin, iy * size - EXTENT_F + margin,
                       iz * size - EXTENT_F + margin};
    const Point3 hi = {(ix + 1.0f) * size - EXTENT_F - margin,
                       (iy + 1.0f) * size - EXTENT_F - margin,
                       (iz + 1.0f) * size - EXTENT_F - margin};
    vfloat T = box_exit(r->o, r->d, tk, lo, hi);
    const vint in_cube = walking & cube;
    if (any(in_cube)) {
        const vfloat cx = u.x * SIDE_F - EXTENT_F, cy = u.y * SIDE_F - EXTENT_F,
                     cz = u.z * SIDE_F - EXTENT_F;
        const Point3 c_lo = {cx - half_side, cy - half_side, cz - half_side};
        const Point3 c_hi = {cx + half_side, cy + half_side, cz + half_side};
        T = select(T, lane_max(T, box_exit(r->o, r->d, tk, c_lo, c_hi)), in_cube);
    }
    return select(tk, T, walking);
}

/* Unbounded skip of the lanes in `empty`, whose exit code is `code` (no memory read but
 * G): the first lattice point outside both the empty mip cell and, when G was read, the
 * ball of radius g / G_RES (u units) about u, as a walk point by point finds it, jumping
 * in closed form over the points in the shrunk cell or in the shrunk cube inscribed in
 * the ball (boxes_exit); the point after a jump is tested, and the lane goes on from
 * it while it is inside. render_ref.skip_unbounded. */
inline vint skip_unbounded(const Model *m, const Rays *r, const MarchPoint *p, vint empty,
                           vint code)
{
    const vint lev = CODE_LEVEL(code) - 1;
    const vint res = (vint)(OCC_RES) >> lev;
    Cell3 cell;
    cell.x = p->cell.x >> lev;
    cell.y = p->cell.y >> lev;
    cell.z = p->cell.z >> lev;
    const Point3 u = p->u;
    const vint g = g_distance(m, u, empty & VMASK(res < G_RES), CODE_G(code));
    const vfloat radius = VF(g) / (float)G_RES;   /* u is in [0, 1]^3 */
    const vfloat half_side = SIDE_F * radius * CUBE - SIDE_F / (float)G_RES * BOX_MARGIN;
    const vint cube = VMASK(g > 0) & VMASK(half_side > 0.0f);
    const vfloat lim = k_limit(r);
    vint k = r->k, walking = empty;
    vfloat tk = lattice_t(r->lt, lattice_g(r, k));
    while (any(walking)) {
        const vfloat T = boxes_exit(r, tk, walking, cell, res, u, cube, half_side);
        const vint jump = lane_ceil_i(lane_min(lattice_s(r->lt, T) / r->s - K_BACKOFF, lim));
        k = select(k, max(k + 1, jump), walking);
        tk = lattice_t(r->lt, lattice_g(r, k));
        const Point3 uk = point_u(r->o, r->d, tk);
        const vfloat dx = uk.x - u.x, dy = uk.y - u.y, dz = uk.z - u.z;
        const vint stay = same_cell(cells(uk, res), cell)
                          | (VMASK(g > 0) & VMASK(sqrt(dx * dx + dy * dy + dz * dz) < radius));
        walking = walking & stay & VMASK(lattice_g(r, k) < r->g_end);
    }
    return k;
}
#endif  /* UNBOUNDED */

/* Next lattice index (> k) of the lanes in `empty`, whose exit code is `code`: the skip of
 * the build's scene (render_ref._skip, march "ours"; the paper's march: paper_skip). */
inline vint skip(const Model *m, const Rays *r, const MarchPoint *p, vint empty, vint code)
{
#if UNBOUNDED
    return skip_unbounded(m, r, p, empty, code);
#else
    return skip_bounded(m, r, p, empty, code);
#endif
}
#endif
