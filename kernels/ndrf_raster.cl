/* NDRF visibility-buffer rasteriser (docs/ndrf.md "Hits"), binned into screen tiles; mirrors
 * the Embree first hits of clrender/ndrf/hits.py, which the tests hold it to:
 *   ndrf_raster_setup  per triangle (all K meshes, faces concatenated; LANES a work-item,
 *                      one a vector lane): to camera space, edge normals, screen bounds
 *                      (tri_geo, tri_box); then counted in every TS x TS tile its edges do
 *                      not exclude (tile_overlaps).
 *   ndrf_raster_scan   one work-group: the counts to each tile's first slot in the triangle
 *                      list (a parallel prefix sum), and back to 0 for the next frame.
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
 * Buffers: tri_geo (faces, TRI_WORDS) 32-bit words, all the tile pass reads of a triangle
 * in one 64-byte record (offsets TRI_* below): c (9), n (3), V (floats), then its rows
 * y0 | y1 << 16, its face within its mesh, its mesh | the tie-ownership bits of its 3
 * edges << 8 (ints); tri_box
 * (faces, 4) int: x0, y0, x1, y1 inclusive pixel bounds (x0 > x1: covers nothing);
 * tile_count (n_tiles) int, 0 between frames (zeroed when allocated, then by the scan);
 * cursor (n_tiles) int, each tile's next free slot (its first, advanced by ndrf_raster_bin);
 * tile_start (n_tiles + 1) int; list
 * (capacity) int, nothing past capacity written or read (an overflowed frame); out tri
 * (K, H, W) int (-1: miss), bary (K, H, W) float2, depth (K, H, W) float (inf on a miss).
 * ray_ab: the pixel rays' a (tiles_x * TS floats; NaN past the image's last column, so
 * nothing covers them), then b (height floats) of
 * kernels/camera.h, computed once a frame on the host with the same float32 operations
 * (clrender/ndrf/raster_cl.py).
 * -D defines (clrender/ndrf/raster_cl.py): K, TRI_WORDS (a triangle record's words: 16),
 * TS (tile side: 16, the vector width),
 * TROWS (rows of a tile a work-item covers, dividing TS: TS on CPUs, 1 on GPUs), LANES
 * (triangles a setup work-item: 16 on CPUs, one a float16 lane; 1 on GPUs).
 */
#include "camera.h"
#pragma OPENCL FP_CONTRACT OFF

#if !defined(K) || !defined(TS) || !defined(TROWS) || !defined(LANES) || !defined(TRI_WORDS)
#error "ndrf_raster.cl needs -D K TS TROWS LANES TRI_WORDS"
#endif
#if TS != 16 || TS % TROWS != 0
#error "TS must be 16 (one float16 a tile row) and a multiple of TROWS"
#endif
/* The setup's values, one a triangle: lfloat / lint hold LANES of them (scalars at
 * LANES = 1). Masks are only combined with & | and consumed by select(), so the scalar
 * comparisons' 1 / 0 serve as the vectors' -1 / 0. */
#if LANES == 1
typedef float lfloat;
typedef int lint;
#define LANE_IDS 0
#define CONVERT_LINT(x) convert_int(x)
#define LLOAD(p) (*(p))
#define LSTORE(v, p) (*(p) = (v))
#elif LANES == 16
typedef float16 lfloat;
typedef int16 lint;
#define LANE_IDS ((int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define CONVERT_LINT(x) convert_int16(x)
#define LLOAD(p) vload16(0, p)
#define LSTORE(v, p) vstore16(v, 0, p)
#else
#error "LANES must be 1 or 16 (the setup's triangles a work-item, one a vector lane)"
#endif
/* The triangle record's fields (word offsets). */
#define TRI_C 0                 /* 3 edge functions, 3 floats each */
#define TRI_N 9                 /* the plane normal (3 floats) */
#define TRI_V 12                /* the plane offset */
#define TRI_ROWS 13             /* y0 | y1 << 16 */
#define TRI_FACE 14             /* its face within its mesh */
#define TRI_META 15             /* its mesh | its edges' tie bits << 8 */
#if TRI_WORDS != TRI_META + 1
#error "TRI_WORDS must count the record's fields"
#endif
#define GROUPS (TS / TROWS)
#define NONE 0x7fffffff
/* Where ray_ab's b values start: after the a of every column of whole tiles. */
#define RAY_B(width) (((width) + TS - 1) / TS * TS)

