// Fused multi-level grid lookup of the fast training engine (clrender/ngprt/fused.py):
// the corner indices (Instant-NGP hash or dense), the trilinear weights and the gather in
// one pass over the samples, and the table gradient's scatter in one pass per level.
// The specification is torch_ops.grid_lookup: the same float32 operations in the same
// order; the gradient accumulates in float32 in the order of its bincount (sample, then
// corner), so it is the reference's bit for bit.
// Also: the auxiliary NGP fused whole (encoding, then its one-hidden-layer MLP per corner,
// nothing of the hidden layer kept; torch_ops.aux_values), the coarse grid's corners with
// their de-duplication (torch_ops.coarse_corners, bit for bit) and their trilinear sum
// (torch_ops.corner_gather). The MLP uses fused multiply-adds and its own summation
// order: a change of rounding, bounded in tests/test_fused.py.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <vector>

namespace {

constexpr int64_t PRIME_Y = 2654435761LL, PRIME_Z = 805459861LL;

struct Level {
    float res;          // R_l
    int64_t r1;         // R_l + 1 (dense levels)
    bool dense;
    bool vertex;        // every sample lies on a vertex: read the one row of `base`
};

std::vector<Level> levels(const std::vector<int64_t>& res, const std::vector<bool>& dense,
                          int64_t on_vertices) {
    const int64_t n = (int64_t)res.size();
    std::vector<Level> out(n);
    for (int64_t l = 0; l < n; ++l)
        out[l] = {(float)res[l], res[l] + 1, (bool)dense[l], l >= n - on_vertices};
    return out;
}

// The corners (rows) and trilinear weights of sample u at level lv: 8, or 1 on vertices.
// Rows as torch_ops._level_indices (hash: x ^ y * PRIME_Y ^ z * PRIME_Z masked; dense:
// clamped, x slowest), built from each axis' two terms; weights wx * wy * wz in float32.
inline int corners(const Level& lv, const float* u, int64_t mask, int64_t* rows, float* w) {
    int64_t t[3][2];                   // each axis' term of the row, for corner offsets 0, 1
    float wa[3][2];
    const int64_t scale[3] = {lv.dense ? lv.r1 * lv.r1 : 1, lv.dense ? lv.r1 : PRIME_Y,
                              lv.dense ? 1 : PRIME_Z};
    for (int a = 0; a < 3; ++a) {
        const float p = u[a] * lv.res;
        const float f = std::floor(p);
        const int64_t b = (int64_t)f;
        wa[a][1] = p - f;
        wa[a][0] = 1.0f - wa[a][1];
        for (int c = 0; c < 2; ++c) {
            const int64_t x = lv.dense ? std::min(std::max(b + c, (int64_t)0), lv.r1 - 1) : b + c;
            t[a][c] = x * scale[a];
        }
    }
    if (lv.vertex) {
        rows[0] = lv.dense ? t[0][0] + t[1][0] + t[2][0] : (t[0][0] ^ t[1][0] ^ t[2][0]) & mask;
        w[0] = 1.0f;
        return 1;
    }
    for (int c = 0; c < 8; ++c) {
        const int cx = (c >> 2) & 1, cy = (c >> 1) & 1, cz = c & 1;
        rows[c] = lv.dense ? t[0][cx] + t[1][cy] + t[2][cz]
                           : (t[0][cx] ^ t[1][cy] ^ t[2][cz]) & mask;
        w[c] = wa[0][cx] * wa[1][cy] * wa[2][cz];
    }
    return 8;
}

// Samples between a row's prefetch and its read.
constexpr int64_t AHEAD = 16;

// The corners of levels [l0, l1) of samples [begin, end), each computed once, AHEAD samples
// before they are read: the rows prefetched then (the tables are larger than the caches
// and their rows random; RW 1 for rows about to be written), kept in a ring of AHEAD + 1
// samples until read.
template <int RW>
class CornerRing {
  public:
    CornerRing(const std::vector<Level>& lv, int64_t l0, int64_t l1, const float* tab,
               int64_t T, int64_t F, const float* u, int64_t begin, int64_t end)
        : lv_(lv), l0_(l0), nl_(l1 - l0), T_(T), F_(F), tab_(tab), u_(u), end_(end),
          next_(begin), k_(SLOTS * nl_), rows_(SLOTS * nl_ * 8), w_(SLOTS * nl_ * 8) {
        while (next_ < std::min(begin + AHEAD, end)) compute(next_++);
    }

    // The slot of sample n (n = begin, begin + 1, ... in turn); computes sample n + AHEAD.
    int64_t next(int64_t n) {
        if (next_ < end_) compute(next_++);
        return n % SLOTS;
    }
    // Slot s's corner count, rows and weights at its i-th level (level l0 + i).
    int k(int64_t s, int64_t i) const { return k_[s * nl_ + i]; }
    const int64_t* rows(int64_t s, int64_t i) const { return &rows_[(s * nl_ + i) * 8]; }
    const float* w(int64_t s, int64_t i) const { return &w_[(s * nl_ + i) * 8]; }

