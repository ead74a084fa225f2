/* NDRF shading (docs/ndrf.md), two pixel-parallel passes, one per conv layer as in the
 * paper's WebGL shader; mirrors clrender/ndrf/shader_ref.py:
 *   ndrf_conv0   KSIZE x KSIZE conv C_IN -> HIDDEN, ReLU -> hidden, over the screen pixels
 *                (x..x+PAD, y..y+PAD) (padding bottom/right), factored by linearity (see
 *                the kernel): a hit's 11 geometry channels per mesh enter as the
 *                barycentric blend of per-vertex projections, the view channels as their
 *                weighted encoding (exact build) or a tabulated 1D function of each
 *                direction component, linearly interpolated (fast build). No screen buffer
 *                travels through global memory.
 *   ndrf_conv1   KSIZE x KSIZE conv HIDDEN -> 3 over hidden (x-PAD..x, y-PAD..y) (padding
 *                top/left), sigmoid, composited on the background by coverage.
 *   ndrf_screen  the screen buffer itself (tests only: the gather against the reference):
 *                for each mesh k the barycentric gather of features_k and of the hit
 *                position (zeros on a miss), the view encoding; zeros outside the image.
 * (PAD = KSIZE - 1.) Only what a covered pixel's colour depends on is computed: conv1 runs on
 * covered pixels, conv0 where a covered pixel reads its output. A pixel is covered where any
 * mesh's tri >= 0. Uncovered pixels show the background whatever the shader computes there.
 *
 * Hits: tri (K, H, W) int (-1: miss) and bary (K, H, W, 2) float Embree (u, v), from the
 * rasteriser (kernels/ndrf_raster.cl) or uploaded Embree hits.
 * The frame is shaded in bands of rows [y_band, y_end) (one band where the hidden layer
 * fits the device's largest buffer: clrender/ndrf/shader_cl.py). hidden holds a band's
 * hidden rows y_band - PAD .. y_end - 1 (rows + PAD buffer rows, width + PAD columns,
 * H_STRIDE): pixel (x, y) at (y - y_band + PAD, x + PAD). Its first PAD columns are zeroed
 * once per size (ndrf_zero_padding) and never written, its first PAD rows zeroed for the
 * first band (y < 0: the image's padding) and written by conv0 for the others; of the rest
 * conv1 reads only what conv0 wrote for the same band.
 *
 * -D defines (clrender/ndrf/shader_cl.py:kernel_defines): from NDRFConfig K, FEATURES,
 * C_IN, HIDDEN, N_FREQ, KSIZE; for the device H_VEC (8 or 16: floats per hidden-channel
 * vector), H_STRIDE (HIDDEN rounded up to whole vectors), SEG x ROWS (the block of
 * outputs of a conv0 work-item); VIEW_NODES (the fast build's table nodes); FAST_MATH
 * (the view table, native exp). Weights (clrender/ndrf/shader_cl.py:packed_weights),
 * zero-padded to H_STRIDE:
 *   proj (sum V_k, KSIZE*KSIZE, H_STRIDE) per-vertex projections, b0 (H_STRIDE),
 *   w_view (KSIZE*KSIZE, VIEW_C, H_STRIDE) [tap, in, out] (exact build) or the table
 *   (3, VIEW_NODES, KSIZE*KSIZE, 2, H_STRIDE) [component, node, tap, value | step to the
 *   next node, out] (fast build),
 *   w1 (KSIZE*KSIZE, 3, H_STRIDE) [tap, out, in], b1 (3).
 * Speed: conv0 vectorises across output channels; a work-item prepares the
 * (SEG + PAD) x (ROWS + PAD) input pixels of its block once (hits, ray direction).
 * Plain a * b + c: mad()/fma() are several times slower on PoCL (docs/explanation/opencl.md,
 * "PoCL facts the kernels rely on"); the fast build turns contraction on, so they become
 * fused multiply-adds (PoCL does not contract under FP_CONTRACT OFF, even with
 * -cl-mad-enable).
 */
#include "camera.h"
#if FAST_MATH
#pragma OPENCL FP_CONTRACT ON
#else
#pragma OPENCL FP_CONTRACT OFF
#endif

#if !defined(K) || !defined(FEATURES) || !defined(C_IN) || !defined(HIDDEN) || \
    !defined(N_FREQ) || !defined(KSIZE) || !defined(H_VEC) || !defined(H_STRIDE) || \
    !defined(SEG) || !defined(ROWS) || !defined(VIEW_NODES) || !defined(FAST_MATH)
