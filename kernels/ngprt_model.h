/* The baked NGP-RT model as the march sees it: its -D sizes and the buffers it reads.
 *
 * Every constant comes as a -D define from clrender/ngprt/render_cl.py:kernel_defines,
 * so Python and OpenCL share one definition:
 *   shared constants (config.kernel_constants): T_STOP, N_MIP, FEATURES, FUSION_HIDDEN,
 *     LATTICE_BREAKS and the variant codes VARIANT_SUM .. VARIANT_SEPARATE_V
 *     (config.VARIANT_CODES); the hash primes HASH_PRIME_X/Y/Z (encoding.HASH_PRIMES);
 *   per model: L, L_C, OCC_RES (the finest occupancy level's cells a side, L_C << OCC_SHIFT:
 *     ModelConfig.occ_res, occ_shift), LOG2_T, COARSE_BLOCK, G_RES, N_ATT (attention channels in the
 *     coarse grid), N_INV (spatially invariant logits), VARIANT, UNBOUNDED, EXTENT
 *     (ModelConfig.extent), USE_G, G_IN_CODE (render_cl.g_in_codes), MARCH_PAPER (the
 *     paper's march, ngprt_paper.h, or ours), COUNT_READS (the counting build),
 *     HALF_TABLES (the fine tables in half precision);
 *   per device: RAYS (ngprt_lanes.h), FAST_MATH (ngprt_math.h); the skip's margins come
 *     with ngprt_skip.h.
 * A missing define fails the build: an undefined name is 0 in #if, which would
 * silently pick VARIANT_SUM's code or a zero T_STOP.
 */
#ifndef CLRENDER_NGPRT_MODEL_H
#define CLRENDER_NGPRT_MODEL_H

#if !defined(T_STOP) || !defined(N_MIP) || !defined(FEATURES) || !defined(FUSION_HIDDEN) || \
    !defined(LATTICE_BREAKS)
#error "ngprt kernels need -D T_STOP N_MIP FEATURES FUSION_HIDDEN LATTICE_BREAKS (config.kernel_constants)"
#endif
#if !defined(VARIANT_SUM) || !defined(VARIANT_MLP) || !defined(VARIANT_SHARED_INV) || \
    !defined(VARIANT_SEPARATE_INV) || !defined(VARIANT_SHARED_V) || !defined(VARIANT_SEPARATE_V)
#error "ngprt kernels need -D VARIANT_SUM .. VARIANT_SEPARATE_V (config.VARIANT_CODES)"
#endif
#if !defined(HASH_PRIME_X) || !defined(HASH_PRIME_Y) || !defined(HASH_PRIME_Z)
#error "ngprt kernels need -D HASH_PRIME_X HASH_PRIME_Y HASH_PRIME_Z (encoding.HASH_PRIMES)"
#endif
#if !defined(L) || !defined(L_C) || !defined(OCC_RES) || !defined(OCC_SHIFT) || \
    !defined(LOG2_T) || !defined(COARSE_BLOCK) || \
    !defined(G_RES) || !defined(N_ATT) || !defined(N_INV) || !defined(VARIANT) || \
    !defined(UNBOUNDED) || !defined(EXTENT) || !defined(USE_G) || !defined(G_IN_CODE)
#error "ngprt kernels need -D L L_C OCC_RES OCC_SHIFT LOG2_T COARSE_BLOCK G_RES N_ATT N_INV VARIANT UNBOUNDED EXTENT USE_G G_IN_CODE"
#endif
#if !defined(MARCH_PAPER) || !defined(COUNT_READS) || !defined(CODE_G_SHIFT) || \
    !defined(HALF_TABLES)
#error "ngprt kernels need -D MARCH_PAPER COUNT_READS CODE_G_SHIFT HALF_TABLES (render_cl.kernel_defines)"
#endif
/* An exit code (render_cl.exit_codes): 1 + its exit level (0: occupied) below
 * CODE_G_SHIFT, the G value read with it above. */