  private:
    static constexpr int64_t SLOTS = AHEAD + 1;

    void compute(int64_t m) {
        const int64_t s = m % SLOTS;
        for (int64_t i = 0; i < nl_; ++i) {
            int64_t* r = &rows_[(s * nl_ + i) * 8];
            const int k = k_[s * nl_ + i] =
                corners(lv_[l0_ + i], u_ + 3 * m, T_ - 1, r, &w_[(s * nl_ + i) * 8]);
            const float* base = tab_ + (l0_ + i) * T_ * F_;
            for (int j = 0; j < k; ++j) __builtin_prefetch(base + r[j] * F_, RW);
        }
    }

    const std::vector<Level>& lv_;
    const int64_t l0_, nl_, T_, F_;
    const float *tab_, *u_;
    const int64_t end_;
    int64_t next_;                     // the next sample to compute
    std::vector<int> k_;               // (SLOTS, nl)
    std::vector<int64_t> rows_;        // (SLOTS, nl, 8)
    std::vector<float> w_;             // (SLOTS, nl, 8)
};

// The (n_levels * F) features of ring slot s (every level) into dst; FF > 0: F known at
// compile time (4 and 8, the presets' feature counts).
template <int FF>
inline void lookup_f(const CornerRing<0>& ring, int64_t s, int64_t n_lev, const float* tab,
                     int64_t T, int64_t Fr, float* dst) {
    const int64_t F = FF > 0 ? FF : Fr;
    for (int64_t l = 0; l < n_lev; ++l, dst += F) {
        const int k = ring.k(s, l);
        const int64_t* rows = ring.rows(s, l);
        const float* w = ring.w(s, l);
        // Summed in a local array (FF > 0): dst may alias the tables for all the compiler
        // knows, which would make every product's addition a store and a reload.
        float local[FF > 0 ? FF : 1];
        float* sum = FF > 0 ? local : dst;
        for (int64_t f = 0; f < F; ++f) sum[f] = 0.0f;
        for (int j = 0; j < k; ++j) {
            const float* src = tab + (l * T + rows[j]) * F;
            for (int64_t f = 0; f < F; ++f) sum[f] += w[j] * src[f];
        }
        if (FF > 0)
            for (int64_t f = 0; f < F; ++f) dst[f] = sum[f];
    }
}

// The features (n_levels * F) of samples [n0, n1) into x (n1 - n0, n_levels * F), their
// corners taken from ring in turn (n0: the next sample the ring hands out).
void lookup_block(CornerRing<0>& ring, int64_t n_lev, const float* tab, int64_t T, int64_t F,
                  int64_t n0, int64_t n1, float* x) {
    for (int64_t n = n0; n < n1; ++n, x += n_lev * F) {
        const int64_t s = ring.next(n);
        if (F == 4) lookup_f<4>(ring, s, n_lev, tab, T, F, x);
        else if (F == 8) lookup_f<8>(ring, s, n_lev, tab, T, F, x);
        else lookup_f<0>(ring, s, n_lev, tab, T, F, x);
    }
}

// Table gradient of the levels [begin, end) from g (N, n_levels, F), rows summed in
// float32 in sample then corner order (as bincount), into acc (n_levels, T, F); FF as in
// lookup_f.
template <int FF>
void scatter_levels_f(const std::vector<Level>& lv, const float* gp, const float* up, int64_t N,
                      int64_t T, int64_t Fr, int64_t begin, int64_t end, float* a) {
    const int64_t F = FF > 0 ? FF : Fr;
    const int64_t n_lev = (int64_t)lv.size();
    for (int64_t l = begin; l < end; ++l) {
        CornerRing<1> ring(lv, l, l + 1, a, T, F, up, 0, N);
        for (int64_t n = 0; n < N; ++n) {
            const int64_t s = ring.next(n);
            const int k = ring.k(s, 0);
            const int64_t* rows = ring.rows(s, 0);
            const float* w = ring.w(s, 0);
            const float* src = gp + (n * n_lev + l) * F;
            for (int j = 0; j < k; ++j) {
                float* dst = a + (l * T + rows[j]) * F;
                for (int64_t f = 0; f < F; ++f) dst[f] += w[j] * src[f];
            }
        }
    }
}

void scatter_levels(const std::vector<Level>& lv, const float* gp, const float* up, int64_t N,
                    int64_t T, int64_t F, int64_t begin, int64_t end, float* a) {
    if (F == 4) scatter_levels_f<4>(lv, gp, up, N, T, F, begin, end, a);
    else if (F == 8) scatter_levels_f<8>(lv, gp, up, N, T, F, begin, end, a);
    else scatter_levels_f<0>(lv, gp, up, N, T, F, begin, end, a);
}

}  // namespace

