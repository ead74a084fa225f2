/* NDRF visibility-buffer rasteriser (docs/ndrf.md "Hits"); mirrors the Embree first hits of
 * clrender/ndrf/hits.py, which the tests hold it to:
 *   ndrf_raster_clear  every pixel of every mesh: no hit yet.
 *   ndrf_raster_tris   per triangle (all K meshes, faces concatenated): to camera space,
 *                      screen bounding box; a box of at most TILE^2 pixels is covered
 *                      here, row by row over the span its edges allow (row_span), a larger
 *                      one is binned as (triangle, TILE x TILE screen tile) pairs.
 *   ndrf_raster_tiles  per binned pair: the triangle over the tile's pixels.
 *   ndrf_resolve       per pixel and mesh: triangle id, Embree (u, v) and depth along the
 *                      unit ray, recomputed from the pixel ray and the triangle.
 *
 * Coverage is exact ray-triangle coverage in camera space (homogeneous rasterisation,
 * Olano & Greer 1997): with camera-space vertices v0, v1, v2 and the pixel ray
 * r = (a, b, -1) of kernels/camera.h, the edge functions E_ij = (v_i x v_j) . r all share
 * the sign of V = det(v0, v1, v2) exactly when the ray's line crosses the triangle in
 * front of the camera, at t = V / (n . r) > 0 with n = (v1 - v0) x (v2 - v0) (the sum of
 * the three edge normals; V = n . v0). Each is computed without the cancellation of long
 * vectors (edge_normal), so a small triangle far away keeps its edges and depth. No near plane is needed: a
 * triangle crossing the camera plane is neither dropped nor clipped, its pixels are those
 * Embree (tnear = 0) hits. A zero-area or edge-on triangle (V = 0) covers nothing.
 * Tie rule: a pixel centre on an edge (E = 0) is covered only where the edge's normal
 * c = sign(V) (v_i x v_j) is lexicographically positive. Two triangles sharing an edge,
 * facing the same way, compute exactly opposite c (a cross product with swapped operands
 * negates exactly without contraction), so such a pixel is covered exactly once.
 *
 * Depth test: per pixel and mesh a 64-bit key (depth bits << 32 | triangle), kept by
 * atom_min (cl_khr_int64_extended_atomics): the nearest triangle, the smaller id on a tie.
 * depth is the camera-space z distance V / (n . r) (positive floats order as their bits).
 * Without 64-bit atomics (ATOMICS64=0) two passes over the same triangles: pass 0 keeps
 * the least depth bits per pixel (atomic_min on uint), pass 1 the least id among the
 * triangles whose depth bits equal it; the same result.
 *
 * Buffers: keys (K, H, W) ulong (ATOMICS64) or depth_bits + ids (K, H, W) uint; pairs
 * (capacity, 2) int (global triangle, tile) with the int counter n_pairs (may exceed the
 * capacity: the host grows it and reruns); out tri (K, H, W) int (-1: miss), bary (K, H, W)
 * float2, depth (K, H, W) float (inf on a miss).
 * -D defines (clrender/ndrf/raster_cl.py): K, TILE (pixels a tile side), ATOMICS64.
 */
#include "camera.h"
#pragma OPENCL FP_CONTRACT OFF

#if !defined(K) || !defined(TILE) || !defined(ATOMICS64)
#error "ndrf_raster.cl needs -D K TILE ATOMICS64"
#endif
#if ATOMICS64
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
#pragma OPENCL EXTENSION cl_khr_int64_extended_atomics : enable
#define NO_HIT 0xffffffffffffffffUL
#endif

/* The visibility target of one frame: either the 64-bit keys or the two 32-bit planes. */
typedef struct {
#if ATOMICS64
    volatile __global ulong *keys;
#else
    volatile __global uint *depth_bits;
    volatile __global uint *ids;
    int pass;
#endif
    int width, height;
} Target;

/* A triangle in camera space, ready to test pixels. */
typedef struct {
    float c[9];            /* edge normals: sign(V) (v1 x v2), (v2 x v0), (v0 x v1) */
    float n[3];            /* sign(V) (v1 - v0) x (v2 - v0) */
    float V;               /* |det(v0, v1, v2)| = |n . v0| */
    int x0, y0, x1, y1;    /* inclusive pixel bounds, clamped to the image */
    int mesh, id;          /* mesh k and the face index within it */
} Tri;