#error "ndrf_shade.cl needs -D K FEATURES C_IN HIDDEN N_FREQ KSIZE H_VEC H_STRIDE SEG ROWS VIEW_NODES FAST_MATH"
#endif
#if FEATURES != 8
#error "the gather reads the per-vertex features as float8"
#endif
#if C_IN != (FEATURES + 3) * K + 3 + 6 * N_FREQ
#error "C_IN must be 8K features + 3K positions + 3 + 6 N_FREQ view channels"
#endif
#if SEG + KSIZE - 1 > 16
#error "a conv0 work-item's row of input pixels must fit one 16-lane vector"
#endif
#if H_STRIDE < HIDDEN || H_STRIDE % H_VEC != 0
#error "H_STRIDE must be a multiple of H_VEC no smaller than HIDDEN"
#endif

#if H_VEC == 8
typedef float8 hvec;
#define vload_h vload8
#define vstore_h vstore8
#elif H_VEC == 16
typedef float16 hvec;
#define vload_h vload16
#define vstore_h vstore16
#else
#error "H_VEC must be 8 or 16"
#endif

#if FAST_MATH
#define EXP native_exp
#else
#define EXP exp
#endif

#define PAD (KSIZE - 1)
#define TAPS (KSIZE * KSIZE)
#define VIEW_C (3 + 6 * N_FREQ)
#define VIEW_OFF ((FEATURES + 3) * K)

/* The fast build's view table lookups of a conv0 row: its SEG + PAD input pixels, one a lane
 * of a ROW_LANES-wide vector (the narrowest OpenCL width that holds them: 2 at SEG = 1). */
#if SEG + PAD == 1
#define ROW_LANES 1
typedef float row_float;
typedef int row_int;
#define ROW_LANE_IDS 0
#define CONVERT_ROW_FLOAT(x) convert_float(x)
#define CONVERT_ROW_INT(x) convert_int(x)
#define ROW_STORE(v, p) (*(p) = (v))
#elif SEG + PAD == 2
#define ROW_LANES 2
typedef float2 row_float;
typedef int2 row_int;
#define ROW_LANE_IDS ((int2)(0, 1))
#define CONVERT_ROW_FLOAT(x) convert_float2(x)
#define CONVERT_ROW_INT(x) convert_int2(x)
#define ROW_STORE(v, p) vstore2(v, 0, p)
#elif SEG + PAD <= 4
#define ROW_LANES 4
typedef float4 row_float;
typedef int4 row_int;
#define ROW_LANE_IDS ((int4)(0, 1, 2, 3))
#define CONVERT_ROW_FLOAT(x) convert_float4(x)
#define CONVERT_ROW_INT(x) convert_int4(x)
#define ROW_STORE(v, p) vstore4(v, 0, p)
#elif SEG + PAD <= 8
#define ROW_LANES 8
typedef float8 row_float;
typedef int8 row_int;
#define ROW_LANE_IDS ((int8)(0, 1, 2, 3, 4, 5, 6, 7))
#define CONVERT_ROW_FLOAT(x) convert_float8(x)
#define CONVERT_ROW_INT(x) convert_int8(x)
#define ROW_STORE(v, p) vstore8(v, 0, p)
#else
#define ROW_LANES 16
typedef float16 row_float;
typedef int16 row_int;
#define ROW_LANE_IDS ((int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define CONVERT_ROW_FLOAT(x) convert_float16(x)
#define CONVERT_ROW_INT(x) convert_int16(x)
#define ROW_STORE(v, p) vstore16(v, 0, p)
#endif

/* The hits of one frame and the meshes they index. */
typedef struct {
    __global const float *cam;
    int width, height;
    __global const int *tri;           /* (K, H, W) */
    __global const float *bary;        /* (K, H, W, 2) */
    __global const int *face_start;    /* (K + 1) */
    __global const int *faces;         /* (sum F_k, 3), into the concatenated vertices */
    __global const float *vertices;    /* (sum V_k, 3) */
    __global const float *features;    /* (sum V_k, FEATURES) */
} Frame;

/* The hidden band's first PAD columns = 0, and its first PAD rows where top_rows.
 * (clEnqueueFillBuffer would do, but Oclgrind 21.10's --uninitialized plugin does not count
 * it as a write.) */