// (N, n_levels, F) features of tables (n_levels, T, F) at grid coordinates u (N, 3).
torch::Tensor grid_forward(torch::Tensor tables, torch::Tensor u, std::vector<int64_t> res,
                           std::vector<bool> dense, int64_t on_vertices) {
    const int64_t n_lev = tables.size(0), T = tables.size(1), F = tables.size(2);
    const int64_t N = u.size(0);
    const auto lv = levels(res, dense, on_vertices);
    auto out = torch::empty({N, n_lev, F}, tables.options());
    const float* tab = tables.data_ptr<float>();
    const float* up = u.data_ptr<float>();
    float* o = out.data_ptr<float>();
    at::parallel_for(0, N, 256, [&](int64_t begin, int64_t end) {
        CornerRing<0> ring(lv, 0, n_lev, tab, T, F, up, begin, end);
        lookup_block(ring, n_lev, tab, T, F, begin, end, o + begin * n_lev * F);
    });
    return out;
}

// (n_levels, T, F) float32 gradient of the tables from g (N, n_levels, F): each level's
// rows owned by one task, summed in float32 in sample then corner order (as bincount).
torch::Tensor grid_backward(torch::Tensor g, torch::Tensor u, int64_t T,
                            std::vector<int64_t> res, std::vector<bool> dense,
                            int64_t on_vertices) {
    const int64_t N = u.size(0), n_lev = g.size(1), F = g.size(2);
    const auto lv = levels(res, dense, on_vertices);
    auto acc = torch::zeros({n_lev, T, F}, g.options());
    const float* gp = g.data_ptr<float>();
    const float* up = u.data_ptr<float>();
    float* a = acc.data_ptr<float>();
    at::parallel_for(0, n_lev, 1, [&](int64_t begin, int64_t end) {
        scatter_levels(lv, gp, up, N, T, F, begin, end, a);
    });
    return acc;
}


// -- the auxiliary NGP: encoding + MLP (torch_ops.aux_values) ----------------------------
// The MLP's multiply-adds may be fused (its rounding is not the reference's anyway), in
// this section only; the grid and corner code rounds each product.
#pragma GCC push_options
#pragma GCC optimize("fp-contract=fast")

namespace {

// Corners per task of the MLP's backward: each chunk sums its weight gradient alone, and
// the chunks are added in order, so the result does not depend on the thread count.
constexpr int64_t AUX_CHUNK = 2048;
// Corners whose features the forward looks up before their MLPs.
constexpr int64_t AUX_BLOCK = 64;
// The MLP's sizes padded with zero weights (exact: a padded unit's pre-activation is 0,
// so relu keeps it 0 and masks its gradient), in vectors of V floats, the target's widest
// (GCC vector types: wider ones are split into the target's with values passed through
// the stack, and compared a float at a time). A float's operations and their order do not
// depend on V, so neither do the results (where the target has FMA: one without rounds each
// product, e.g. x86-64 without AVX).
constexpr int64_t PI = 32, PH = 64, PO = 16;
#if defined(__AVX512F__)
constexpr int64_t V = 16;
#elif defined(__AVX__)
constexpr int64_t V = 8;
#else
constexpr int64_t V = 4;
#endif
typedef float vf __attribute__((vector_size(V * 4)));
constexpr int64_t HV = PH / V, OV = PO / V;         // the hidden layer's vectors, the output's
static_assert(PI % V == 0 && PH % V == 0 && PO % V == 0, "the padded sizes are whole vectors");
// Independent partial sums of the MLP's long dot products (PH a multiple of it).
constexpr int ACC = 4;
static_assert(ACC == 4 && PH % ACC == 0, "output() and input_grad() add four partial sums");
// Corners whose weight-gradient outer products are added to the accumulators at once
// (one load and store of an accumulator row per GROUP corners instead of per corner).
constexpr int GROUP = 4;

struct Mlp {
    vf w0[PI][HV], b0[HV], w1[PH][OV], b1[OV];        // x @ w + b: w0[i] the row of input i
    vf w1t[PO][HV], w0t[PH][PI / V];                  // transposed: w1t[k] the column k
    int64_t I, H, O;

    Mlp(const torch::Tensor& W0, const torch::Tensor& B0, const torch::Tensor& W1,
        const torch::Tensor& B1)
        : w0(), b0(), w1(), b1(), w1t(), w0t(), I(W0.size(0)), H(W0.size(1)), O(W1.size(1)) {
        TORCH_CHECK(I <= PI && H <= PH && O <= PO, "aux MLP ", I, "->", H, "->", O,
                    " is above the fused sizes ", PI, "->", PH, "->", PO);
        const float *a0 = W0.data_ptr<float>(), *c0 = B0.data_ptr<float>();
        const float *a1 = W1.data_ptr<float>(), *c1 = B1.data_ptr<float>();
        for (int64_t j = 0; j < H; ++j) {
            b0[j / V][j % V] = c0[j];
            for (int64_t i = 0; i < I; ++i)
                w0t[j][i / V][i % V] = w0[i][j / V][j % V] = a0[i * H + j];
            for (int64_t k = 0; k < O; ++k)
                w1t[k][j / V][j % V] = w1[j][k / V][k % V] = a1[j * O + k];
        }
        for (int64_t k = 0; k < O; ++k) b1[k / V][k % V] = c1[k];
    }

