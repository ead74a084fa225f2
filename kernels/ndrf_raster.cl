/* NDRF visibility-buffer rasteriser (docs/ndrf.md "Hits"), binned into screen tiles; mirrors
 * the Embree first hits of clrender/ndrf/hits.py, which the tests hold it to:
 *   ndrf_raster_clear  the tiles' triangle counts = 0.
 *   ndrf_raster_setup  per triangle (all K meshes, faces concatenated): to camera space, edge
 *                      normals, screen bounds (tri_geo, tri_box).
 *   ndrf_raster_count  per triangle: counted in every TS x TS tile its edges do not exclude
 *                      (tile_overlaps).
 *   ndrf_raster_scan   the counts to each tile's first slot in the triangle list.
 *   ndrf_raster_bin    per triangle: its index into the list of every tile it overlaps.
 *   ndrf_raster_tile   per tile (TROWS of its rows a work-item): every listed triangle tested
 *                      against the tile's pixels, TS columns at once as one vector; per
 *                      pixel and mesh the nearest triangle, its Embree (u, v) and its depth
 *                      along the unit ray (from the same edge functions: no gather, no
 *                      second pass) kept in private memory, then written once. No atomics
 *                      on the depth: a tile owns its pixels.
 *
 * Coverage is exact ray-triangle coverage in camera space (homogeneous rasterisation,
 * Olano & Greer 1997): with camera-space vertices v0, v1, v2 and the pixel ray
 * r = (a, b, -1) of kernels/camera.h, the edge functions E_ij = (v_i x v_j) . r all share
 * the sign of V = det(v0, v1, v2) exactly when the ray's line crosses the triangle in
 * front of the camera, at t = V / (n . r) > 0 with n = (v1 - v0) x (v2 - v0) (the sum of
 * the three edge normals; V = n . v0). Each is computed without the cancellation of long
 * vectors (edge_normal), so a small triangle far away keeps its edges and depth. No near
 * plane is needed: a triangle crossing the camera plane is neither dropped nor clipped, its
 * pixels are those Embree (tnear = 0) hits. A zero-area or edge-on triangle (V = 0) covers
 * nothing.
 * Tie rule: a pixel centre on an edge (E = 0) is covered only where the edge's normal
 * c = sign(V) (v_i x v_j) is lexicographically positive. Two triangles sharing an edge,
 * facing the same way, compute exactly opposite c (a cross product with swapped operands
 * negates exactly without contraction) and evaluate E in one fixed order, so such a pixel
 * is covered exactly once.
 * Depth test: per pixel and mesh the least camera-space depth V / (n . r), the smaller
 * triangle id on a tie (whatever order the tile's list holds its triangles in).
 *
 * Buffers: tri_geo (faces, 16) float: c (9), n (3), V, 3 unused; tri_box (faces, 8) int:
 * x0, y0, x1, y1 inclusive pixel bounds (x0 > x1: covers nothing), mesh, face within it,
 * tie-ownership bits of the 3 edges, 0; tile_count (n_tiles) int, then each tile's cursor
 * (its first slot, advanced by ndrf_raster_bin); tile_start (n_tiles + 1) int; list
 * (capacity) int; out tri (K, H, W) int (-1: miss), bary (K, H, W) float2, depth (K, H, W)
 * float (inf on a miss). ray_ab: the pixel rays' a (tiles_x * TS floats; NaN past the
 * image's last column, so nothing covers them), then b (height floats) of
 * kernels/camera.h, computed once a frame on the host with the same float32 operations
 * (clrender/ndrf/raster_cl.py).
 * -D defines (clrender/ndrf/raster_cl.py): K, TS (tile side: 16, the vector width),
 * TROWS (rows of a tile a work-item covers, dividing TS: TS on CPUs, 1 on GPUs).
 */
#include "camera.h"
#pragma OPENCL FP_CONTRACT OFF

#if !defined(K) || !defined(TS) || !defined(TROWS)
#error "ndrf_raster.cl needs -D K TS TROWS"
#endif
#if TS != 16 || TS % TROWS != 0
#error "TS must be 16 (one float16 a tile row) and a multiple of TROWS"
#endif
#define GROUPS (TS / TROWS)
#define NONE 0x7fffffff
/* Where ray_ab's b values start: after the a of every column of whole tiles. */
#define RAY_B(width) (((width) + TS - 1) / TS * TS)

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