__kernel void ndrf_zero_padding(const int width, const int rows, const int top_rows,
                                __global float *hidden)
{
    const int x = (int)get_global_id(0), y = (int)get_global_id(1);
    if (x >= width + PAD || y >= rows + PAD || (x >= PAD && (y >= PAD || !top_rows))) return;
    __global float *h = hidden + ((size_t)y * (width + PAD) + x) * H_STRIDE;
    for (int c = 0; c < H_STRIDE; ++c) h[c] = 0.0f;
}

/* Whether pixel p is covered: a hit on some mesh (hits.Hits.coverage). */
inline int coverage(const Frame *f, int p)
{
    const int n = f->width * f->height;
    for (int k = 0; k < K; ++k)
        if (f->tri[k * n + p] >= 0) return 1;
    return 0;
}

/* d, then sin(2^i d), cos(2^i d) for i < N_FREQ (shader_ref.view_encoding; 2^i d: exact
 * scaling, as in the reference), five frequencies at a time: one float16 call vectorises where a scalar call
 * per channel does not (docs/explanation/opencl.md, "PoCL facts the kernels rely on"). sincos() shares the range reduction; under
 * -D OCLGRIND separate sin() and cos(): sincos() breaks the --uninitialized plugin of
 * Oclgrind 21.10 (its output pointer). */
inline void view_encoding(float3 d, float *v)
{
    vstore3(d, 0, v);
    float scale = 1.0f;
    for (int i0 = 0; i0 < N_FREQ; i0 += 5) {
        float a[16], sa[16], ca[16];
        for (int i = 0; i < 5; ++i) {
            vstore3(i0 + i < N_FREQ ? scale * d : (float3)(0.0f), i, a);
            scale = scale * 2.0f;
        }
        a[15] = 0.0f;
        const float16 a16 = vload16(0, a);
#ifndef OCLGRIND
        float16 c16;
        vstore16(sincos(a16, &c16), 0, sa);
        vstore16(c16, 0, ca);
#else
        vstore16(sin(a16), 0, sa);
        vstore16(cos(a16), 0, ca);
#endif
        for (int i = 0; i < 5 && i0 + i < N_FREQ; ++i) {
            vstore3(vload3(i, sa), 0, v + 3 + 6 * (i0 + i));
            vstore3(vload3(i, ca), 0, v + 6 + 6 * (i0 + i));
        }
    }
}

/* The C_IN screen channels of pixel (px, py) into out (shader_ref.screen_buffer, one
 * pixel); all zeros outside the image. */
inline void screen_pixel(const Frame *f, int px, int py, float *out)
{
    if (px >= f->width || py >= f->height) {
        for (int c = 0; c < C_IN; ++c) out[c] = 0.0f;
        return;
    }
    const int n = f->width * f->height, p = py * f->width + px;
    for (int k = 0; k < K; ++k) {
        const int t = f->tri[k * n + p];
        /* x as three floats: a float3 assigned in the branch crashes the --uninitialized
         * plugin of Oclgrind 21.10 (tests/test_oclgrind.py). */
        float8 feat = (float8)(0.0f);
        float x[3] = {0.0f, 0.0f, 0.0f};
        /* Hits index faces of mesh k (the host checks uploaded ones); the bound here only
         * keeps reads inside the buffers. */
        if (t >= 0 && t < f->face_start[k + 1] - f->face_start[k]) {
            const int3 i = vload3(f->face_start[k] + t, f->faces);
            const float2 uv = vload2(k * n + p, f->bary);
            const float w = 1.0f - uv.x - uv.y;
            feat = w * vload8(i.x, f->features) + uv.x * vload8(i.y, f->features)
                   + uv.y * vload8(i.z, f->features);
            for (int e = 0; e < 3; ++e)
                x[e] = w * f->vertices[3 * i.x + e] + uv.x * f->vertices[3 * i.y + e]
                       + uv.y * f->vertices[3 * i.z + e];
        }
        vstore8(feat, 0, out + FEATURES * k);
        for (int e = 0; e < 3; ++e) out[FEATURES * K + 3 * k + e] = x[e];
    }
    view_encoding(camera_ray_dir(f->cam, px, py), out + VIEW_OFF);
}

#define FRAME_ARGS __global const float *cam, const int width, const int height, \
    __global const int *tri, __global const float *bary, __global const int *face_start, \
    __global const int *faces, __global const float *vertices, __global const float *features