    // h = relu(x @ w0 + b0) for x (I)
    void hidden(const float* x, vf* h) const {
        for (int q = 0; q < HV; ++q) h[q] = b0[q];
        for (int64_t i = 0; i < I; ++i)
            for (int q = 0; q < HV; ++q) h[q] += x[i] * w0[i][q];
        for (int q = 0; q < HV; ++q) h[q] = h[q] > 0.0f ? h[q] : 0.0f;
    }

    // y = h @ w1 + b1 (OV vectors), in ACC interleaved sums (one chain of 64 fused
    // multiply-adds would wait on each one's latency)
    void output(const vf* h, vf* y) const {
        float hs[PH];                          // scalars to broadcast
        std::memcpy(hs, h, sizeof(hs));
        for (int r = 0; r < OV; ++r) {
            vf o[ACC] = {b1[r]};
            for (int64_t j = 0; j < PH; j += ACC)
                for (int a = 0; a < ACC; ++a) o[a] += hs[j + a] * w1[j + a][r];
            y[r] = (o[0] + o[1]) + (o[2] + o[3]);
        }
    }

    // (x's gradient) gh @ w0^T for gh (H) into dx (the first PI / V vectors up to I),
    // ACC interleaved sums as output()
    void input_grad(const vf* gh, vf* dx) const {
        float ghs[PH];
        std::memcpy(ghs, gh, sizeof(ghs));
        for (int q = 0; q < (I + V - 1) / V; ++q) {
            vf d[ACC] = {};
            for (int64_t j = 0; j < PH; j += ACC)
                for (int a = 0; a < ACC; ++a) d[a] += ghs[j + a] * w0t[j + a][q];
            dx[q] = (d[0] + d[1]) + (d[2] + d[3]);
        }
    }
};

}  // namespace

// [(M, O) auxiliary NGP outputs at grid coordinates u (M, 3), and with keep_x the (M, I)
// features x]: the grid lookup of tables (n_levels, T, F) into x (n_levels * F = I), then
// relu(x @ w0 + b0) @ w1 + b1.
std::vector<torch::Tensor> aux_forward(torch::Tensor tables, torch::Tensor u,
                                       std::vector<int64_t> res, std::vector<bool> dense,
                                       int64_t on_vertices, torch::Tensor w0, torch::Tensor b0,
                                       torch::Tensor w1, torch::Tensor b1, bool keep_x) {
    const int64_t n_lev = tables.size(0), T = tables.size(1), F = tables.size(2), M = u.size(0);
    const auto lv = levels(res, dense, on_vertices);
    const auto mlp_ptr = std::make_unique<Mlp>(w0, b0, w1, b1);
    const Mlp& mlp = *mlp_ptr;
    TORCH_CHECK(n_lev * F == mlp.I, "aux MLP input ", mlp.I, " != levels x features");
    auto out = torch::empty({M, mlp.O}, tables.options());
    const float* tab = tables.data_ptr<float>();
    const float* up = u.data_ptr<float>();
    float* o = out.data_ptr<float>();
    const int64_t I = mlp.I, O = mlp.O;
    auto xs = torch::empty({keep_x ? M : 0, I}, tables.options());
    float* xp = xs.data_ptr<float>();
    at::parallel_for(0, M, 256, [&](int64_t begin, int64_t end) {
        // The lookup (lookup_block, compiled outside this section) rounds each product as
        // grid_forward does; only the MLP below fuses its multiply-adds.
        CornerRing<0> ring(lv, 0, n_lev, tab, T, F, up, begin, end);
        float block[AUX_BLOCK * PI];   // the features of a block of corners, unless kept
        vf h[HV], y[OV];
        for (int64_t n0 = begin; n0 < end; n0 += AUX_BLOCK) {
            const int64_t n1 = std::min(end, n0 + AUX_BLOCK);
            float* x = keep_x ? xp + n0 * I : block;
            lookup_block(ring, n_lev, tab, T, F, n0, n1, x);
            for (int64_t n = n0; n < n1; ++n, x += I) {
                mlp.hidden(x, h);
                mlp.output(h, y);
                for (int64_t k = 0; k < O; ++k) o[n * O + k] = y[k / V][k % V];
            }
        }
    });
    return {out, xs};
}