/* The pixel column (or row) range [lo, hi] whose centres +0.5 fall in [a, b], widened by
 * 0.05 pixels (a projected vertex is placed within ~1e-3 pixels: a few float32 roundings of
 * coordinates below 2^14; the edge functions decide). */
inline int2 pixel_range(float a, float b, int n)
{
    const float lo = fmin(fmax(ceil(a - 0.5f - 0.05f), 0.0f), (float)n);
    const float hi = fmax(fmin(floor(b - 0.5f + 0.05f), (float)(n - 1)), -1.0f);
    return (int2)((int)lo, (int)hi);
}

/* s (v_a x v_b) of camera-space vertices va, vb (global indices ia, ib) into out, computed as
 * v_lo x (v_hi - v_lo) from the vertex of the smaller index: the same value in exact
 * arithmetic, but without the cancellation of two long vectors (a small triangle far from
 * the eye), and, since both triangles of a shared edge compute the same product, still
 * exactly negated between them. */
inline void edge_normal(const float *va, const float *vb, int ia, int ib, float s, float *out)
{
    const int swap = !(ia < ib);
    float lo[3], d[3];
    for (int j = 0; j < 3; ++j) {
        lo[j] = swap ? vb[j] : va[j];
        d[j] = (swap ? va[j] : vb[j]) - lo[j];
    }
    cross_scaled(lo, d, swap ? -s : s, out);
}

/* Triangle g of the concatenated faces: its mesh, camera-space edge normals and inclusive
 * pixel bounds. Returns 0 when it cannot cover a pixel (degenerate, behind the camera, off
 * screen, or between pixel centres); t is then filled all the same (straight-line code),
 * its values meaningless. */
inline int tri_setup(int g, __global const float *cam, int width, int height,
                     __global const int *face_start, __global const int *faces,
                     __global const int *face_ids, __global const float *vertices, Tri *t)
{
    int k = 0;
    for (int j = 1; j < K; ++j) k += g >= face_start[j];
    t->mesh = k;
    t->id = face_ids[g];
    const int i0 = faces[3 * g], i1 = faces[3 * g + 1], i2 = faces[3 * g + 2];
    float v0[3], v1[3], v2[3], e1[3], e2[3], n[3];
    to_camera(cam, vertices + 3 * i0, v0);
    to_camera(cam, vertices + 3 * i1, v1);
    to_camera(cam, vertices + 3 * i2, v2);
    for (int j = 0; j < 3; ++j) {
        e1[j] = v1[j] - v0[j];
        e2[j] = v2[j] - v0[j];
    }
    cross_scaled(e1, e2, 1.0f, n);
    const float V = n[0] * v0[0] + n[1] * v0[1] + n[2] * v0[2];
    const float s = V > 0.0f ? 1.0f : -1.0f;
    edge_normal(v1, v2, i1, i2, s, t->c);
    edge_normal(v2, v0, i2, i0, s, t->c + 3);
    edge_normal(v0, v1, i0, i1, s, t->c + 6);
    for (int j = 0; j < 3; ++j) t->n[j] = s * n[j];
    t->V = s * V;
    /* Camera looks down -z: depth -z. A vertex at or behind the camera plane: the covered
     * rays may lie anywhere on screen, bound by the image. */
    const float eps = 1e-7f;
    const int near = -v0[2] <= eps || -v1[2] <= eps || -v2[2] <= eps;
    const float ax = v0[0] / -v0[2], bx = v1[0] / -v1[2], cx = v2[0] / -v2[2];
    const float ay = v0[1] / -v0[2], by = v1[1] / -v1[2], cy = v2[1] / -v2[2];
    /* pixel x + 0.5 = cx + fx a, y + 0.5 = cy - fy b (kernels/camera.h) */
    const float sx0 = cam[2] + cam[0] * fmin(ax, fmin(bx, cx));
    const float sx1 = cam[2] + cam[0] * fmax(ax, fmax(bx, cx));
    const float sy0 = cam[3] - cam[1] * fmax(ay, fmax(by, cy));
    const float sy1 = cam[3] - cam[1] * fmin(ay, fmin(by, cy));
    const int2 xr = pixel_range(sx0, sx1, width), yr = pixel_range(sy0, sy1, height);
    t->x0 = near ? 0 : xr.x;
    t->x1 = near ? width - 1 : xr.y;
    t->y0 = near ? 0 : yr.x;
    t->y1 = near ? height - 1 : yr.y;
    const int facing = V != 0.0f && !(v0[2] >= 0.0f && v1[2] >= 0.0f && v2[2] >= 0.0f);
    return facing && t->x0 <= t->x1 && t->y0 <= t->y1;
}