#define CODE_LEVEL(code) ((code) & ((1 << CODE_G_SHIFT) - 1))
#define CODE_G(code) ((code) >> CODE_G_SHIFT)
/* The occupancy the march reads: exit codes (ours) or the mip's bytes (the paper's). */
#if MARCH_PAPER
typedef uchar occ_t;
#else
typedef ushort occ_t;
#endif
/* The code's shape fixes these: features travel as float8 (the mlp fusion also runs its
 * hidden layer in float8 lanes); the lattice table holds the ray's start, 12 candidate
 * breakpoints and its end (ngprt_lattice.h). */
#if FEATURES != 8
#error "FEATURES must be 8: features are held in float8"
#endif
#if FUSION_HIDDEN % 8 != 0
#error "FUSION_HIDDEN must be a multiple of 8"
#endif
#if LATTICE_BREAKS != 14
#error "LATTICE_BREAKS must be 14: the start, 12 candidate breakpoints, the end"
#endif

/* The fine hash tables' entries: float8, or (HALF_TABLES, render_cl.Tuning.half_tables)
 * 8 halves read with vload_half8, half the bytes a corner. */
#if HALF_TABLES
typedef half table_t;
#define TABLE_ENTRY(tables, i) vload_half8((i), (tables))
#else
typedef float8 table_t;
#define TABLE_ENTRY(tables, i) ((tables)[i])
#endif

#define TABLE_MASK ((1u << LOG2_T) - 1u)
/* The primes as uint: a decimal literal above INT_MAX would be a long. */
#define HASH_X ((uint)(HASH_PRIME_X))
#define HASH_Y ((uint)(HASH_PRIME_Y))
#define HASH_Z ((uint)(HASH_PRIME_Z))
#define EXTENT_F ((float)(EXTENT))
#define SIDE_F (2.0f * EXTENT_F)         /* the grid's side: [-EXTENT, EXTENT]^3 */
/* A coarse corner holds 8 + N_ATT channels; the renderer pads each corner to a
 * multiple of 8 floats (COARSE_STRIDE) so every read is an aligned float8. */
#define ATT_VEC ((N_ATT + 7) / 8)                 /* float8 chunks of attention logits */
#define INV_VEC ((N_INV + 7) / 8)                 /* float8 chunks of invariant logits */
/* float8 chunks of attention weights (sigmoids) a sample's fusion reads: from the coarse
 * grid (-v variants) or from the invariant logits (-inv), at least one. */
#define SIG_LEN (ATT_VEC > INV_VEC ? ATT_VEC : (INV_VEC > 0 ? INV_VEC : 1))
#define COARSE_STRIDE (FEATURES * (1 + ATT_VEC))  /* floats per coarse corner */
#define COARSE_BLOCKS_PER_AXIS (L_C / COARSE_BLOCK)
#define COARSE_CORNERS (COARSE_BLOCK + 1)

/* The model's buffers (the kernel arguments of ngprt_march, render_cl.Renderer._upload)
 * and what every sample derives from them alone. */
typedef struct {
    __global const occ_t *occupancy;   /* ours: OCC_RES^3 render_cl.exit_codes; the paper's
                                        * (MARCH_PAPER): render_cl.mip_levels */
    __global const uchar *G;           /* G_RES^3: distance to occupancy, G-voxels */
    __global const int *block_index;   /* (L_C / COARSE_BLOCK)^3: block of a cell, -1 none */
    __global const float8 *blocks;     /* n_blocks * COARSE_CORNERS^3 corners, COARSE_STRIDE */
    int n_blocks;
    __global const table_t *tables;    /* L * 2^LOG2_T entries: the fine hash tables */
    __global const float *fusion;      /* render_cl.fusion_params */
    float8 inv_sig[SIG_LEN];           /* -inv variants: sigmoid of the invariant logits */
} Model;
#endif