// Gradients of aux_forward from g (M, O), given its features xs (M, I): [tables (n_levels,
// T, F), w0, b0, w1, b1]. The hidden layer is recomputed; the table gradient is
// grid_backward's of the input gradient.
std::vector<torch::Tensor> aux_backward(torch::Tensor g, torch::Tensor xs, torch::Tensor tables,
                                        torch::Tensor u,
                                        std::vector<int64_t> res, std::vector<bool> dense,
                                        int64_t on_vertices, torch::Tensor w0, torch::Tensor b0,
                                        torch::Tensor w1, torch::Tensor b1) {
    const int64_t n_lev = tables.size(0), T = tables.size(1), F = tables.size(2);
    const int64_t M = u.size(0);
    const auto lv = levels(res, dense, on_vertices);
    const auto mlp_ptr = std::make_unique<Mlp>(w0, b0, w1, b1);
    const Mlp& mlp = *mlp_ptr;
    const int64_t I = mlp.I, H = mlp.H, O = mlp.O;
    TORCH_CHECK(n_lev * F == I, "aux MLP input ", I, " != levels x features");
    const int64_t n_chunks = (M + AUX_CHUNK - 1) / AUX_CHUNK;
    auto gx = torch::empty({M, n_lev, F}, g.options());
    struct Part {                      // one chunk's weight gradient, padded
        vf w0[PI][HV], b0[HV], w1[PH][OV], b1[OV];
    };
    std::vector<Part> part(n_chunks);
    const float* xp = xs.data_ptr<float>();
    const float* up = u.data_ptr<float>();
    const float* gp = g.data_ptr<float>();
    float* gxp = gx.data_ptr<float>();
    at::parallel_for(0, n_chunks, 1, [&](int64_t c0, int64_t c1) {
        // per corner of a group: its features, hidden layer, output and hidden gradients
        float x[GROUP][PI], hs[GROUP][PH];
        vf h[HV], gh[GROUP][HV], go[GROUP][OV], dx[PI / V];
        for (int64_t c = c0; c < c1; ++c) {
            Part& d = part[c];           // zero-initialised by the vector
            const int64_t end = std::min(M, (c + 1) * AUX_CHUNK);
            for (int64_t n0 = c * AUX_CHUNK; n0 < end; n0 += GROUP) {
                for (int g = 0; g < GROUP; ++g) {
                    const int64_t n = n0 + g;
                    if (n >= end) {      // past the chunk: zero rows add nothing
                        std::memset(x[g], 0, sizeof(x[g]));
                        std::memset(hs[g], 0, sizeof(hs[g]));
                        for (int r = 0; r < OV; ++r) go[g][r] = vf{};
                        for (int q = 0; q < HV; ++q) gh[g][q] = vf{};
                        continue;
                    }
                    for (int64_t i = 0; i < I; ++i) x[g][i] = xp[n * I + i];
                    mlp.hidden(x[g], h);
                    std::memcpy(hs[g], h, sizeof(h));
                    for (int r = 0; r < OV; ++r) go[g][r] = vf{};
                    for (int64_t k = 0; k < O; ++k) go[g][k / V][k % V] = gp[n * O + k];
                    for (int q = 0; q < HV; ++q) gh[g][q] = vf{};
                    for (int64_t k = 0; k < O; ++k)
                        for (int q = 0; q < HV; ++q)
                            gh[g][q] += go[g][k / V][k % V] * mlp.w1t[k][q];
                    for (int q = 0; q < HV; ++q)       // relu's mask
                        gh[g][q] = h[q] > 0.0f ? gh[g][q] : 0.0f;
                    mlp.input_grad(gh[g], dx);
                    for (int64_t i = 0; i < I; ++i) gxp[n * I + i] = dx[i / V][i % V];
                }
                // The group's weight gradients: each accumulator row loaded and stored
                // once (h 0 where relu cut: a zero row, as torch's).
                for (int r = 0; r < OV; ++r)
                    for (int g = 0; g < GROUP; ++g) d.b1[r] += go[g][r];
                for (int64_t j = 0; j < H; ++j)
                    for (int r = 0; r < OV; ++r) {
                        vf a = d.w1[j][r];
                        for (int g = 0; g < GROUP; ++g) a += hs[g][j] * go[g][r];
                        d.w1[j][r] = a;
                    }
                for (int q = 0; q < HV; ++q)
                    for (int g = 0; g < GROUP; ++g) d.b0[q] += gh[g][q];
                for (int64_t i = 0; i < I; ++i)
                    for (int q = 0; q < HV; ++q) {
                        vf a = d.w0[i][q];
                        for (int g = 0; g < GROUP; ++g) a += x[g][i] * gh[g][q];
                        d.w0[i][q] = a;
                    }
            }
        }
    });
    Part sum = {};                     // the chunks in order
    for (const Part& d : part) {
        for (int64_t i = 0; i < PI; ++i)
            for (int q = 0; q < HV; ++q) sum.w0[i][q] += d.w0[i][q];
        for (int q = 0; q < HV; ++q) sum.b0[q] += d.b0[q];
        for (int64_t j = 0; j < PH; ++j)
            for (int r = 0; r < OV; ++r) sum.w1[j][r] += d.w1[j][r];
        for (int r = 0; r < OV; ++r) sum.b1[r] += d.b1[r];
    }
    auto gw0 = torch::empty({I, H}, g.options()), gb0 = torch::empty({H}, g.options());
    auto gw1 = torch::empty({H, O}, g.options()), gb1 = torch::empty({O}, g.options());
    for (int64_t j = 0; j < H; ++j) {
        gb0.data_ptr<float>()[j] = sum.b0[j / V][j % V];
        for (int64_t i = 0; i < I; ++i) gw0.data_ptr<float>()[i * H + j] = sum.w0[i][j / V][j % V];
        for (int64_t k = 0; k < O; ++k)
            gw1.data_ptr<float>()[j * O + k] = sum.w1[j][k / V][k % V];
    }
    for (int64_t k = 0; k < O; ++k) gb1.data_ptr<float>()[k] = sum.b1[k / V][k % V];
    auto acc = torch::zeros({n_lev, T, F}, g.options());
    float* a = acc.data_ptr<float>();
    at::parallel_for(0, n_lev, 1, [&](int64_t begin, int64_t end) {
        scatter_levels(lv, gxp, up, M, T, F, begin, end, a);
    });
    return {acc, gw0, gb0, gw1, gb1};
}

