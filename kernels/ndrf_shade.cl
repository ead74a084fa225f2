/* NDRF shading (docs/ndrf.md), three pixel-parallel passes; mirrors
 * clrender/ndrf/shader_ref.py:
 *   ndrf_gather  per pixel: for each mesh k the barycentric gather of features_k and of the
 *                hit position (zeros on a miss), then the view encoding of the camera ray
 *                (camera.h) -> screen; the coverage byte -> covered.
 *   ndrf_conv0   KSIZE x KSIZE conv C_IN -> HIDDEN over screen (x..x+PAD, y..y+PAD) (padding
 *                bottom/right), ReLU -> hidden.
 *   ndrf_conv1   KSIZE x KSIZE conv HIDDEN -> 3 over hidden (x-PAD..x, y-PAD..y) (padding
 *                top/left), sigmoid, composited on the background by coverage.
 * (PAD = KSIZE - 1.) Only what a covered pixel's colour depends on is computed: conv1 runs on
 * covered pixels, conv0 where a covered pixel reads its output, and the gather computes the
 * view encoding only where a covered pixel lies within PAD pixels (elsewhere the screen pixel
 * is all zeros). Uncovered pixels show the background whatever the shader computes there.
 *
 * Buffers carry the convs' zero padding, so no conv read needs a bounds test; ndrf_zero
 * clears them once per image size and the three passes never write the padding:
 *   screen (height + PAD rows, screen_cols columns, C_IN): pixel (x, y) at row y, column x;
 *          screen_cols >= width + PIX - 1 + PAD covers a conv0 work-item's last reads.
 *   hidden (height + PAD rows, width + PAD columns, H_STRIDE): pixel (x, y) at (y + PAD, x + PAD).
 *   covered (height, width) uchar.
 *
 * -D defines (clrender/ndrf/shader_cl.py:kernel_defines): from NDRFConfig K, FEATURES,
 * C_IN, HIDDEN, N_FREQ, KSIZE; for the device H_VEC (8 or 16: floats per hidden-channel
 * vector), H_BLOCK (vectors per block of outputs kept in registers), H_STRIDE (HIDDEN
 * rounded up to whole blocks) and PIX (adjacent pixels per conv0 work-item). Weights,
 * zero-padded to H_STRIDE:
 *   w0 (KSIZE*KSIZE, C_IN, H_STRIDE) [tap, in, out], b0 (H_STRIDE),
 *   w1 (KSIZE*KSIZE, 3, H_STRIDE) [tap, out, in], b1 (3).
 * Speed: conv0 vectorises across output channels; each weight vector, read once per
 * work-item, serves PIX pixels. Plain a * b + c: mad()/fma() are several times slower on
 * PoCL (DESIGN.md, performance notes).
 */
#include "camera.h"
#pragma OPENCL FP_CONTRACT OFF

#if !defined(K) || !defined(FEATURES) || !defined(C_IN) || !defined(HIDDEN) || \
    !defined(N_FREQ) || !defined(KSIZE) || !defined(H_VEC) || !defined(H_BLOCK) || \
    !defined(H_STRIDE) || !defined(PIX)
#error "ndrf_shade.cl needs -D K FEATURES C_IN HIDDEN N_FREQ KSIZE H_VEC H_BLOCK H_STRIDE PIX"
#endif
#if FEATURES != 8
#error "the gather reads the per-vertex features as float8"
#endif
#if C_IN != (FEATURES + 3) * K + 3 + 6 * N_FREQ
#error "C_IN must be 8K features + 3K positions + 3 + 6 N_FREQ view channels"
#endif
#if H_STRIDE < HIDDEN || H_STRIDE % (H_VEC * H_BLOCK) != 0
#error "H_STRIDE must be a multiple of H_VEC * H_BLOCK no smaller than HIDDEN"
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

#define PAD (KSIZE - 1)
#define VIEW_OFF ((FEATURES + 3) * K)

/* buf[0..n) = 0. (clEnqueueFillBuffer would do, but Oclgrind 21.10's --uninitialized
 * plugin does not count it as a write.) */
__kernel void ndrf_zero(__global float *buf, const int n)
{
    const int i = (int)get_global_id(0);
    if (i < n) buf[i] = 0.0f;
}