#define FRAME_INIT {cam, width, height, tri, bary, face_start, faces, vertices, features}

__kernel void ndrf_screen(FRAME_ARGS, __global float *screen)
{
    const int px = (int)get_global_id(0), py = (int)get_global_id(1);
    if (px >= width || py >= height) return;
    const Frame f = FRAME_INIT;
    float out[C_IN];
    screen_pixel(&f, px, py, out);
    for (int c = 0; c < C_IN; ++c) screen[(size_t)(py * width + px) * C_IN + c] = out[c];
}

/* Whether any pixel of columns x0..x0+nx-1, rows y0..y0+ny-1 (clipped to the image) is
 * covered. */
inline int any_covered(const Frame *f, int x0, int y0, int nx, int ny)
{
    const int x1 = min(x0 + nx, f->width), y1 = min(y0 + ny, f->height);
    for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x)
            if (coverage(f, y * f->width + x)) return 1;
    return 0;
}

inline hvec relu(hvec x)
{
    return x > 0.0f ? x : (hvec)(0.0f);
}

/* What conv0 needs of screen pixel (px, py), for the KSIZE x KSIZE taps it feeds:
 * vi[3k + e] the vertices (concatenated numbering) of its hit on mesh k, -1 on a miss or
 * outside the image, vw[3k + e] their barycentric weights (1-u-v, u, v); exact build: the
 * view encoding's VIEW_C channels, untouched outside the image (*inside = 0). (The fast
 * build's view table lookups come a row at a time: view_nodes.) */
inline void conv0_pixel(const Frame *f, int px, int py, int *inside, int *vi, float *vw,
                        float *view)
{
    *inside = px < f->width && py < f->height;
    for (int e = 0; e < 3 * K; ++e) {
        vi[e] = -1;
        vw[e] = 0.0f;
    }
    if (!*inside) return;
    const int n = f->width * f->height, p = py * f->width + px;
    for (int k = 0; k < K; ++k) {
        const int t = f->tri[k * n + p];
        /* Hits index faces of mesh k (the host checks uploaded ones); the bound here only
         * keeps reads inside the buffers. */
        if (t >= 0 && t < f->face_start[k + 1] - f->face_start[k]) {
            const int3 i = vload3(f->face_start[k] + t, f->faces);
            const float2 uv = vload2(k * n + p, f->bary);
            vi[3 * k] = i.x;
            vi[3 * k + 1] = i.y;
            vi[3 * k + 2] = i.z;
            vw[3 * k] = 1.0f - uv.x - uv.y;
            vw[3 * k + 1] = uv.x;
            vw[3 * k + 2] = uv.y;
        }
    }
#if !FAST_MATH
    float dc[3];
    camera_ray_dir_into(f->cam, px, py, dc);
    view_encoding(vload3(0, dc), view);
#endif
}

/* The fast build's view table lookups of the ROW_LANES pixels x0 .. x0 + ROW_LANES - 1 of
 * row py, one a lane: node[c] and frac[c] for direction component c. The ray direction of
 * kernels/camera.h with one division where it has five (inv_f: the reciprocal focal
 * lengths, once a work-item): a few ulp off. */
inline void view_nodes(__global const float *cam, const float *inv_f, int x0, int py,
                       row_int *node, row_float *frac)
{
    const row_int px = x0 + ROW_LANE_IDS;
    const row_float a = (CONVERT_ROW_FLOAT(px) + 0.5f - cam[CAM_CX]) * inv_f[0];
    const float b = -(((float)py + 0.5f - cam[CAM_CY]) * inv_f[1]);
    row_float dc[3];
    for (int c = 0; c < 3; ++c)
        dc[c] = cam[CAM_R + 3 * c] * a + cam[CAM_R + 1 + 3 * c] * b - cam[CAM_R + 2 + 3 * c];
    const row_float inv_norm = 1.0f / sqrt(dc[0] * dc[0] + dc[1] * dc[1] + dc[2] * dc[2]);
    for (int c = 0; c < 3; ++c) {
        const row_float u = (dc[c] * inv_norm + 1.0f) * (0.5f * (float)(VIEW_NODES - 1));
        /* Clamped as a float (the same node): Oclgrind 21.10's clamp() of an int16 is
         * wrong. */
        node[c] = CONVERT_ROW_INT(fmin(fmax(u, 0.0f), (float)(VIEW_NODES - 2)));
        frac[c] = u - CONVERT_ROW_FLOAT(node[c]);
    }
}