/* Whether a pixel centre exactly on edge c (3 floats, E = 0) counts as covered: c
 * lexicographically positive (the tie rule). */
inline int edge_owns_ties(const float *c)
{
    return c[0] > 0.0f || (c[0] == 0.0f && (c[1] > 0.0f || (c[1] == 0.0f && c[2] > 0.0f)));
}

/* Whether some pixel centre of the tile of columns [px0, px1], rows [py0, py1] may have all
 * three edge functions of t >= 0. Each E = c0 a + c1 b - c2 is linear in the pixel ray's
 * (a, b), so its largest value over the tile is at a corner; a tile is excluded only where
 * that is below zero by more than its rounding (1e-5 of the terms' magnitude, ~80 ulp):
 * never a pixel the exact test would cover. */
inline int tile_overlaps(const float *c, __global const float *ray_ab, int width, int px0,
                         int py0, int px1, int py1)
{
    const float a0 = ray_ab[px0], a1 = ray_ab[px1];
    const float b0 = ray_ab[RAY_B(width) + py0], b1 = ray_ab[RAY_B(width) + py1];
    for (int e = 0; e < 3; ++e) {
        const float c0 = c[3 * e], c1 = c[3 * e + 1], c2 = c[3 * e + 2];
        const float a = c0 > 0.0f ? fmax(a0, a1) : fmin(a0, a1);
        const float b = c1 > 0.0f ? fmax(b0, b1) : fmin(b0, b1);
        const float top = c0 * a + c1 * b - c2;
        const float size = fabs(c0 * a) + fabs(c1 * b) + fabs(c2);
        if (top < -1e-5f * size) return 0;
    }
    return 1;
}

__kernel void ndrf_raster_clear(const int n_tiles, __global int *tile_count)
{
    const int i = (int)get_global_id(0);
    if (i < n_tiles) tile_count[i] = 0;
}

__kernel void ndrf_raster_setup(__global const float *cam, const int width, const int height,
                                const int n_faces, __global const int *face_start,
                                __global const int *faces, __global const int *face_ids,
                                __global const float *vertices, __global float *tri_geo,
                                __global int *tri_box)
{
    const int g = (int)get_global_id(0);
    if (g >= n_faces) return;
    Tri t;
    const int ok = tri_setup(g, cam, width, height, face_start, faces, face_ids, vertices, &t);
    __global float *geo = tri_geo + 16 * g;
    for (int j = 0; j < 9; ++j) geo[j] = t.c[j];
    for (int j = 0; j < 3; ++j) geo[9 + j] = t.n[j];
    geo[12] = t.V;
    geo[13] = geo[14] = geo[15] = 0.0f;
    const int own = edge_owns_ties(t.c) | edge_owns_ties(t.c + 3) << 1
                    | edge_owns_ties(t.c + 6) << 2;
    __global int *box = tri_box + 8 * g;
    box[0] = ok ? t.x0 : 1;             /* x0 > x1: covers nothing */
    box[1] = t.y0;
    box[2] = ok ? t.x1 : 0;
    box[3] = t.y1;
    box[4] = t.mesh;
    box[5] = t.id;
    box[6] = own;
    box[7] = 0;
}

/* The tiles of triangle g that its edges do not exclude, counted (atomic) or each given
 * the triangle's index in its list (at the tile's cursor). */