/* Whether any pixel within PAD of (px, py) (clamped to the image) hits a mesh. */
inline int ndrf_near_coverage(__global const int *tri, int width, int height, int px, int py)
{
    const int n = width * height;
    for (int y = max(py - PAD, 0); y <= min(py + PAD, height - 1); ++y)
        for (int x = max(px - PAD, 0); x <= min(px + PAD, width - 1); ++x)
            for (int k = 0; k < K; ++k)
                if (tri[k * n + y * width + x] >= 0) return 1;
    return 0;
}

/* d, then sin(2^i d), cos(2^i d) for i < N_FREQ (2^i d: exact scaling, as in the
 * reference), five frequencies at a time: one float16 call vectorises where a scalar call
 * per channel does not (PoCL: ~30x faster). sincos() would save a little more but breaks
 * the --uninitialized plugin of Oclgrind 21.10 (its output pointer). */
inline void ndrf_view_encoding(float3 d, __global float *v)
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
        vstore16(sin(a16), 0, sa);
        vstore16(cos(a16), 0, ca);
        for (int i = 0; i < 5 && i0 + i < N_FREQ; ++i) {
            vstore3(vload3(i, sa), 0, v + 3 + 6 * (i0 + i));
            vstore3(vload3(i, ca), 0, v + 6 + 6 * (i0 + i));
        }
    }
}

__kernel void ndrf_gather(__global const float *cam, const int width, const int height,
                          __global const int *tri, __global const float *bary,
                          __global const int *face_start, __global const int *faces,
                          __global const float *vertices, __global const float *features,
                          const int screen_cols, __global float *screen,
                          __global uchar *covered)
{
    const int px = (int)get_global_id(0), py = (int)get_global_id(1);
    if (px >= width || py >= height) return;
    const int n = width * height, p = py * width + px;
    __global float *out = screen + ((size_t)py * screen_cols + px) * C_IN;
    uchar cov = 0;
    for (int k = 0; k < K; ++k) {
        const int t = tri[k * n + p];
        /* x as three floats: a float3 assigned in the branch crashes the --uninitialized
         * plugin of Oclgrind 21.10 (tests/test_oclgrind.py). */
        float8 f = (float8)(0.0f);
        float x[3] = {0.0f, 0.0f, 0.0f};
        /* The host checks t < F_k; the bound here only keeps reads inside the buffers. */
        if (t >= 0 && t < face_start[k + 1] - face_start[k]) {
            const int3 i = vload3(face_start[k] + t, faces);
            const float2 uv = vload2(k * n + p, bary);
            const float w = 1.0f - uv.x - uv.y;
            f = w * vload8(i.x, features) + uv.x * vload8(i.y, features)
                + uv.y * vload8(i.z, features);
            for (int e = 0; e < 3; ++e)
                x[e] = w * vertices[3 * i.x + e] + uv.x * vertices[3 * i.y + e]
                       + uv.y * vertices[3 * i.z + e];
            cov = 1;
        }
        vstore8(f, 0, out + FEATURES * k);
        for (int e = 0; e < 3; ++e) out[FEATURES * K + 3 * k + e] = x[e];
    }
    covered[p] = cov;
    if (cov || ndrf_near_coverage(tri, width, height, px, py)) {
        ndrf_view_encoding(camera_ray_dir(cam, px, py), out + VIEW_OFF);
    } else {
        for (int c = VIEW_OFF; c < C_IN; ++c) out[c] = 0.0f;
    }
}

/* Whether conv1 reads hidden at any of pixels (x0..x0+PIX-1, y0) for a covered pixel: the
 * readers of (x, y) are (x..x+PAD, y..y+PAD). */
inline int ndrf_hidden_needed(__global const uchar *covered, int width, int height, int x0,
                              int y0)
{
    const int x1 = min(x0 + PIX + PAD, width), y1 = min(y0 + KSIZE, height);
    for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x)
            if (covered[y * width + x]) return 1;
    return 0;
}

inline hvec ndrf_relu(hvec x)
{
    return x > 0.0f ? x : (hvec)(0.0f);
}