#define NB (H_STRIDE / H_VEC)

/* acc += tap t of one screen pixel (all H_STRIDE outputs, NB vectors): its geometry
 * through the per-vertex projections plus its view encoding's (weights, or table lerp). */
inline void tap(hvec *acc, int t, const int *vi, const float *vw, const float *view,
                const int *node, const float *frac, __global const float *proj,
                __global const float *w_view)
{
    for (int e = 0; e < 3 * K; ++e) {
        if (vi[e] < 0) continue;
        __global const float *a = proj + ((size_t)vi[e] * TAPS + t) * H_STRIDE;
        const float b = vw[e];
        #pragma unroll
        for (int j = 0; j < NB; ++j) acc[j] = acc[j] + b * vload_h(j, a);
    }
#if FAST_MATH
    for (int c = 0; c < 3; ++c) {
        __global const float *a =
            w_view + (((c * VIEW_NODES + node[c]) * TAPS + t) * 2) * H_STRIDE;
        const float b = frac[c];
        #pragma unroll
        for (int j = 0; j < NB; ++j)
            acc[j] = acc[j] + (vload_h(j, a) + b * vload_h(j, a + H_STRIDE));
    }
#else
    __global const float *w = w_view + t * VIEW_C * H_STRIDE;
    for (int c = 0; c < VIEW_C; ++c)
        #pragma unroll
        for (int j = 0; j < NB; ++j) acc[j] = acc[j] + view[c] * vload_h(j, w + c * H_STRIDE);
#endif
}

/* conv0 factored by linearity: a pixel's geometry channels are barycentric blends of its
 * triangle's per-vertex values, so tap t's weights applied to them equal the same blend of
 * proj[v][t] = W_t (features[v], vertices[v]) (clrender/ndrf/shader_cl.py:
 * vertex_projections), 3 x HIDDEN MACs a mesh instead of 11 x HIDDEN. The view channels:
 * exact build, the encoding times its weights; fast build, a sum over the three direction
 * components of a tabulated 1D function each, linearly interpolated (view_weights). */
__kernel void ndrf_conv0(FRAME_ARGS, __global const float *proj, __global const float *w_view,
                         __global const float *b0, const int y_band, const int y_end,
                         __global float *hidden)
{
    /* The band's hidden rows max(y_band - PAD, 0) .. y_end - 1. */
    const int x0 = (int)get_global_id(0) * SEG;
    const int y0 = max(y_band - PAD, 0) + (int)get_global_id(1) * ROWS;
    if (x0 >= width || y0 >= y_end) return;
    const Frame f = FRAME_INIT;
    const int nx = min(SEG, width - x0) + PAD, ny = min(ROWS, y_end - y0) + PAD;
    /* hidden (x, y) is read by the covered pixels among (x..x+PAD, y..y+PAD): conv0's own
     * input pixels. */
    if (!any_covered(&f, x0, y0, nx, ny)) return;
    int inside[ROWS + PAD][SEG + PAD], vi[ROWS + PAD][SEG + PAD][3 * K];
    int node[ROWS + PAD][SEG + PAD][3];
    float vw[ROWS + PAD][SEG + PAD][3 * K], frac[ROWS + PAD][SEG + PAD][3];
    float view[ROWS + PAD][SEG + PAD][VIEW_C];
#if FAST_MATH
    const float inv_f[2] = {1.0f / cam[CAM_FX], 1.0f / cam[CAM_FY]};
#endif
    for (int r = 0; r < ny; ++r) {
        for (int i = 0; i < nx; ++i)
            conv0_pixel(&f, x0 + i, y0 + r, &inside[r][i], vi[r][i], vw[r][i], view[r][i]);
#if FAST_MATH
        row_int row_node[3];
        row_float row_frac[3];
        int nodes[3][ROW_LANES];
        float fracs[3][ROW_LANES];
        view_nodes(cam, inv_f, x0, y0 + r, row_node, row_frac);
        for (int c = 0; c < 3; ++c) {
            ROW_STORE(row_node[c], nodes[c]);
            ROW_STORE(row_frac[c], fracs[c]);
        }
        for (int i = 0; i < nx; ++i)
            for (int c = 0; c < 3; ++c) {
                node[r][i][c] = nodes[c][i];
                frac[r][i][c] = fracs[c][i];
            }
#endif
    }
    for (int r = 0; r < ny - PAD; ++r) {
        for (int q = 0; q < nx - PAD; ++q) {
            int needed = 0;
            for (int dy = 0; dy < KSIZE; ++dy)
                for (int dx = 0; dx < KSIZE; ++dx)
                    for (int k = 0; k < K; ++k) needed |= vi[r + dy][q + dx][3 * k] >= 0;
            if (!needed) continue;
            hvec acc[NB];
            #pragma unroll
            for (int j = 0; j < NB; ++j) acc[j] = vload_h(j, b0);
            for (int dy = 0; dy < KSIZE; ++dy)
                for (int dx = 0; dx < KSIZE; ++dx)
                    if (inside[r + dy][q + dx])
                        tap(acc, dy * KSIZE + dx, vi[r + dy][q + dx], vw[r + dy][q + dx],
                            view[r + dy][q + dx], node[r + dy][q + dx],
                            frac[r + dy][q + dx], proj, w_view);
            __global float *h = hidden + ((size_t)(y0 + r - y_band + PAD) * (width + PAD)
                                          + x0 + q + PAD) * H_STRIDE;
            #pragma unroll
            for (int j = 0; j < NB; ++j) vstore_h(relu(acc[j]), j, h);
        }
    }
}