/* p (world) to camera space: R^T (p - origin), R row-major at cam[4..12], into v[0..2]. */
inline void to_camera(__global const float *cam, __global const float *p, float *v)
{
    const float qx = p[0] - cam[13], qy = p[1] - cam[14], qz = p[2] - cam[15];
    v[0] = cam[4] * qx + cam[7] * qy + cam[10] * qz;
    v[1] = cam[5] * qx + cam[8] * qy + cam[11] * qz;
    v[2] = cam[6] * qx + cam[9] * qy + cam[12] * qz;
}

/* out = s (a x b) for 3-float a, b. Scalar arrays throughout this file, not float3: float3
 * values built in these helpers crash the --uninitialized plugin of Oclgrind 21.10. */
inline void cross_scaled(const float *a, const float *b, float s, float *out)
{
    out[0] = s * (a[1] * b[2] - a[2] * b[1]);
    out[1] = s * (a[2] * b[0] - a[0] * b[2]);
    out[2] = s * (a[0] * b[1] - a[1] * b[0]);
}

/* The pixel column (or row) range [lo, hi] whose centres +0.5 can fall in [a, b]; one pixel
 * of slack either side (the edge functions decide). */
inline int2 pixel_range(float a, float b, int n)
{
    const float lo = fmax(floor(a - 0.5f) - 1.0f, 0.0f);
    const float hi = fmin(ceil(b - 0.5f) + 1.0f, (float)(n - 1));
    return (int2)((int)lo, (int)hi);
}

/* s (v_a x v_b) of camera-space vertices v[a], v[b] (global indices i[a], i[b]) into out,
 * computed as v_lo x (v_hi - v_lo) from the vertex of the smaller index: the same value in
 * exact arithmetic, but without the cancellation of two long vectors (a small triangle far
 * from the eye), and, since both triangles of a shared edge compute the same product, still
 * exactly negated between them. */
inline void edge_normal(float v[3][3], const int *i, int a, int b, float s, float *out)
{
    const int lo = i[a] < i[b] ? a : b, hi = lo == a ? b : a;
    float d[3];
    for (int j = 0; j < 3; ++j) d[j] = v[hi][j] - v[lo][j];
    cross_scaled(v[lo], d, lo == a ? s : -s, out);
}

/* Triangle g of the concatenated faces: its mesh, camera-space edge normals and bounds.
 * Returns 0 when it cannot cover a pixel (degenerate, behind the camera, off screen). */
inline int tri_setup(int g, __global const float *cam, int width, int height,
                     __global const int *face_start, __global const int *faces,
                     __global const float *vertices, Tri *t)
{
    int k = 0;
    while (k + 1 < K && g >= face_start[k + 1]) ++k;
    t->mesh = k;
    t->id = g - face_start[k];
    float v[3][3], e1[3], e2[3], n[3];
    int vi[3];
    for (int j = 0; j < 3; ++j) {
        vi[j] = faces[3 * g + j];
        to_camera(cam, vertices + 3 * vi[j], v[j]);
    }
    for (int j = 0; j < 3; ++j) {
        e1[j] = v[1][j] - v[0][j];
        e2[j] = v[2][j] - v[0][j];
    }
    cross_scaled(e1, e2, 1.0f, n);
    const float V = n[0] * v[0][0] + n[1] * v[0][1] + n[2] * v[0][2];
    if (!(V != 0.0f) || (v[0][2] >= 0.0f && v[1][2] >= 0.0f && v[2][2] >= 0.0f)) return 0;
    const float s = V > 0.0f ? 1.0f : -1.0f;
    edge_normal(v, vi, 1, 2, s, t->c);
    edge_normal(v, vi, 2, 0, s, t->c + 3);
    edge_normal(v, vi, 0, 1, s, t->c + 6);
    for (int j = 0; j < 3; ++j) t->n[j] = s * n[j];
    t->V = s * V;
    /* Camera looks down -z: depth -z. A vertex at or behind the camera plane: the covered
     * rays may lie anywhere on screen, bound by the image. */
    const float eps = 1e-7f;
    if (-v[0][2] <= eps || -v[1][2] <= eps || -v[2][2] <= eps) {
        t->x0 = 0; t->y0 = 0; t->x1 = width - 1; t->y1 = height - 1;
        return 1;
    }
    const float ax = v[0][0] / -v[0][2], bx = v[1][0] / -v[1][2], cx = v[2][0] / -v[2][2];
    const float ay = v[0][1] / -v[0][2], by = v[1][1] / -v[1][2], cy = v[2][1] / -v[2][2];
    /* pixel x + 0.5 = cx + fx a, y + 0.5 = cy - fy b (kernels/camera.h) */
    const float sx0 = cam[2] + cam[0] * fmin(ax, fmin(bx, cx));
    const float sx1 = cam[2] + cam[0] * fmax(ax, fmax(bx, cx));
    const float sy0 = cam[3] - cam[1] * fmax(ay, fmax(by, cy));
    const float sy1 = cam[3] - cam[1] * fmin(ay, fmin(by, cy));
    if (sx1 < -1.0f || sy1 < -1.0f || sx0 > (float)width + 1.0f || sy0 > (float)height + 1.0f)
        return 0;
    const int2 xr = pixel_range(sx0, sx1, width), yr = pixel_range(sy0, sy1, height);
    t->x0 = xr.x; t->x1 = xr.y; t->y0 = yr.x; t->y1 = yr.y;
    return t->x0 <= t->x1 && t->y0 <= t->y1;
}

