/* NGP-RT deferred shading (docs/ngprt.md "Per pixel", Eq. 5): per pixel the MLP_psi
 *   x = [diffuse (3), specular (4), sh4(d) (16)]                         (23)
 *   h1 = relu(x @ w0 + b0), h2 = relu(h1 @ w1 + b1)                      (64, 64)
 *   rgb = sigmoid(diffuse + h2 @ w2 + b2) * opacity + background * (1 - opacity)
 * Mirrors clrender/ngprt/render_ref.py:deferred_reference.
 *
 * Each work-item shades DEFERRED_VEC consecutive pixels held in the lanes of a vector
 * (-D DEFERRED_VEC = 1, 2, 4, 8 or 16), so the 5.8 k multiply-adds per pixel run as
 * SIMD on CPU devices without relying on the driver to vectorise across work-items;
 * the weights are read once per work-item and broadcast. Plain a * b + c: mad()/fma()
 * are several times slower on PoCL (docs/explanation/opencl.md, "PoCL facts the kernels rely on").
 * The fast build turns contraction on (no geometry is computed here), so they become
 * fused multiply-adds: PoCL does not contract under FP_CONTRACT OFF even with
 * -cl-mad-enable, and runs this MLP slower without them (docs/explanation/opencl.md, "Each kernel
 * in its own lanes on both"). A work-item whose pixels all have
 * opacity 0 (background) writes the background and skips the MLP: rgb * 0 + bg * 1 is bg
 * exactly.
 *
 * Sizes from config.kernel_constants: FEATURES (8: 7 composited + opacity), SH_DIM (16),
 * DEFERRED_HIDDEN (64).
 * params: [w0 (23, 64), b0 (64), w1 (64, 64), b1 (64), w2 (64, 3), b2 (3)] float32, in
 * __constant memory with -D DEFERRED_CONSTANT=1 (the host sets it where the device's
 * constant buffer holds them: every work-item reads the same weight at once, which a GPU's
 * constant cache broadcasts), else __global; with -D DEFERRED_LOCAL=1 (a GPU variant,
 * render_cl.Tuning) the work-group first copies them from there into the __local
 * argument `staged` and reads them from it.
 * -D DEFERRED_STREAMED=1 (a GPU variant): each output of the second hidden layer goes
 * straight into the output layer's sums, in the same order, so the 64 of h2 are never
 * held at once (fewer live registers a work-item; the same values).
 */
#include "camera.h"
#include "ngprt_math.h"
#if FAST_MATH
#pragma OPENCL FP_CONTRACT ON
#else
#pragma OPENCL FP_CONTRACT OFF
#endif

#if !defined(FEATURES) || !defined(SH_DIM) || !defined(DEFERRED_HIDDEN) || \
    !defined(DEFERRED_VEC) || !defined(DEFERRED_CONSTANT) || !defined(DEFERRED_LOCAL) || \
    !defined(DEFERRED_STREAMED) || !defined(FAST_MATH)
#error "ngprt_deferred.cl needs -D FEATURES SH_DIM DEFERRED_HIDDEN DEFERRED_VEC \
    DEFERRED_CONSTANT DEFERRED_LOCAL DEFERRED_STREAMED FAST_MATH"
#endif
/* PARAMS: where the weights arrive; WEIGHT: where the MLP reads them. */
#if DEFERRED_CONSTANT
#define PARAMS __constant const float
#else
#define PARAMS __global const float
#endif
#if DEFERRED_LOCAL
#define WEIGHT __local const float
#else
#define WEIGHT PARAMS
#endif
/* The code's shape fixes these: the march writes 7 features + opacity per pixel, sh4
 * spells out degree 4, the hidden layers run four outputs per pass. */
#if FEATURES != 8
#error "FEATURES must be 8: the march writes 7 composited features and the opacity"
#endif
#if SH_DIM != 16
#error "SH_DIM must be 16: sh4 spells out degree 4"
#endif
#if DEFERRED_HIDDEN % 4 != 0
#error "DEFERRED_HIDDEN must be a multiple of 4"
#endif

#define N_FEAT (FEATURES - 1)              /* diffuse rgb (3) + specular (4) */
#define IN (N_FEAT + SH_DIM)
#define HID DEFERRED_HIDDEN
#define P_W0 0
#define P_B0 (P_W0 + IN * HID)
#define P_W1 (P_B0 + HID)
#define P_B1 (P_W1 + HID * HID)
#define P_W2 (P_B1 + HID)
#define P_B2 (P_W2 + HID * 3)
#define N_PARAMS (P_B2 + 3)