/* Triangle setup, LANES triangles a work-item, one per lane (on PoCL a scalar work-item
 * per triangle is slower: calls and gathers do not vectorise across work-items;
 * docs/explanation/gpu-paths.md, "One triangle a setup work-item on GPUs"). Points and vectors are 3 lfloat (x, y, z), one triangle a lane; every
 * lane computes with the float32 operations of the scalar version (LANES = 1), in the
 * same order. */

/* p (world) to camera space: R^T (p - origin), R row-major at cam[CAM_R..]. */
inline void to_camera(__global const float *cam, const lfloat *p, lfloat *v)
{
    const lfloat qx = p[0] - cam[CAM_O + 0], qy = p[1] - cam[CAM_O + 1],
                 qz = p[2] - cam[CAM_O + 2];
    v[0] = cam[CAM_R + 0] * qx + cam[CAM_R + 3] * qy + cam[CAM_R + 6] * qz;
    v[1] = cam[CAM_R + 1] * qx + cam[CAM_R + 4] * qy + cam[CAM_R + 7] * qz;
    v[2] = cam[CAM_R + 2] * qx + cam[CAM_R + 5] * qy + cam[CAM_R + 8] * qz;
}

/* out = s (a x b). Arrays of lfloat, not float3 vectors: float3 values built in helpers
 * crash the --uninitialized plugin of Oclgrind 21.10. */
inline void cross_scaled(const lfloat *a, const lfloat *b, lfloat s, lfloat *out)
{
    out[0] = s * (a[1] * b[2] - a[2] * b[1]);
    out[1] = s * (a[2] * b[0] - a[0] * b[2]);
    out[2] = s * (a[0] * b[1] - a[1] * b[0]);
}

/* The pixel column (or row) ranges [lo, hi] whose centres +0.5 fall in [a, b], widened by
 * 0.05 pixels (a projected vertex is placed within ~1e-3 pixels: a few float32 roundings of
 * coordinates below 2^14; the edge functions decide). */
inline void pixel_range(lfloat a, lfloat b, int n, lint *lo, lint *hi)
{
    *lo = CONVERT_LINT(fmin(fmax(ceil(a - 0.5f - 0.05f), 0.0f), (float)n));
    *hi = CONVERT_LINT(fmax(fmin(floor(b - 0.5f + 0.05f), (float)(n - 1)), -1.0f));
}

/* s (v_a x v_b) of camera-space vertices va, vb (global indices ia, ib) into out, computed as
 * v_lo x (v_hi - v_lo) from the vertex of the smaller index: the same value in exact
 * arithmetic, but without the cancellation of two long vectors (a small triangle far from
 * the eye), and, since both triangles of a shared edge compute the same product, still
 * exactly negated between them. */
inline void edge_normal(const lfloat *va, const lfloat *vb, lint ia, lint ib, lfloat s,
                        lfloat *out)
{
    const lint swap = ia >= ib;
    lfloat lo[3], d[3];
    for (int j = 0; j < 3; ++j) {
        lo[j] = select(va[j], vb[j], swap);
        d[j] = select(vb[j], va[j], swap) - lo[j];
    }
    cross_scaled(lo, d, select(s, -s, swap), out);
}

/* Whether a pixel centre exactly on edge c (E = 0) counts as covered: c lexicographically
 * positive (the tie rule); 1 or 0 a lane. (Masks become 0 / 1 by select(): Oclgrind 21.10
 * evaluates -mask and mask & 1 of vector comparisons as 255.) */