/* Whether a pixel centre exactly on edge c (3 floats, E = 0) counts as covered: c
 * lexicographically positive (the tie rule). */
inline int edge_owns_ties(const float *c)
{
    return c[0] > 0.0f || (c[0] == 0.0f && (c[1] > 0.0f || (c[1] == 0.0f && c[2] > 0.0f)));
}

inline void write_hit(const Target *tg, int k, int p, float depth, int id)
{
    const int idx = k * tg->width * tg->height + p;
    const uint bits = as_uint(depth);
#if ATOMICS64
    atom_min(tg->keys + idx, ((ulong)bits << 32) | (ulong)(uint)id);
#else
    if (tg->pass == 0) atomic_min(tg->depth_bits + idx, bits);
    else if (tg->depth_bits[idx] == bits) atomic_min(tg->ids + idx, (uint)id);
#endif
}

/* The columns [*lo, *hi] of [x0, x1] where, on a row, all three edge functions of t may be
 * >= 0, one pixel of slack either side (*lo > *hi: none). On the row of ray b = ry the edge
 * function E = c0 a + rest, rest = c1 ry - c2, is linear in the pixel ray's
 * a = (px + 0.5 - cx) / fx and changes sign once, at a = -rest / c0 (inv_c0: the 1 / c0
 * of the three edges); the exact edge tests then run on this span only, not on the whole
 * box. Two triangles sharing an edge compute
 * exactly negated c and rest, hence the same crossing: their spans overlap by the slack. */
inline void row_span(const Tri *t, const float *rest, const float *inv_c0, float fx, float cx,
                     int x0, int x1, int *lo, int *hi)
{
    float a_lo = -INFINITY, a_hi = INFINITY;
    for (int e = 0; e < 3; ++e) {
        const float c0 = t->c[3 * e];
        if (c0 > 0.0f) a_lo = fmax(a_lo, -rest[e] * inv_c0[e]);
        else if (c0 < 0.0f) a_hi = fmin(a_hi, -rest[e] * inv_c0[e]);
        else if (rest[e] < 0.0f) a_hi = -INFINITY;
    }
    /* a to pixel columns, clamped into [x0 - 1, x1 + 1] as floats first (a may be +-inf
     * or NaN: a huge vertex), so the int conversion is defined. */
    const float l = fmin(fmax(floor(a_lo * fx + cx - 0.5f) - 1.0f, (float)x0),
                         (float)x1 + 1.0f);
    const float h = fmax(fmin(ceil(a_hi * fx + cx - 0.5f) + 1.0f, (float)x1),
                         (float)x0 - 1.0f);
    *lo = (int)l;
    *hi = a_lo <= a_hi ? (int)h : (int)l - 1;
}