inline void for_each_tile(int g, int width, __global const float *ray_ab,
                          __global const float *tri_geo, __global const int *tri_box,
                          volatile __global int *counter, const int capacity,
                          __global int *list)
{
    const int4 b = vload4(0, tri_box + 8 * g);
    if (b.x > b.z) return;
    float c[9];
    for (int j = 0; j < 9; ++j) c[j] = tri_geo[16 * g + j];
    const int tiles_x = (width + TS - 1) / TS;
    for (int ty = b.y / TS; ty <= b.w / TS; ++ty)
        for (int tx = b.x / TS; tx <= b.z / TS; ++tx)
            if (tile_overlaps(c, ray_ab, width, max(tx * TS, b.x), max(ty * TS, b.y),
                              min(tx * TS + TS - 1, b.z), min(ty * TS + TS - 1, b.w))) {
                const int slot = atomic_inc(counter + ty * tiles_x + tx);
                if (list && slot < capacity) list[slot] = g;
            }
}

__kernel void ndrf_raster_count(const int width, const int n_faces,
                                __global const float *ray_ab, __global const float *tri_geo,
                                __global const int *tri_box, volatile __global int *tile_count)
{
    const int g = (int)get_global_id(0);
    if (g < n_faces) for_each_tile(g, width, ray_ab, tri_geo, tri_box, tile_count, 0, 0);
}

/* One work-item: tile_start = the exclusive prefix sum of tile_count, tile_start[n_tiles]
 * the total; tile_count becomes each tile's cursor (its first slot). */
__kernel void ndrf_raster_scan(const int n_tiles, __global int *tile_count,
                               __global int *tile_start)
{
    if (get_global_id(0) != 0) return;
    int s = 0;
    for (int i = 0; i < n_tiles; ++i) {
        const int c = tile_count[i];
        tile_start[i] = s;
        tile_count[i] = s;
        s += c;
    }
    tile_start[n_tiles] = s;
}

__kernel void ndrf_raster_bin(const int width, const int n_faces, __global const float *ray_ab,
                              __global const float *tri_geo, __global const int *tri_box,
                              volatile __global int *cursor, const int capacity,
                              __global int *list)
{
    const int g = (int)get_global_id(0);
    if (g < n_faces) for_each_tile(g, width, ray_ab, tri_geo, tri_box, cursor, capacity, list);
}

/* Rows [y0, y0 + TROWS) of the tile at column x0: every triangle of its list against the TS
 * pixels of each row at once (a float16 of pixel rays), E = c0 a + (c1 b - c2) in the fixed
 * order of a shared edge's other triangle; the nearest (then smallest id) per pixel and mesh
 * kept in best / best_id with its barycentrics, then written out as the hits. These come
 * from the same edge functions: with E_0, E_1, E_2 those of the edges opposite v0, v1, v2
 * and n . r = E_0 + E_1 + E_2, the ray meets the triangle at Embree's u = E_1 / (n . r),
 * v = E_2 / (n . r) (ratios of the tetrahedra (eye, v_i, v_j)), at camera-space depth
 * V / (n . r), i.e. at distance V / (n . r) |(a, b, -1)| along the unit ray. */