#if DEFERRED_VEC == 1
typedef float vfloat;
#elif DEFERRED_VEC == 2
typedef float2 vfloat;
#elif DEFERRED_VEC == 4
typedef float4 vfloat;
#elif DEFERRED_VEC == 8
typedef float8 vfloat;
#elif DEFERRED_VEC == 16
typedef float16 vfloat;
#else
#error "DEFERRED_VEC must be 1, 2, 4, 8 or 16"
#endif

#define LANE(v, lane) (((float *)&(v))[lane])

/* Degree-4 real SH of a unit direction (encoding.sh4, its constants SH_C0 .. SH_C10 and
 * order). */
inline void sh4(float3 d, float *out)
{
    const float x = d.x, y = d.y, z = d.z;
    const float xy = x * y, xz = x * z, yz = y * z;
    const float x2 = x * x, y2 = y * y, z2 = z * z;
    out[0] = SH_C0;
    out[1] = -SH_C1 * y;
    out[2] = SH_C1 * z;
    out[3] = -SH_C1 * x;
    out[4] = SH_C2 * xy;
    out[5] = -SH_C2 * yz;
    out[6] = SH_C3 * z2 - SH_C4;
    out[7] = -SH_C2 * xz;
    out[8] = SH_C5 * x2 - SH_C5 * y2;
    out[9] = SH_C6 * y * (-3.0f * x2 + y2);
    out[10] = SH_C7 * xy * z;
    out[11] = SH_C8 * y * (1.0f - 5.0f * z2);
    out[12] = SH_C9 * z * (5.0f * z2 - 3.0f);
    out[13] = SH_C8 * x * (1.0f - 5.0f * z2);
    out[14] = SH_C10 * z * (x2 - y2);
    out[15] = SH_C6 * x * (-x2 + 3.0f * y2);
}

/* max(x, 0) per lane; a select rather than fmax, which PoCL calls out of line. */
inline vfloat relu(vfloat x)
{
    return x > 0.0f ? x : (vfloat)(0.0f);
}

/* out[j] = relu(sum_i in[i] * w[i, j] + b[j]) for j < HID; four outputs per pass so
 * each input vector is loaded once for four broadcast weights. */
inline void dense_relu(const vfloat *in, int n_in, WEIGHT *w, WEIGHT *b, vfloat *out)
{
    for (int j = 0; j < HID; j += 4) {
        vfloat a0 = 0.0f, a1 = 0.0f, a2 = 0.0f, a3 = 0.0f;
        for (int i = 0; i < n_in; ++i) {
            const vfloat x = in[i];
            WEIGHT *wi = w + i * HID + j;
            a0 = a0 + x * wi[0];
            a1 = a1 + x * wi[1];
            a2 = a2 + x * wi[2];
            a3 = a3 + x * wi[3];
        }
        out[j] = relu(a0 + b[j]);
        out[j + 1] = relu(a1 + b[j + 1]);
        out[j + 2] = relu(a2 + b[j + 2]);
        out[j + 3] = relu(a3 + b[j + 3]);
    }
}

#if DEFERRED_STREAMED
/* The second hidden layer (dense_relu of h1) fed straight into the output layer:
 * o[c] += relu(h1 @ w1 + b1)[j] * w2[3 j + c] for j = 0 .. HID-1 in order, as the
 * output loop of ngprt_deferred adds them. */
inline void dense_relu_output(const vfloat *in, WEIGHT *w, WEIGHT *b, WEIGHT *w2,
                              vfloat *o0, vfloat *o1, vfloat *o2)
{
    for (int j = 0; j < HID; j += 4) {
        vfloat a[4] = {(vfloat)(0.0f), (vfloat)(0.0f), (vfloat)(0.0f), (vfloat)(0.0f)};
        for (int i = 0; i < HID; ++i) {
            const vfloat x = in[i];
            WEIGHT *wi = w + i * HID + j;
            a[0] = a[0] + x * wi[0];
            a[1] = a[1] + x * wi[1];
            a[2] = a[2] + x * wi[2];
            a[3] = a[3] + x * wi[3];
        }
        for (int q = 0; q < 4; ++q) {
            const vfloat h = relu(a[q] + b[j + q]);
            *o0 = *o0 + h * w2[3 * (j + q)];
            *o1 = *o1 + h * w2[3 * (j + q) + 1];
            *o2 = *o2 + h * w2[3 * (j + q) + 2];
        }
    }
}
#endif