/* Cover the pixels of [x0, x1] x [y0, y1] (within the triangle's bounds) that t covers:
 * every edge function E = c0 rx + (c1 ry - c2) > 0, or = 0 on an edge that owns its ties
 * (a fixed evaluation order: a shared edge's E is exactly negated in its other triangle).
 * ray_ab: the pixel rays' a (width floats, then b: height floats) of kernels/camera.h,
 * (px + 0.5 - cx) / fx and -((py + 0.5 - cy) / fy), computed once a frame on the host
 * with the same float32 operations (clrender/ndrf/raster_cl.py); fx, cx: the camera's. */
inline void cover(__global const float *ray_ab, float fx, float cx, const Tri *t,
                  const Target *tg, int x0, int y0, int x1, int y1)
{
    __global const float *ray_b = ray_ab + tg->width;
    const float c00 = t->c[0], c10 = t->c[3], c20 = t->c[6], nx = t->n[0];
    const int own0 = edge_owns_ties(t->c), own1 = edge_owns_ties(t->c + 3),
              own2 = edge_owns_ties(t->c + 6);
    const float inv_c0[3] = {1.0f / c00, 1.0f / c10, 1.0f / c20};
    x0 = max(x0, t->x0);
    x1 = min(x1, t->x1);
    for (int py = max(y0, t->y0); py <= min(y1, t->y1); ++py) {
        const float ry = ray_b[py];
        float rest[3];
        for (int e = 0; e < 3; ++e) rest[e] = t->c[3 * e + 1] * ry - t->c[3 * e + 2];
        const float rest_n = t->n[1] * ry - t->n[2];
        int lo, hi;
        row_span(t, rest, inv_c0, fx, cx, x0, x1, &lo, &hi);
        for (int px = lo; px <= hi; ++px) {
            const float rx = ray_ab[px];
            const float e0 = c00 * rx + rest[0], e1 = c10 * rx + rest[1],
                        e2 = c20 * rx + rest[2], en = nx * rx + rest_n;
            if ((e0 > 0.0f || (e0 == 0.0f && own0)) && (e1 > 0.0f || (e1 == 0.0f && own1)) &&
                (e2 > 0.0f || (e2 == 0.0f && own2)) && en > 0.0f)
                write_hit(tg, t->mesh, py * tg->width + px, t->V / en, t->id);
        }
    }
}

#if ATOMICS64
#define TARGET_ARGS volatile __global ulong *keys
#define TARGET_INIT {keys, width, height}
#else
#define TARGET_ARGS volatile __global uint *depth_bits, volatile __global uint *ids, \
                    const int pass
#define TARGET_INIT {depth_bits, ids, pass, width, height}
#endif

__kernel void ndrf_raster_clear(const int n, TARGET_ARGS)
{
    const int i = (int)get_global_id(0);
    if (i >= n) return;
#if ATOMICS64
    keys[i] = NO_HIT;
#else
    if (pass == 0) depth_bits[i] = 0xffffffffu;
    ids[i] = 0xffffffffu;
#endif
}

__kernel void ndrf_raster_tris(__global const float *cam, const int width, const int height,
                               const int n_faces, __global const int *face_start,
                               __global const int *faces, __global const float *vertices,
                               __global const float *ray_ab, const int capacity,
                               volatile __global int *n_pairs, __global int *pairs,
                               TARGET_ARGS)
{
    const int g = (int)get_global_id(0);
    if (g >= n_faces) return;
    Tri t;
    if (!tri_setup(g, cam, width, height, face_start, faces, vertices, &t)) return;
    const Target tg = TARGET_INIT;
    if ((t.x1 - t.x0 + 1) * (t.y1 - t.y0 + 1) <= TILE * TILE) {
        cover(ray_ab, cam[0], cam[2], &t, &tg, t.x0, t.y0, t.x1, t.y1);
        return;
    }
    const int tx0 = t.x0 / TILE, tx1 = t.x1 / TILE, ty0 = t.y0 / TILE, ty1 = t.y1 / TILE;
    const int tiles_x = (width + TILE - 1) / TILE;
    const int n = (tx1 - tx0 + 1) * (ty1 - ty0 + 1);
    const int first = atomic_add(n_pairs, n);
    /* Quotient and remainder written out: LLVM pairs a / and % of the same operands with a
     * freeze instruction, which Oclgrind 21.10's --uninitialized plugin cannot run. */
    const int nx = tx1 - tx0 + 1;
    for (int i = 0; i < n && first + i < capacity; ++i) {
        const int row = i / nx;
        vstore2((int2)(g, (ty0 + row) * tiles_x + tx0 + (i - row * nx)), first + i, pairs);
    }
}