#pragma GCC pop_options

// -- the coarse grid's corners (torch_ops.coarse_corners) --------------------------------

// The L_C cell of each sample u (N, 3) at resolution R: [corners (M, 3) int64, the batch's
// unique corners in increasing flat id (x slowest), as torch.unique; idx (N, 8) int64 into
// them; w (N, 8) float32 trilinear weights (x slowest)], torch_ops' float32 operations.
std::vector<torch::Tensor> coarse_corners(torch::Tensor u, int64_t R) {
    const int64_t N = u.size(0), R1 = R + 1, n_ids = R1 * R1 * R1;
    auto idx = torch::empty({N, 8}, u.options().dtype(torch::kInt64));
    auto w = torch::empty({N, 8}, u.options());
    const float* up = u.data_ptr<float>();
    int64_t* ip = idx.data_ptr<int64_t>();
    float* wp = w.data_ptr<float>();
    const float Rf = (float)R;
    at::parallel_for(0, N, 1024, [&](int64_t begin, int64_t end) {
        for (int64_t n = begin; n < end; ++n) {
            int64_t b[3];
            float w1[3];
            for (int a = 0; a < 3; ++a) {
                const float p = up[3 * n + a] * Rf;
                const float f = std::min(std::max(std::floor(p), 0.0f), (float)(R - 1));
                b[a] = (int64_t)f;
                w1[a] = p - f;
            }
            for (int c = 0; c < 8; ++c) {
                const int cx = (c >> 2) & 1, cy = (c >> 1) & 1, cz = c & 1;
                ip[8 * n + c] = ((b[0] + cx) * R1 + (b[1] + cy)) * R1 + (b[2] + cz);
                const float wx = cx ? w1[0] : 1.0f - w1[0];
                const float wy = cy ? w1[1] : 1.0f - w1[1];
                const float wz = cz ? w1[2] : 1.0f - w1[2];
                wp[8 * n + c] = wx * wy * wz;
            }
        }
    });
    // De-duplication by a bit a corner id over the (R+1)^3 ids (sorted by construction;
    // 270 KB at R = 128, in cache): a corner's index is the marked ids below it, its
    // word's count of them plus the bits below it in the word.
    const int64_t n_words = (n_ids + 63) / 64;
    std::vector<uint64_t> bits(n_words, 0);
    for (int64_t q = 0; q < 8 * N; ++q) bits[ip[q] >> 6] |= uint64_t(1) << (ip[q] & 63);
    std::vector<int64_t> below(n_words + 1, 0);     // marked ids in the words before
    for (int64_t k = 0; k < n_words; ++k) below[k + 1] = below[k] + __builtin_popcountll(bits[k]);
    const int64_t M = below[n_words];
    auto corners = torch::empty({M, 3}, idx.options());
    int64_t* cp = corners.data_ptr<int64_t>();
    at::parallel_for(0, n_words, 1024, [&](int64_t k0, int64_t k1) {
        for (int64_t k = k0; k < k1; ++k) {
            int64_t j = below[k];
            for (uint64_t b = bits[k]; b; b &= b - 1, ++j) {
                const int64_t id = 64 * k + __builtin_ctzll(b);
                cp[3 * j] = id / (R1 * R1);
                cp[3 * j + 1] = (id / R1) % R1;
                cp[3 * j + 2] = id % R1;
            }
        }
    });
    at::parallel_for(0, 8 * N, 8192, [&](int64_t begin, int64_t end) {
        for (int64_t q = begin; q < end; ++q) {
            const int64_t id = ip[q];
            const uint64_t lower = (uint64_t(1) << (id & 63)) - 1;
            ip[q] = below[id >> 6] + __builtin_popcountll(bits[id >> 6] & lower);
        }
    });
    return {corners, idx, w};
}

