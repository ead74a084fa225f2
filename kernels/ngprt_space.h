/* Scene space per lane (clrender/ngprt/space.py, render_ref.py): the rays of a
 * work-item, their range, the lattice points they march and the grid cells of a point.
 *
 * The exact build (device.exact_options) keeps FP contraction off and asks for correctly
 * rounded division and sqrt, so positions, cells and lattice indices are bit-identical
 * to the numpy reference; the fast build computes them by the same operations.
 */
#ifndef CLRENDER_NGPRT_SPACE_H
#define CLRENDER_NGPRT_SPACE_H
#pragma OPENCL FP_CONTRACT OFF
#include "camera.h"
#include "ngprt_model.h"
#include "ngprt_lanes.h"
#include "ngprt_lattice.h"

/* The RAYS rays of a work-item: their fixed geometry, then the march state of each lane
 * (the twin of render_ref._Rays). The lattice tables and the accumulators are arrays the
 * struct points to, held apart: acc is indexed by lane at run time, and an array indexed
 * so inside the struct would keep every field in memory instead of registers. */
typedef struct {
    float3 o;              /* the camera's origin, every lane */
    Point3 d;              /* unit directions */
    float s, far;          /* the step (lattice units); far, where unbounded rays end */
    vfloat g_end;          /* lattice distance of the ray's end: t_end, unbounded S(far) */
    Lattice *lt;           /* unbounded: each lane's lattice table */
    vint k;                /* the current lattice index */
    vfloat T, opacity, depth_acc;
    float8 *acc;           /* [RAYS] composited features; .s0 (w * sigma logit) unused */
    vint n_march, n_occ;   /* marching points, occupied samples */
} Rays;

/* A lattice point of each lane: distance t, grid coordinates u, finest occupancy cell
 * (OCC_RES; its coarse cell is it shifted right by OCC_SHIFT). */
typedef struct {
    vfloat t;
    Point3 u;
    Cell3 cell;
} MarchPoint;

/* camera_ray_dir of pixels (px, py), one a lane, the same operations in the same order. */
inline Point3 camera_ray_dirs(__global const float *cam, vint px, int py)
{
    const vfloat a = (VF(px) + 0.5f - cam[2]) / cam[0];
    const float b = -(((float)py + 0.5f - cam[3]) / cam[1]);
    Point3 d;
    d.x = cam[4] * a + cam[5] * b - cam[6];
    d.y = cam[7] * a + cam[8] * b - cam[9];
    d.z = cam[10] * a + cam[11] * b - cam[12];
    const vfloat norm = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    d.x = d.x / norm;
    d.y = d.y / norm;
    d.z = d.z / norm;
    return d;
}

/* Grid coordinates u = to_grid(o + t * d) per lane (render_ref._point_u, space.to_grid). */
inline Point3 point_u(float3 o, Point3 d, vfloat t)
{
    Point3 p;
    p.x = o.x + t * d.x;
    p.y = o.y + t * d.y;
    p.z = o.z + t * d.z;
#if UNBOUNDED
    p = contract(p);
#endif
    p.x = (p.x + EXTENT_F) / SIDE_F;
    p.y = (p.y + EXTENT_F) / SIDE_F;
    p.z = (p.z + EXTENT_F) / SIDE_F;
    return p;
}

/* One axis of cells: v = u * res, clamped to [0, res - 1] and floored. Clamping the float
 * before flooring gives the same cell as clamping floor(u * res), and the clamped value is
 * non-negative, so floor is the conversion. */
inline vint cell_axis(vfloat v, vint res)
{
    const vfloat hi = VF(res - 1);
    return VI(select(select(v, hi, VMASK(v > hi)), 0.0f, VMASK(v < 0.0f)));
}

/* Cell of u at a per-lane resolution res, clamped to the grid (render_ref._cells;
 * space.cell_index at one resolution). */
inline Cell3 cells(Point3 u, vint res)
{
    const vfloat r = VF(res);
    Cell3 c;
    c.x = cell_axis(u.x * r, res);
    c.y = cell_axis(u.y * r, res);
    c.z = cell_axis(u.z * r, res);
    return c;
}