__kernel void ndrf_raster_tiles(__global const float *cam, const int width, const int height,
                                __global const int *face_start, __global const int *faces,
                                __global const float *vertices, __global const float *ray_ab,
                                const int n_pairs, __global const int *pairs, TARGET_ARGS)
{
    const int i = (int)get_global_id(0);
    if (i >= n_pairs) return;
    const int2 pair = vload2(i, pairs);
    Tri t;
    if (!tri_setup(pair.x, cam, width, height, face_start, faces, vertices, &t)) return;
    const Target tg = TARGET_INIT;
    const int tiles_x = (width + TILE - 1) / TILE;
    const int row = pair.y / tiles_x;                   /* no %: see ndrf_raster_tris */
    const int x0 = (pair.y - row * tiles_x) * TILE, y0 = row * TILE;
    cover(ray_ab, cam[0], cam[2], &t, &tg, x0, y0, x0 + TILE - 1, y0 + TILE - 1);
}

inline float dot3(const float *a, const float *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* Embree's (u, v) and distance along the unit ray: Moller-Trumbore on the world-space
 * triangle, clamped into the triangle (a pixel the edge test covered may sit a rounding
 * error outside). The ray direction only where a mesh is hit. Scalar arrays for Oclgrind,
 * as in cover(). */
__kernel void ndrf_resolve(__global const float *cam, const int width, const int height,
                           __global const int *face_start, __global const int *faces,
                           __global const float *vertices, __global const float *ray_ab,
#if ATOMICS64
                           __global const ulong *keys,
#else
                           __global const uint *ids,
#endif
                           __global int *tri, __global float *bary, __global float *depth)
{
    const int px = (int)get_global_id(0), py = (int)get_global_id(1);
    if (px >= width || py >= height) return;
    const int n = width * height;
    float o[3], d[3];
    int have_dir = 0;
    vstore3(camera_ray_origin(cam), 0, o);
    for (int k = 0; k < K; ++k) {
        const int idx = k * n + py * width + px;
#if ATOMICS64
        const ulong key = keys[idx];
        const int id = key == NO_HIT ? -1 : (int)(uint)(key & 0xffffffffUL);
#else
        const int id = ids[idx] == 0xffffffffu ? -1 : (int)ids[idx];
#endif
        float u = 0.0f, v = 0.0f, t = INFINITY;
        if (id >= 0) {
            if (!have_dir) {
                /* camera_ray_dir_into's operations on its a, b from ray_ab: the same bits. */
                const float a = ray_ab[px], b = ray_ab[width + py];
                for (int j = 0; j < 3; ++j)
                    d[j] = cam[4 + 3 * j] * a + cam[5 + 3 * j] * b - cam[6 + 3 * j];
                const float norm = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                for (int j = 0; j < 3; ++j) d[j] = d[j] / norm;
                have_dir = 1;
            }
            const int g = face_start[k] + id;
            float p0[3], e1[3], e2[3], tv[3], pv[3], qv[3];
            for (int j = 0; j < 3; ++j) {
                p0[j] = vertices[3 * faces[3 * g] + j];
                e1[j] = vertices[3 * faces[3 * g + 1] + j] - p0[j];
                e2[j] = vertices[3 * faces[3 * g + 2] + j] - p0[j];
                tv[j] = o[j] - p0[j];
            }
            cross_scaled(d, e2, 1.0f, pv);
            cross_scaled(tv, e1, 1.0f, qv);
            const float inv_det = 1.0f / dot3(e1, pv);
            u = clamp(dot3(tv, pv) * inv_det, 0.0f, 1.0f);
            v = clamp(dot3(d, qv) * inv_det, 0.0f, 1.0f - u);
            t = dot3(e2, qv) * inv_det;
        }
        tri[idx] = id;
        bary[2 * idx] = u;
        bary[2 * idx + 1] = v;
        depth[idx] = t;
    }
}