/* The sum of a's lanes by halving (a scalar loop costs PoCL more than the conv itself):
 * .lo/.hi shuffles in registers; under -D OCLGRIND the same sums through private memory,
 * as the shuffles crash the --uninitialized plugin of Oclgrind 21.10. */
inline float sum_lanes(hvec a)
{
#ifndef OCLGRIND
#if H_VEC == 16
    const float8 a8 = a.lo + a.hi;
#else
    const float8 a8 = a;
#endif
    const float4 a4 = a8.lo + a8.hi;
    const float2 a2 = a4.lo + a4.hi;
    return a2.x + a2.y;
#else
    float t[H_VEC];
    vstore_h(a, 0, t);
#if H_VEC == 16
    vstore8(vload8(0, t) + vload8(1, t), 0, t);
#endif
    vstore4(vload4(0, t) + vload4(1, t), 0, t);
    vstore2(vload2(0, t) + vload2(1, t), 0, t);
    return t[0] + t[1];
#endif
}

/* shader_ref.sigmoid of the three colour channels at once (lane 3 unused): one vector exp
 * instead of three. */
inline float4 sigmoid(float4 x)
{
    return 1.0f / (1.0f + EXP(-x));
}

/* Rows y_band .. y_end - 1 of the image. */
__kernel void ndrf_conv1(FRAME_ARGS, __global const float *hidden, __global const float *w1,
                         __global const float *b1, const float bg_r, const float bg_g,
                         const float bg_b, const int y_band, const int y_end,
                         __global float *rgb)
{
    const int px = (int)get_global_id(0), py = y_band + (int)get_global_id(1);
    if (px >= width || py >= y_end) return;
    const Frame f = FRAME_INIT;
    const int p = py * width + px;
    if (!coverage(&f, p)) {
        rgb[3 * p] = bg_r;
        rgb[3 * p + 1] = bg_g;
        rgb[3 * p + 2] = bg_b;
        return;
    }
    hvec a0 = (hvec)(0.0f), a1 = (hvec)(0.0f), a2 = (hvec)(0.0f);
    for (int dy = 0; dy < KSIZE; ++dy) {
        for (int dx = 0; dx < KSIZE; ++dx) {
            __global const float *h =
                hidden + ((size_t)(py - y_band + dy) * (width + PAD) + px + dx) * H_STRIDE;
            __global const float *w = w1 + (dy * KSIZE + dx) * 3 * H_STRIDE;
            for (int j = 0; j < H_STRIDE / H_VEC; ++j) {
                const hvec hv = vload_h(j, h);
                a0 = a0 + hv * vload_h(j, w);
                a1 = a1 + hv * vload_h(j, w + H_STRIDE);
                a2 = a2 + hv * vload_h(j, w + 2 * H_STRIDE);
            }
        }
    }
    const float4 c = sigmoid((float4)(b1[0] + sum_lanes(a0), b1[1] + sum_lanes(a1),
                                      b1[2] + sum_lanes(a2), 0.0f));
    vstore3(c.xyz, p, rgb);
}