inline lint edge_owns_ties(const lfloat *c)
{
    return select((lint)(0), (lint)(1), (c[0] > 0.0f) | ((c[0] == 0.0f)
                  & ((c[1] > 0.0f) | ((c[1] == 0.0f) & (c[2] > 0.0f)))));
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

/* The tiles of triangle g (edge normals c, inclusive pixel box b) that its edges do not
 * exclude, counted (atomic) or each given the triangle's index in its list (at the tile's
 * cursor). */
inline void for_each_tile(int g, const float *c, int4 b, int width,
                          __global const float *ray_ab, volatile __global int *counter,
                          const int capacity, __global int *list)
{
    if (b.x > b.z) return;
    const int tiles_x = (width + TS - 1) / TS;
    for (int ty = b.y / TS; ty <= b.w / TS; ++ty)
        for (int tx = b.x / TS; tx <= b.z / TS; ++tx)
            if (tile_overlaps(c, ray_ab, width, max(tx * TS, b.x), max(ty * TS, b.y),
                              min(tx * TS + TS - 1, b.z), min(ty * TS + TS - 1, b.w))) {
                const int slot = atomic_inc(counter + ty * tiles_x + tx);
                if (list && slot < capacity) list[slot] = g;
            }
}

/* Triangles g0 .. g0 + LANES - 1 of the concatenated faces: camera-space edge normals, n and
 * V, their mesh and face within it, inclusive pixel bounds and tie bits into tri_geo and
 * tri_box, and each counted in its tiles (tile_count). A triangle that cannot cover a pixel
 * (degenerate, behind the camera, off screen, or between pixel centres) gets bounds
 * x0 > x1. */
/* vec_type_hint: the lanes are explicit (LANES triangles a work-item); Intel's CPU
 * compiler keeps them (ngprt_march.cl says why). */
__kernel __attribute__((vec_type_hint(lfloat)))
void ndrf_raster_setup(__global const float *cam, const int width, const int height,
                       const int n_faces, __global const int *face_start,
                       __global const int *faces, __global const int *face_ids,
                       __global const float *vertices, __global const float *ray_ab,
                       __global float *tri_geo, __global int *tri_box,
                       volatile __global int *tile_count)
{
    const int g0 = (int)get_global_id(0) * LANES;
    if (g0 >= n_faces) return;
    /* Gather the lanes' vertex indices and world positions (past n_faces: the last face). */
    int index[3][LANES], id[LANES];
    float world[3][3][LANES];
    for (int l = 0; l < LANES; ++l) {
        const int g = min(g0 + l, n_faces - 1);
        id[l] = face_ids[g];
        for (int j = 0; j < 3; ++j) {
            index[j][l] = faces[3 * g + j];
            for (int e = 0; e < 3; ++e) world[j][e][l] = vertices[3 * index[j][l] + e];
        }
    }
    const lint g = g0 + LANE_IDS;
    lint mesh = (lint)(0), i[3];
    for (int j = 1; j < K; ++j) mesh += select((lint)(0), (lint)(1), g >= face_start[j]);
    lfloat v[3][3], p[3], e1[3], e2[3], n[3], c[3][3];
    for (int j = 0; j < 3; ++j) {
        i[j] = LLOAD(index[j]);
        for (int e = 0; e < 3; ++e) p[e] = LLOAD(world[j][e]);
        to_camera(cam, p, v[j]);
    }
    for (int e = 0; e < 3; ++e) {
        e1[e] = v[1][e] - v[0][e];
        e2[e] = v[2][e] - v[0][e];
    }
    cross_scaled(e1, e2, (lfloat)(1.0f), n);
    const lfloat V = n[0] * v[0][0] + n[1] * v[0][1] + n[2] * v[0][2];
    const lfloat s = select((lfloat)(-1.0f), (lfloat)(1.0f), V > 0.0f);
    edge_normal(v[1], v[2], i[1], i[2], s, c[0]);
    edge_normal(v[2], v[0], i[2], i[0], s, c[1]);
    edge_normal(v[0], v[1], i[0], i[1], s, c[2]);
    /* Camera looks down -z: depth -z. A vertex at or behind the camera plane: the covered
     * rays may lie anywhere on screen, bound by the image. */
    const float eps = 1e-7f;
    const lint near = (-v[0][2] <= eps) | (-v[1][2] <= eps) | (-v[2][2] <= eps);
    lfloat sx[3], sy[3];
    for (int j = 0; j < 3; ++j) {
        sx[j] = v[j][0] / -v[j][2];
        sy[j] = v[j][1] / -v[j][2];
    }
    /* pixel x + 0.5 = cx + fx a, y + 0.5 = cy - fy b (kernels/camera.h) */
    lint x0, x1, y0, y1;
    pixel_range(cam[CAM_CX] + cam[CAM_FX] * fmin(sx[0], fmin(sx[1], sx[2])),
                cam[CAM_CX] + cam[CAM_FX] * fmax(sx[0], fmax(sx[1], sx[2])), width, &x0, &x1);
    pixel_range(cam[CAM_CY] - cam[CAM_FY] * fmax(sy[0], fmax(sy[1], sy[2])),
                cam[CAM_CY] - cam[CAM_FY] * fmin(sy[0], fmin(sy[1], sy[2])), height, &y0, &y1);
    x0 = select(x0, (lint)(0), near);
    x1 = select(x1, (lint)(width - 1), near);
    y0 = select(y0, (lint)(0), near);
    y1 = select(y1, (lint)(height - 1), near);
    const lint facing = (V != 0.0f) & ((v[0][2] < 0.0f) | (v[1][2] < 0.0f) | (v[2][2] < 0.0f));
    const lint ok = facing & (x0 <= x1) & (y0 <= y1);
    /* The records, lane by lane through private memory. */
    float rec[TRI_ROWS][LANES];
    int rows[LANES], meta[LANES], box[4][LANES];
    for (int j = 0; j < 3; ++j)
        for (int e = 0; e < 3; ++e) LSTORE(c[j][e], rec[TRI_C + 3 * j + e]);
    for (int j = 0; j < 3; ++j) LSTORE(s * n[j], rec[TRI_N + j]);
    LSTORE(s * V, rec[TRI_V]);
    LSTORE(y0 | y1 << 16, rows);      /* height < 2^16 (clrender/ndrf/raster_cl.py) */
    LSTORE(mesh | (edge_owns_ties(c[0]) | edge_owns_ties(c[1]) << 1
                   | edge_owns_ties(c[2]) << 2) << 8, meta);
    LSTORE(select((lint)(1), x0, ok), box[0]);    /* x0 > x1: covers nothing */
    LSTORE(y0, box[1]);
    LSTORE(select((lint)(0), x1, ok), box[2]);
    LSTORE(y1, box[3]);
    for (int l = 0; l < LANES && g0 + l < n_faces; ++l) {
        __global float *geo = tri_geo + TRI_WORDS * (g0 + l);
        __global int *w = (__global int *)geo;
        for (int j = 0; j < TRI_ROWS; ++j) geo[j] = rec[j][l];
        w[TRI_ROWS] = rows[l];
        w[TRI_FACE] = id[l];
        w[TRI_META] = meta[l];
        for (int j = 0; j < 4; ++j) tri_box[4 * (g0 + l) + j] = box[j][l];
        float cl[9];
        for (int j = 0; j < 9; ++j) cl[j] = rec[TRI_C + j][l];
        for_each_tile(g0 + l, cl, (int4)(box[0][l], box[1][l], box[2][l], box[3][l]), width,
                      ray_ab, tile_count, 0, 0);
    }
}

/* One work-group of n = get_local_size(0) work-items, sums (n) int of local memory:
 * tile_start = the exclusive prefix sum of tile_count, tile_start[n_tiles] the total;
 * cursor = tile_start; tile_count = 0 (the next frame counts into it). Work-item i scans
 * the i-th contiguous block of ceil(n_tiles / n) tiles: its block's sum, the block sums'
 * inclusive scan in local memory (Hillis-Steele, ceil(log2 n) steps), then its block's
 * offsets. Integer sums: the same values as a serial scan in any order. */
__kernel void ndrf_raster_scan(const int n_tiles, __global int *tile_count,
                               __global int *tile_start, __global int *cursor,
                               __local int *sums)
{
    const int i = (int)get_local_id(0), n = (int)get_local_size(0);
    const int per = (n_tiles + n - 1) / n;
    const int i0 = min(i * per, n_tiles), i1 = min(i0 + per, n_tiles);
    int own = 0;
    for (int t = i0; t < i1; ++t) own += tile_count[t];
    sums[i] = own;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int d = 1; d < n; d *= 2) {
        const int left = i >= d ? sums[i - d] : 0;
        barrier(CLK_LOCAL_MEM_FENCE);
        sums[i] += left;
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    int s = sums[i] - own;
    for (int t = i0; t < i1; ++t) {
        const int c = tile_count[t];
        tile_start[t] = cursor[t] = s;
        tile_count[t] = 0;
        s += c;
    }
    if (i == n - 1) tile_start[n_tiles] = s;
}

__kernel void ndrf_raster_bin(const int width, const int n_faces, __global const float *ray_ab,
                              __global const float *tri_geo, __global const int *tri_box,
                              volatile __global int *cursor, const int capacity,
                              __global int *list)
{
    const int g = (int)get_global_id(0);
    if (g >= n_faces) return;
    float c[9];
    for (int j = 0; j < 9; ++j) c[j] = tri_geo[TRI_WORDS * g + TRI_C + j];
    for_each_tile(g, c, vload4(g, tri_box), width, ray_ab, cursor, capacity, list);
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
                               __global const float *tri_geo, __global const int *tile_start,
                               const int capacity, __global const int *list,
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
    /* A frame that binned more pairs than the list holds reads only the list (its hits are
     * incomplete; the host grows the list and bins the frame again). */
    const int end = min(tile_start[tile + 1], capacity);
    for (int i = tile_start[tile]; i < end; ++i) {
        const int g = list[i];
        __global const float *geo = tri_geo + TRI_WORDS * g;
        __global const int *words = (__global const int *)geo;
        const uint rows = (uint)words[TRI_ROWS];
        const int meta = words[TRI_META];
        const int r0 = max((int)(rows & 0xffff) - y0, 0);
        const int r1 = min((int)(rows >> 16) - y0, TROWS - 1);
        if (r0 > r1) continue;
        __global const float *tc = geo + TRI_C, *tn = geo + TRI_N;
        const float c00 = tc[0], c01 = tc[1], c02 = tc[2], c10 = tc[3], c11 = tc[4],
                    c12 = tc[5], c20 = tc[6], c21 = tc[7], c22 = tc[8], n0 = tn[0],
                    n1 = tn[1], n2 = tn[2], V = geo[TRI_V];
        const int16 own0 = (int16)(-((meta >> 8) & 1)), own1 = (int16)(-((meta >> 9) & 1)),
                    own2 = (int16)(-((meta >> 10) & 1)), id = (int16)(words[TRI_FACE]);
        const int k = meta & 0xff;
        for (int r = r0; r <= r1; ++r) {
            const float ry = ray_b[y0 + r];
            const float16 e0 = c00 * rx + (c01 * ry - c02), e1 = c10 * rx + (c11 * ry - c12),
                          e2 = c20 * rx + (c21 * ry - c22), en = n0 * rx + (n1 * ry - n2);
            const int16 cov = ((e0 > 0.0f) | ((e0 == 0.0f) & own0))
                              & ((e1 > 0.0f) | ((e1 == 0.0f) & own1))
                              & ((e2 > 0.0f) | ((e2 == 0.0f) & own2)) & (en > 0.0f);
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
            if (cols == TS) {   /* (u, v) pairs interleaved: two shuffles, two stores */
                vstore16(shuffle2(u, v, (uint16)(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6,
                                                 22, 7, 23)), 0, bary + 2 * p);
                vstore16(shuffle2(u, v, (uint16)(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13,
                                                 29, 14, 30, 15, 31)), 0, bary + 2 * p + TS);
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
