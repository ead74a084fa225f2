/* Scalar math of the NGP-RT kernels.
 *
 * exp and 1/x (EXP, RECIP): the library's (a few ulps, as numpy's) in the exact build, the device's
 * native ones in the fast build (-D FAST_MATH=1, device.FAST_OPTIONS).
 */
#ifndef CLRENDER_NGPRT_MATH_H
#define CLRENDER_NGPRT_MATH_H
#if !defined(FAST_MATH)
#error "ngprt kernels need -D FAST_MATH=0 or 1 (render_cl.kernel_defines)"
#endif
#if FAST_MATH
#define EXP(x) native_exp(x)
#define RECIP(x) native_recip(x)
#else
#define EXP(x) exp(x)
#define RECIP(x) (1.0f / (x))
#endif
#endif