namespace {

// The coarse trilinear sum and its gradient for C channels; CC > 0: C known at compile
// time (the presets' 12 and 16: 8 features + 2 L attention logits), so the channel loops
// are vector code.
template <int CC>
void corner_sum(const float* v, const int64_t* ip, const float* wp, int64_t J, int64_t Cr,
                int64_t begin, int64_t end, float* o) {
    const int64_t C = CC > 0 ? CC : Cr;
    for (int64_t n = begin; n < end; ++n) {
        float acc[CC > 0 ? CC : 1] = {};
        float* dst = CC > 0 ? acc : o + n * C;
        if (CC == 0)
            for (int64_t c = 0; c < C; ++c) dst[c] = 0.0f;
        for (int64_t j = 0; j < J; ++j) {
            const float wj = wp[n * J + j];
            const float* src = v + ip[n * J + j] * C;
            for (int64_t c = 0; c < C; ++c) dst[c] += wj * src[c];
        }
        if (CC > 0)
            for (int64_t c = 0; c < C; ++c) o[n * C + c] = acc[c];
    }
}

template <int CC>
void corner_scatter(const float* gp, const int64_t* ip, const float* wp, int64_t N, int64_t J,
                    int64_t Cr, int64_t lo, int64_t hi, float* a) {
    const int64_t C = CC > 0 ? CC : Cr;
    for (int64_t n = 0; n < N; ++n) {
        const float* src = gp + n * C;
        for (int64_t q = n * J; q < (n + 1) * J; ++q) {
            const int64_t r = ip[q];
            if (r < lo || r >= hi) continue;
            const float wq = wp[q];
            float* dst = a + r * C;
            for (int64_t c = 0; c < C; ++c) dst[c] += wq * src[c];
        }
    }
}

}  // namespace

// (N, C) sum_j w[n, j] * values[idx[n, j]] for values (M, C), idx and w (N, J).
torch::Tensor corner_forward(torch::Tensor values, torch::Tensor idx, torch::Tensor w) {
    const int64_t N = idx.size(0), J = idx.size(1), C = values.size(1);
    auto out = torch::empty({N, C}, values.options());
    const float* v = values.data_ptr<float>();
    const int64_t* ip = idx.data_ptr<int64_t>();
    const float* wp = w.data_ptr<float>();
    float* o = out.data_ptr<float>();
    at::parallel_for(0, N, 512, [&](int64_t begin, int64_t end) {
        if (C == 12) corner_sum<12>(v, ip, wp, J, C, begin, end, o);
        else if (C == 16) corner_sum<16>(v, ip, wp, J, C, begin, end, o);
        else corner_sum<0>(v, ip, wp, J, C, begin, end, o);
    });
    return out;
}

// (M, C) gradient of corner_forward's values from g (N, C): each task owns a range of
// rows and sums into it in sample then corner order (any thread count, the same sums).
torch::Tensor corner_backward(torch::Tensor g, torch::Tensor idx, torch::Tensor w, int64_t M) {
    const int64_t N = idx.size(0), J = idx.size(1), C = g.size(1);
    auto grad = torch::zeros({M, C}, g.options());
    const float* gp = g.data_ptr<float>();
    const int64_t* ip = idx.data_ptr<int64_t>();
    const float* wp = w.data_ptr<float>();
    float* a = grad.data_ptr<float>();
    const int64_t n_tasks = std::max<int64_t>(1, at::get_num_threads());
    at::parallel_for(0, n_tasks, 1, [&](int64_t t0, int64_t t1) {
        const int64_t lo = M * t0 / n_tasks, hi = M * t1 / n_tasks;
        if (C == 12) corner_scatter<12>(gp, ip, wp, N, J, C, lo, hi, a);
        else if (C == 16) corner_scatter<16>(gp, ip, wp, N, J, C, lo, hi, a);
        else corner_scatter<0>(gp, ip, wp, N, J, C, lo, hi, a);
    });
    return grad;
}

// -- the bounded step lattice (torch_ops.lattice_samples, bounded scenes) ----------------