/* The cell's index in a res^3 grid, C order. */
inline vint flat_index(Cell3 i, vint res)
{
    return (i.x * res + i.y) * res + i.z;
}

/* The lanes where cells a and b are the same. */
inline vint same_cell(Cell3 a, Cell3 b)
{
    return VMASK(a.x == b.x) & VMASK(a.y == b.y) & VMASK(a.z == b.z);
}

/* Lattice distance k * s of lattice index k (render_ref._lattice_g). */
inline vfloat lattice_g(const Rays *r, vint k)
{
    return VF(k) * r->s;
}

/* Distance t_k of lattice point k of each lane: k * s, unbounded S^-1(k * s)
 * (render_ref.lattice_point). */
inline vfloat lattice_point(const Rays *r, vint k)
{
#if UNBOUNDED
    return lattice_t(r->lt, lattice_g(r, k));
#else
    return lattice_g(r, k);
#endif
}

/* Lattice point k of each lane as the march reads it: t_k, its grid coordinates and its
 * finest occupancy cell (render_ref.march_reference's t, u and exit_level's cell). */
inline MarchPoint march_point(const Rays *r, vint k)
{
    MarchPoint p;
    p.t = lattice_point(r, k);
    p.u = point_u(r->o, r->d, p.t);
    p.cell = cells(p.u, (vint)(OCC_RES));
    return p;
}

/* Entry and exit distances of each lane's ray with the box [-1, 1]^3 (space.ray_box);
 * fmin/fmax drop the NaN of 0 * inf like numpy's. */
inline void ray_box(float3 o, Point3 d, vfloat *t_in, vfloat *t_out)
{
    const vfloat ix = 1.0f / d.x, iy = 1.0f / d.y, iz = 1.0f / d.z;
    const vfloat x0 = (-1.0f - o.x) * ix, x1 = (1.0f - o.x) * ix;
    const vfloat y0 = (-1.0f - o.y) * iy, y1 = (1.0f - o.y) * iy;
    const vfloat z0 = (-1.0f - o.z) * iz, z1 = (1.0f - o.z) * iz;
    *t_in = fmax(fmax(fmin(x0, x1), fmin(y0, y1)), fmin(z0, z1));
    *t_out = fmin(fmin(fmax(x0, x1), fmax(y0, y1)), fmax(z0, z1));
}

/* The rays of pixels (px, py) and their range (render_ref.ray_range), the march state
 * cleared: returns the lanes that hit (t_start <= t_end; not for a missed box, nor
 * inf/NaN from an axis-parallel ray outside it, nor px past the image), with g_end the
 * end of the lattice distance and k the first lattice index: bounded t_end and
 * ceil(t_start / s) (0 where missed: ceil() of inf never reaches an int); unbounded
 * S(far) and 0, each lane's lattice built into *r->lt (r->lt and r->acc point to the
 * work-item's arrays). */
inline vint rays_start(Rays *r, __global const float *cam, vint px, int py, int width,
                       float s, float near, float far)
{
    r->o = camera_ray_origin(cam);
    r->d = camera_ray_dirs(cam, px, py);
    r->s = s;
    r->far = far;
    r->T = (vfloat)(1.0f);
    r->opacity = r->depth_acc = (vfloat)(0.0f);
    r->n_march = r->n_occ = (vint)(0);
    FOR_LANES(j) r->acc[j] = (float8)(0.0f);
#if UNBOUNDED
    lattice_table(r->o, r->d, near, far, r->lt);
    r->g_end = r->lt->cum[LATTICE_BREAKS - 1];
    r->k = (vint)(0);
    return VMASK(px < width);
#else
    /* render_ref.ray_range, bounded */
    vfloat t_in, t_end;
    ray_box(r->o, r->d, &t_in, &t_end);
    const vfloat t_start = fmax((vfloat)(near), t_in);
    r->g_end = t_end;
    const vint hit = VMASK(t_start <= t_end) & VMASK(px < width);
    r->k = select((vint)(0), lane_ceil_i(select((vfloat)(0.0f), t_start / s, hit)), hit);
    return hit;
#endif
}
#endif