__kernel void ndrf_conv0(const int width, const int height, const int screen_cols,
                         __global const float *screen, __global const uchar *covered,
                         __global const float *w0, __global const float *b0,
                         __global float *hidden)
{
    const int x0 = (int)get_global_id(0) * PIX, py = (int)get_global_id(1);
    if (x0 >= width || py >= height) return;
    if (!ndrf_hidden_needed(covered, width, height, x0, py)) return;
    for (int j0 = 0; j0 < H_STRIDE / H_VEC; j0 += H_BLOCK) {
        hvec acc[PIX][H_BLOCK];
        for (int q = 0; q < PIX; ++q)
            for (int j = 0; j < H_BLOCK; ++j) acc[q][j] = vload_h(j0 + j, b0);
        for (int dy = 0; dy < KSIZE; ++dy) {
            for (int dx = 0; dx < KSIZE; ++dx) {
                __global const float *in =
                    screen + ((size_t)(py + dy) * screen_cols + x0 + dx) * C_IN;
                __global const float *w =
                    w0 + (dy * KSIZE + dx) * C_IN * H_STRIDE + H_VEC * j0;
                for (int c = 0; c < C_IN; ++c) {
                    for (int j = 0; j < H_BLOCK; ++j) {
                        const hvec wv = vload_h(j, w + c * H_STRIDE);
                        for (int q = 0; q < PIX; ++q)
                            acc[q][j] = acc[q][j] + in[q * C_IN + c] * wv;
                    }
                }
            }
        }
        for (int q = 0; q < PIX && x0 + q < width; ++q) {
            __global float *h =
                hidden + ((size_t)(py + PAD) * (width + PAD) + x0 + q + PAD) * H_STRIDE;
            for (int j = 0; j < H_BLOCK; ++j) vstore_h(ndrf_relu(acc[q][j]), j0 + j, h);
        }
    }
}

/* The sum of a's lanes, halving through private memory: .lo/.hi shuffles crash the
 * --uninitialized plugin of Oclgrind 21.10, and a scalar loop costs PoCL more than the
 * conv itself. */
inline float ndrf_sum(hvec a)
{
    float t[H_VEC];
    vstore_h(a, 0, t);
#if H_VEC == 16
    vstore8(vload8(0, t) + vload8(1, t), 0, t);
#endif
    vstore4(vload4(0, t) + vload4(1, t), 0, t);
    vstore2(vload2(0, t) + vload2(1, t), 0, t);
    return t[0] + t[1];
}

__kernel void ndrf_conv1(const int width, const int height, __global const float *hidden,
                         __global const uchar *covered, __global const float *w1,
                         __global const float *b1, const float bg_r, const float bg_g,
                         const float bg_b, __global float *rgb)
{
    const int px = (int)get_global_id(0), py = (int)get_global_id(1);
    if (px >= width || py >= height) return;
    const int p = py * width + px;
    if (!covered[p]) {
        rgb[3 * p] = bg_r;
        rgb[3 * p + 1] = bg_g;
        rgb[3 * p + 2] = bg_b;
        return;
    }
    hvec a0 = (hvec)(0.0f), a1 = (hvec)(0.0f), a2 = (hvec)(0.0f);
    for (int dy = 0; dy < KSIZE; ++dy) {
        for (int dx = 0; dx < KSIZE; ++dx) {
            __global const float *h =
                hidden + ((size_t)(py + dy) * (width + PAD) + px + dx) * H_STRIDE;
            __global const float *w = w1 + (dy * KSIZE + dx) * 3 * H_STRIDE;
            for (int j = 0; j < H_STRIDE / H_VEC; ++j) {
                const hvec hv = vload_h(j, h);
                a0 = a0 + hv * vload_h(j, w);
                a1 = a1 + hv * vload_h(j, w + H_STRIDE);
                a2 = a2 + hv * vload_h(j, w + 2 * H_STRIDE);
            }
        }
    }
    rgb[3 * p] = 1.0f / (1.0f + exp(-(b1[0] + ndrf_sum(a0))));
    rgb[3 * p + 1] = 1.0f / (1.0f + exp(-(b1[1] + ndrf_sum(a1))));
    rgb[3 * p + 2] = 1.0f / (1.0f + exp(-(b1[2] + ndrf_sum(a2))));
}
