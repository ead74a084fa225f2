/* NGP-RT ray marching (docs/ngprt.md "The march, per ray").
 *
 * Each work-item marches RAYS neighbouring pixels of one row (-D RAYS = 1, 2, 4, 8 or
 * 16, ngprt_lanes.h), one ray per lane of a vector, in lockstep like the numpy reference
 * (clrender/ngprt/render_ref.py:march_reference): every pass of the loop places the
 * current lattice point t_k (k * s, or S^-1(k * s) unbounded) of all lanes at once and
 * reads one ushort per lane, the exit code of its finest cell (render_cl.exit_codes: low
 * byte 0 occupied, else 1 + the exit level, as the mip is a max-pool and the finest cell
 * decides every level; high byte G where it is read, G_IN_CODE), skips empty space with
 * the mip and (USE_G) the occupancy distance grid G (ngprt_skip.h; paper §4.3, Eq. 9),
 * or (MARCH_PAPER) reads the mip's levels coarse to fine and steps as the paper
 * (ngprt_paper.h; docs/ngprt.md "The marches"),
 * and composites the 8 fused features of the occupied lanes (ngprt_features.h, Eq. 5-8)
 * until T < T_STOP (S2.5). Lanes advance independently; a finished lane idles. The lanes
 * give a CPU driver SIMD and independent work to overlap; GPUs take RAYS = 1, one ray
 * per work-item (render_cl.lane_width).
 *
 * Headers, one concept each: ngprt_model.h (the -D sizes, the model's buffers),
 * ngprt_lanes.h (SIMD lanes), ngprt_lattice.h (unbounded lattice, contraction),
 * ngprt_space.h (the rays, their range, lattice points, cells), ngprt_skip.h (empty
 * space), ngprt_fusion.h and ngprt_features.h (a sample's features), ngprt_math.h.
 *
 * Outputs per pixel n = py * width + px:
 *   feat[8n .. 8n+7] = (acc[0..6], opacity): diffuse rgb (3), specular (4), opacity
 *   depth[n]                         depth_acc / opacity, 0 where opacity is 0
 *   n_march[n], n_occ[n]             marching points and occupied samples
 *   reads[3n .. 3n+2]                (COUNT_READS) global reads: occupancy, G, feature
 *                                    corners (clrender/ngprt/marches.py)
 */
#include "ngprt_features.h"
#include "ngprt_paper.h"

#if !defined(OCC_IMAGE)
#error "ngprt_march.cl needs -D OCC_IMAGE (render_cl.kernel_defines)"
#endif
#if OCC_IMAGE
/* OCC_IMAGE (a GPU variant, render_cl.Tuning.occupancy_image): ours' exit codes read from
 * a 3D image (uint16, x the fastest axis = the cell's z) through the texture path, one ray
 * a work-item; every coordinate read is a cell of the grid. */
#if MARCH_PAPER || RAYS != 1
#error "OCC_IMAGE: ours' march with one ray a work-item (RAYS = 1)"
#endif
__constant sampler_t OCC_SAMPLER = CLK_NORMALIZED_COORDS_FALSE | CLK_ADDRESS_CLAMP_TO_EDGE |
                                   CLK_FILTER_NEAREST;
#endif

#if COUNT_READS
/* Global-memory reads of a ray so far (marches.READ_KINDS), counted only in the counting
 * build so that the timed kernels are unchanged. */
typedef struct {
    vint occupancy, G, features;
} Reads;

/* n + c in the lanes of mask, n elsewhere. */
inline vint lane_add(vint n, vint c, vint mask) { return select(n, n + c, mask); }

/* The reads of one marching point of the lanes in `active` whose exit code is `code`:
 * the paper reads levels N_MIP - 1 .. exit level (all N_MIP at a sample), ours one exit
 * code; G where the exit level is coarser than G, unless the code carries it (ours with
 * G_IN_CODE); a sample's features (marches.feature_reads). */
inline void count_reads(Reads *n, vint code, vint active, vint sample, vint empty)
{
#if MARCH_PAPER
    n->occupancy = lane_add(n->occupancy, select((vint)(N_MIP + 1) - code, (vint)(N_MIP),
                                                 sample), active);
#else
    n->occupancy = lane_inc(n->occupancy, active);
#endif
#if USE_G && (MARCH_PAPER || !G_IN_CODE)
    const vint lev = CODE_LEVEL(code) - 1;
    n->G = lane_inc(n->G, empty & VMASK(((vint)(OCC_RES) >> lev) < G_RES));
#endif
    n->features = lane_add(n->features, (vint)(9 + 8 * L), sample);
}
#endif

/* End t_{k+1} of the interval of each lane's lattice point k (render_ref.next_t): an
 * unbounded ray's last interval ends at the ray's end. */
inline vfloat next_t(const Rays *r)
{
    const vfloat g_next = lattice_g(r, r->k + 1);
#if UNBOUNDED
    return select((vfloat)(r->far), lattice_t(r->lt, lane_min(g_next, r->g_end)),
                  VMASK(g_next < r->g_end));
#else
    return g_next;
#endif
}

/* Alpha-composites the samples of the lanes in `sample` at p and steps them on
 * (render_ref.composite): the features lane by lane, density and alpha for all lanes
 * at once (two vector exps); the march loop counts the samples. */