__kernel void ndrf_raster_tile(const int width, const int height, __global const float *ray_ab,
                               __global const float *tri_geo, __global const int *tri_box,
                               __global const int *tile_start, __global const int *list,
                               __global int *tri, __global float *bary, __global float *depth)
{
    const int tx = (int)get_global_id(0), gy = (int)get_global_id(1);
    const int ty = gy / GROUPS;
    const int x0 = tx * TS, y0 = ty * TS + (gy - ty * GROUPS) * TROWS;  /* no %: Oclgrind */
    if (x0 >= width || y0 >= height) return;
    const int tile = ty * ((width + TS - 1) / TS) + tx;
    const float16 rx = vload16(0, ray_ab + x0);
    __global const float *ray_b = ray_ab + RAY_B(width);
    float16 best[K][TROWS], best_u[K][TROWS], best_v[K][TROWS];
    int16 best_id[K][TROWS];
    for (int k = 0; k < K; ++k)
        for (int r = 0; r < TROWS; ++r) {
            best[k][r] = (float16)(INFINITY);
            best_u[k][r] = best_v[k][r] = (float16)(0.0f);
            best_id[k][r] = (int16)(NONE);
        }
    const int end = tile_start[tile + 1];
    for (int i = tile_start[tile]; i < end; ++i) {
        const int g = list[i];
        const int8 box = vload8(0, tri_box + 8 * g);
        const int r0 = max(box.s1 - y0, 0), r1 = min(box.s3 - y0, TROWS - 1);
        if (r0 > r1) continue;
        __global const float *geo = tri_geo + 16 * g;
        const float c00 = geo[0], c01 = geo[1], c02 = geo[2], c10 = geo[3], c11 = geo[4],
                    c12 = geo[5], c20 = geo[6], c21 = geo[7], c22 = geo[8], n0 = geo[9],
                    n1 = geo[10], n2 = geo[11], V = geo[12];
        const int16 own0 = (int16)(-(box.s6 & 1)), own1 = (int16)(-((box.s6 >> 1) & 1)),
                    own2 = (int16)(-((box.s6 >> 2) & 1)), id = (int16)(box.s5);
        const int k = box.s4;
        for (int r = r0; r <= r1; ++r) {
            const float ry = ray_b[y0 + r];
            const float16 e0 = c00 * rx + (c01 * ry - c02), e1 = c10 * rx + (c11 * ry - c12),
                          e2 = c20 * rx + (c21 * ry - c22), en = n0 * rx + (n1 * ry - n2);
            const int16 cov = ((e0 > 0.0f) | ((e0 == 0.0f) & own0))
                              & ((e1 > 0.0f) | ((e1 == 0.0f) & own1))
                              & ((e2 > 0.0f) | ((e2 == 0.0f) & own2)) & (en > 0.0f);
            if (!any(cov)) continue;
            const float16 inv_en = 1.0f / en, dist = V * inv_en;   /* one division */
            const float16 b = best[k][r];
            const int16 better = cov & ((dist < b) | ((dist == b) & (id < best_id[k][r])));
            best[k][r] = select(b, dist, better);
            best_u[k][r] = select(best_u[k][r], e1 * inv_en, better);
            best_v[k][r] = select(best_v[k][r], e2 * inv_en, better);
            best_id[k][r] = select(best_id[k][r], id, better);
        }
    }
    const int n = width * height, cols = min(TS, width - x0);
    for (int r = 0; r < TROWS && y0 + r < height; ++r) {
        const float ry = ray_b[y0 + r];
        /* |(a, b, -1)|: camera-space depth to distance along the unit ray */
        const float16 len = sqrt(rx * rx + (ry * ry + 1.0f));
        for (int k = 0; k < K; ++k) {
            const int16 hit = best_id[k][r] != NONE;
            const int16 id = select((int16)(-1), best_id[k][r], hit);
            /* Clamped into the triangle, as Embree's: a covered pixel may sit a rounding
             * error outside. */
            const float16 u = select((float16)(0.0f), clamp(best_u[k][r], 0.0f, 1.0f), hit);
            const float16 v = select((float16)(0.0f), clamp(best_v[k][r], 0.0f, 1.0f - u), hit);
            const float16 t = select((float16)(INFINITY), best[k][r] * len, hit);
            const int p = k * n + (y0 + r) * width + x0;
            if (cols == TS) {
                vstore16(id, 0, tri + p);
                vstore16(t, 0, depth + p);
            }
            if (cols == TS && !any(hit)) {
                vstore16((float16)(0.0f), 0, bary + 2 * p);
                vstore16((float16)(0.0f), 0, bary + 2 * p + TS);
            } else {
                float uv[2][TS];
                vstore16(u, 0, uv[0]);
                vstore16(v, 0, uv[1]);
                for (int x = 0; x < cols; ++x)
                    vstore2((float2)(uv[0][x], uv[1][x]), p + x, bary);
            }
            if (cols < TS) {
                int ids[TS];
                float ts[TS];
                vstore16(id, 0, ids);
                vstore16(t, 0, ts);
                for (int x = 0; x < cols; ++x) {
                    tri[p + x] = ids[x];
                    depth[p + x] = ts[x];
                }
            }
        }
    }
}