// The lattice points t_k = k * s of rays (R, 3) (unit dirs) inside [-extent, extent]^3 from
// `near`, kept where their L_C cell of `occupancy` (R_C^3 bool) is set: [ray_ids, k (M,)
// int64; t, delta (M,) float32; u (M, 3) float32], ray-major, k increasing; torch_ops'
// float32 operations, so the same samples bit for bit.
std::vector<torch::Tensor> lattice_bounded(torch::Tensor origins, torch::Tensor dirs,
                                           torch::Tensor occupancy, double s, double near,
                                           double extent) {
    const int64_t n_rays = origins.size(0), R = occupancy.size(0);
    const float* op = origins.data_ptr<float>();
    const float* dp = dirs.data_ptr<float>();
    const bool* occ = occupancy.data_ptr<bool>();
    const float st = (float)s, nr = (float)near, ex = (float)extent, ex2 = (float)(2.0 * extent);
    constexpr int64_t RAYS = 64;                     // rays per task
    const int64_t n_tasks = (n_rays + RAYS - 1) / RAYS;
    struct Out { std::vector<int64_t> ray, k; std::vector<float> t, delta, u; };
    std::vector<Out> outs(n_tasks);
    at::parallel_for(0, n_tasks, 1, [&](int64_t b0, int64_t b1) {
        for (int64_t b = b0; b < b1; ++b) {
            Out& out = outs[b];
            for (int64_t r = b * RAYS; r < std::min(n_rays, (b + 1) * RAYS); ++r) {
                const float* o = op + 3 * r;
                const float* d = dp + 3 * r;
                float lo[3], hi[3];
                for (int a = 0; a < 3; ++a) {        // ray_box
                    const float inv = 1.0f / d[a];
                    const float t0 = (-ex - o[a]) * inv, t1 = (ex - o[a]) * inv;
                    lo[a] = std::fmin(t0, t1);
                    hi[a] = std::fmax(t0, t1);
                }
                const float t_in = std::fmax(std::fmax(lo[0], lo[1]), lo[2]);
                const float t_end = std::fmin(std::fmin(hi[0], hi[1]), hi[2]);
                const float t_start = std::isnan(t_in) ? t_in : std::max(t_in, nr);
                const float k0f = std::ceil(t_start / st);
                const float nf = std::max(std::ceil(t_end / st) - k0f + 1.0f, 0.0f);
                if (!(nf > 0.0f) || !std::isfinite(k0f)) continue;    // missed (or NaN): none
                const int64_t k0 = (int64_t)k0f, n = (int64_t)nf;
                for (int64_t k = k0; k < k0 + n; ++k) {
                    const float g = (float)k * st;
                    if (!(g < t_end)) break;
                    float u[3];
                    int64_t c[3];
                    for (int a = 0; a < 3; ++a) {
                        const float x = o[a] + g * d[a];
                        u[a] = (x + ex) / ex2;
                        const float f = std::min(std::max(std::floor(u[a] * (float)R), 0.0f),
                                                 (float)(R - 1));
                        c[a] = (int64_t)f;
                    }
                    if (!occ[(c[0] * R + c[1]) * R + c[2]]) continue;
                    out.ray.push_back(r);
                    out.k.push_back(k);
                    out.t.push_back(g);
                    out.delta.push_back((float)(k + 1) * st - g);
                    out.u.insert(out.u.end(), u, u + 3);
                }
            }
        }
    });
    int64_t M = 0;
    for (const Out& out : outs) M += (int64_t)out.ray.size();
    auto i64 = origins.options().dtype(torch::kInt64);
    auto ray_ids = torch::empty({M}, i64), ks = torch::empty({M}, i64);
    auto t = torch::empty({M}, origins.options()), delta = torch::empty({M}, origins.options());
    auto u = torch::empty({M, 3}, origins.options());
    int64_t at = 0;
    for (const Out& out : outs) {
        const int64_t m = (int64_t)out.ray.size();
        std::copy(out.ray.begin(), out.ray.end(), ray_ids.data_ptr<int64_t>() + at);
        std::copy(out.k.begin(), out.k.end(), ks.data_ptr<int64_t>() + at);
        std::copy(out.t.begin(), out.t.end(), t.data_ptr<float>() + at);
        std::copy(out.delta.begin(), out.delta.end(), delta.data_ptr<float>() + at);
        std::copy(out.u.begin(), out.u.end(), u.data_ptr<float>() + 3 * at);
        at += m;
    }
    return {ray_ids, ks, t, delta, u};
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
    m.def("grid_forward", &grid_forward, "fused multi-level grid lookup");
    m.def("grid_backward", &grid_backward, "its table gradient");
    m.attr("AUX_MAX") = pybind11::make_tuple(PI, PH, PO);   // the MLP's largest sizes
    m.attr("AUX_VECTOR") = V;                                // floats a vector of the MLP
    m.def("aux_forward", &aux_forward, "the auxiliary NGP: encoding + MLP");
    m.def("aux_backward", &aux_backward, "its gradients");
    m.def("coarse_corners", &coarse_corners, "the L_C cells' corners, de-duplicated");
    m.def("corner_forward", &corner_forward, "the coarse trilinear sum");
    m.def("corner_backward", &corner_backward, "its gradient");
    m.def("lattice_bounded", &lattice_bounded, "the bounded step lattice's kept samples");
}