inline void composite(const Model *m, Rays *r, const MarchPoint *p, vint sample)
{
    vint idx[N_CORNERS];
    vfloat wt[N_CORNERS];
    coarse_corners(m, p, sample, idx, wt);
    fine_corners(p, idx, wt);
    float8 f[RAYS];
    float logit[RAYS];
    FOR_LANES(j) {
        logit[j] = 0.0f;
        if (LANE_I(sample, j)) {
            f[j] = features(j, idx, wt, m->blocks, m->tables, m->fusion, m->inv_sig);
            logit[j] = f[j].s0;
        }
    }
    const vfloat sigma = EXP(VLOAD(logit));
    const vfloat alpha = 1.0f - EXP(-sigma * (next_t(r) - p->t));
    const vfloat w = r->T * alpha;
    FOR_LANES(j) {
        if (LANE_I(sample, j)) r->acc[j] = r->acc[j] + LANE_F(w, j) * f[j];
    }
    r->opacity = select(r->opacity, r->opacity + w, sample);
    r->depth_acc = select(r->depth_acc, r->depth_acc + w * p->t, sample);
    r->T = select(r->T, r->T * (1.0f - alpha), sample);
    r->k = lane_inc(r->k, sample);
}

/* Lanes still marching: the next lattice point before the ray's end, T >= T_STOP. */
inline vint marching(const Rays *r)
{
    return VMASK(lattice_g(r, r->k) < r->g_end) & VMASK(r->T >= T_STOP);
}

/* Writes lane j's outputs for pixel n. */
inline void write_pixel(const Rays *r, int j, int n, __global float *feat,
                        __global float *depth, __global int *n_march,
                        __global int *n_occ)
{
    const float8 a = r->acc[j];
    /* acc.s0 accumulated w * sigma-logit; slot 7 carries the opacity instead. */
    __global float *out = feat + 8 * (size_t)n;
    const float op = LANE_F(r->opacity, j), dacc = LANE_F(r->depth_acc, j);
    out[0] = a.s1; out[1] = a.s2; out[2] = a.s3; out[3] = a.s4;
    out[4] = a.s5; out[5] = a.s6; out[6] = a.s7; out[7] = op;
    depth[n] = op > 0.0f ? dacc / op : 0.0f;
    n_march[n] = LANE_I(r->n_march, j);
    n_occ[n] = LANE_I(r->n_occ, j);
}

/* vec_type_hint: the lanes are explicit (RAYS rays a work-item). Without it Intel's CPU
 * compiler scalarises the vectors and re-vectorises across work-items, far slower at 16
 * lanes (docs/explanation/opencl.md, "Each kernel in its own lanes on both"). A hint: it changes no
 * result. */
__kernel __attribute__((vec_type_hint(vfloat)))
void ngprt_march(__global const float *cam, const int width, const int height,
                 const float s, const float near, const float far,
#if OCC_IMAGE
                 __read_only image3d_t occupancy_image,
#else
                 __global const occ_t *occupancy,
#endif
                 __global const uchar *G,
                 __global const int *block_index, __global const float8 *blocks,
                 const int n_blocks, __global const table_t *tables,
                 __global const float *fusion,
                 __global float *feat, __global float *depth,
                 __global int *n_march_out, __global int *n_occ_out
#if COUNT_READS
                 , __global int *reads_out
#endif
                 )
{
    const int px0 = (int)get_global_id(0) * RAYS, py = get_global_id(1);
    if (px0 >= width || py >= height) return;
#if OCC_IMAGE
    Model m = {0, G, block_index, blocks, n_blocks, tables, fusion};
#else
    Model m = {occupancy, G, block_index, blocks, n_blocks, tables, fusion};
#endif
    inv_sigmoids(fusion, m.inv_sig);
    Lattice lattice;
    float8 acc[RAYS];
    Rays r = {.lt = &lattice, .acc = acc};
    vint active = rays_start(&r, cam, px0 + LANE_IDS, py, width, s, near, far);
    active = active & marching(&r);
#if COUNT_READS
    Reads reads = {(vint)(0), (vint)(0), (vint)(0)};
#endif
    while (any(active)) {
        const MarchPoint p = march_point(&r, r.k);
#if MARCH_PAPER
        const vint code = exit_code(m.occupancy, p.cell, active);
#elif OCC_IMAGE
        const vint code = select((vint)(0), (vint)(read_imageui(
            occupancy_image, OCC_SAMPLER, (int4)(p.cell.z, p.cell.y, p.cell.x, 0)).x), active);
#else
        const vint code = lane_gather_u16(m.occupancy, flat_index(p.cell, (vint)(OCC_RES)), active);
#endif
        const vint sample = active & VMASK(CODE_LEVEL(code) == 0);
        const vint empty = active & ~sample;
        /* Both counters here, outside the branches: counted inside composite, Intel's
         * CPU compiler (RAYS = 1, no G) lost n_occ (docs/explanation/opencl.md, "Intel lost the
         * march's sample count"). */
        r.n_march = lane_inc(r.n_march, active);
        r.n_occ = lane_inc(r.n_occ, sample);
#if COUNT_READS
        count_reads(&reads, code, active, sample, empty);
#endif
        if (any(sample)) composite(&m, &r, &p, sample);
#if MARCH_PAPER
        if (any(empty)) r.k = select(r.k, paper_skip(&m, &r, &p, empty, code), empty);
#else
        if (any(empty)) r.k = select(r.k, skip(&m, &r, &p, empty, code), empty);
#endif
        active = active & marching(&r);
    }
    FOR_LANES(j) {
        if (px0 + j >= width) break;
        write_pixel(&r, j, py * width + px0 + j, feat, depth, n_march_out, n_occ_out);
#if COUNT_READS
        __global int *out = reads_out + 3 * (size_t)(py * width + px0 + j);
        out[0] = LANE_I(reads.occupancy, j);
        out[1] = LANE_I(reads.G, j);
        out[2] = LANE_I(reads.features, j);
#endif
    }
}