/* Gathers the inputs x (IN lane-vectors) and the opacity of pixels p0 .. p0+VEC-1;
 * lanes past the image get zeros. */
inline void load_inputs(__global const float *cam, int width, int n_pix, int p0,
                        __global const float *feat, vfloat *x, vfloat *opacity)
{
    for (int lane = 0; lane < DEFERRED_VEC; ++lane) {
        const int p = p0 + lane;
        float8 f = (float8)(0.0f);
        float sh[SH_DIM];
        for (int i = 0; i < SH_DIM; ++i) sh[i] = 0.0f;
        if (p < n_pix) {
            f = vload8(p, feat);
            /* p - py * width, not p % width: LLVM turns a div/rem pair into a freeze
             * instruction, which Oclgrind 21.10's uninitialised-value check aborts on. */
            const int py = p / width;
            sh4(camera_ray_dir(cam, p - py * width, py), sh);
        }
        const float *fv = (const float *)&f;
        for (int i = 0; i < N_FEAT; ++i) LANE(x[i], lane) = fv[i];
        for (int i = 0; i < SH_DIM; ++i) LANE(x[N_FEAT + i], lane) = sh[i];
        LANE(*opacity, lane) = f.s7;
    }
}

/* vec_type_hint: the lanes are explicit (DEFERRED_VEC pixels a work-item); Intel's CPU
 * compiler keeps them (ngprt_march.cl says why). */
__kernel __attribute__((vec_type_hint(vfloat)))
void ngprt_deferred(__global const float *cam, const int width, const int n_pix,
                    __global const float *feat, PARAMS *weights,
                    const float bg_r, const float bg_g, const float bg_b,
                    __global float *rgb
#if DEFERRED_LOCAL
                    , __local float *staged
#endif
                    )
{
#if DEFERRED_LOCAL
    /* Every work-item of the group takes part before any returns. */
    for (int i = get_local_id(0); i < N_PARAMS; i += get_local_size(0)) staged[i] = weights[i];
    barrier(CLK_LOCAL_MEM_FENCE);
    WEIGHT *params = staged;
#else
    WEIGHT *params = weights;
#endif
    const int p0 = (int)get_global_id(0) * DEFERRED_VEC;
    if (p0 >= n_pix) return;
    bool covered = false;
    for (int lane = 0; lane < DEFERRED_VEC && p0 + lane < n_pix; ++lane)
        covered = covered || feat[8 * (size_t)(p0 + lane) + 7] > 0.0f;
    if (!covered) {
        for (int lane = 0; lane < DEFERRED_VEC && p0 + lane < n_pix; ++lane) {
            const int p = p0 + lane;
            rgb[3 * p] = bg_r;
            rgb[3 * p + 1] = bg_g;
            rgb[3 * p + 2] = bg_b;
        }
        return;
    }
    vfloat x[IN], h1[HID], opacity;
    load_inputs(cam, width, n_pix, p0, feat, x, &opacity);
    dense_relu(x, IN, params + P_W0, params + P_B0, h1);
    WEIGHT *w2 = params + P_W2, *b2 = params + P_B2;
    vfloat o0 = 0.0f, o1 = 0.0f, o2 = 0.0f;
#if DEFERRED_STREAMED
    dense_relu_output(h1, params + P_W1, params + P_B1, w2, &o0, &o1, &o2);
#else
    vfloat h2[HID];
    dense_relu(h1, HID, params + P_W1, params + P_B1, h2);
    for (int i = 0; i < HID; ++i) {
        o0 = o0 + h2[i] * w2[3 * i];
        o1 = o1 + h2[i] * w2[3 * i + 1];
        o2 = o2 + h2[i] * w2[3 * i + 2];
    }
#endif
    const vfloat c0 = RECIP(1.0f + EXP(-(x[0] + o0 + b2[0])));
    const vfloat c1 = RECIP(1.0f + EXP(-(x[1] + o1 + b2[1])));
    const vfloat c2 = RECIP(1.0f + EXP(-(x[2] + o2 + b2[2])));
    const vfloat transparent = 1.0f - opacity;
    const vfloat r = c0 * opacity + bg_r * transparent;
    const vfloat g = c1 * opacity + bg_g * transparent;
    const vfloat b = c2 * opacity + bg_b * transparent;
    for (int lane = 0; lane < DEFERRED_VEC && p0 + lane < n_pix; ++lane) {
        const int p = p0 + lane;
        rgb[3 * p] = LANE(r, lane);
        rgb[3 * p + 1] = LANE(g, lane);
        rgb[3 * p + 2] = LANE(b, lane);
    }
}
