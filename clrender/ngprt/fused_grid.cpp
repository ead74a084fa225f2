// Fused multi-level grid lookup of the fast training engine (clrender/ngprt/fused.py):
// the corner indices (Instant-NGP hash or dense), the trilinear weights and the gather in
// one pass over the samples, and the table gradient's scatter in one pass per level.
// The specification is torch_ops.grid_lookup: the same float32 operations in the same
// order; the gradient accumulates in float32 in the order of its bincount (sample, then
// corner), so it is the reference's bit for bit.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <cmath>
#include <cstdint>
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

// Row (within the level's table) of corner (x, y, z); as torch_ops._level_indices.
inline int64_t row(const Level& lv, int64_t x, int64_t y, int64_t z, int64_t mask) {
    if (lv.dense) {
        x = std::min(std::max(x, (int64_t)0), lv.r1 - 1);
        y = std::min(std::max(y, (int64_t)0), lv.r1 - 1);
        z = std::min(std::max(z, (int64_t)0), lv.r1 - 1);
        return x * (lv.r1 * lv.r1) + y * lv.r1 + z;
    }
    return (x ^ (y * PRIME_Y) ^ (z * PRIME_Z)) & mask;
}

// The corners (rows) and trilinear weights of sample u at level lv: 8, or 1 on vertices.
inline int corners(const Level& lv, const float* u, int64_t mask, int64_t* rows, float* w) {
    int64_t b[3];
    float w1[3];
    for (int a = 0; a < 3; ++a) {
        const float p = u[a] * lv.res;
        const float f = std::floor(p);
        b[a] = (int64_t)f;
        w1[a] = p - f;
    }
    if (lv.vertex) {
        rows[0] = row(lv, b[0], b[1], b[2], mask);
        w[0] = 1.0f;
        return 1;
    }
    for (int c = 0; c < 8; ++c) {
        const int cx = (c >> 2) & 1, cy = (c >> 1) & 1, cz = c & 1;
        rows[c] = row(lv, b[0] + cx, b[1] + cy, b[2] + cz, mask);
        const float wx = cx ? w1[0] : 1.0f - w1[0];
        const float wy = cy ? w1[1] : 1.0f - w1[1];
        const float wz = cz ? w1[2] : 1.0f - w1[2];
        w[c] = wx * wy * wz;
    }
    return 8;
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
        int64_t rows[8];
        float w[8];
        for (int64_t n = begin; n < end; ++n)
            for (int64_t l = 0; l < n_lev; ++l) {
                const int k = corners(lv[l], up + 3 * n, T - 1, rows, w);
                float* dst = o + (n * n_lev + l) * F;
                for (int64_t f = 0; f < F; ++f) dst[f] = 0.0f;
                for (int j = 0; j < k; ++j) {
                    const float* src = tab + (l * T + rows[j]) * F;
                    for (int64_t f = 0; f < F; ++f) dst[f] += w[j] * src[f];
                }
            }
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
        int64_t rows[8];
        float w[8];
        for (int64_t l = begin; l < end; ++l)
            for (int64_t n = 0; n < N; ++n) {
                const int k = corners(lv[l], up + 3 * n, T - 1, rows, w);
                const float* src = gp + (n * n_lev + l) * F;
                for (int j = 0; j < k; ++j) {
                    float* dst = a + (l * T + rows[j]) * F;
                    for (int64_t f = 0; f < F; ++f) dst[f] += w[j] * src[f];
                }
            }
    });
    return acc;
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
    m.def("grid_forward", &grid_forward, "fused multi-level grid lookup");
    m.def("grid_backward", &grid_backward, "its table gradient");
}
