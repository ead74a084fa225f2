"""Torch twins of the numpy primitives in :mod:`clrender.ngprt.space` and
:mod:`clrender.ngprt.encoding` (same float32 operations in the same order), plus the
trilinear corner helpers training needs.

Each function takes tensors on any device and keeps their device; ``tests/test_train.py``
compares them with the numpy originals on random inputs.

References: MERF (Reiser et al. 2023) Eq. 7; Instant-NGP (Mueller et al. 2022) Eq. 4;
NGP-RT S2.1, S2.3.
"""
from __future__ import annotations

import torch

from .config import LATTICE_BREAKS
from .encoding import HASH_PRIMES, SH_C

# The 8 corner offsets of a cell, corner c = (c >> 2 & 1, c >> 1 & 1, c & 1) (x slowest).
_CORNERS = [((c >> 2) & 1, (c >> 1) & 1, c & 1) for c in range(8)]


def corner_offsets(device) -> torch.Tensor:
    """(8, 3) int64 corner offsets, x slowest."""
    return torch.tensor(_CORNERS, dtype=torch.int64, device=device)


def contract(x: torch.Tensor) -> torch.Tensor:
    """MERF contraction of (..., 3) float32 points into [-2, 2]^3 (``space.contract``)."""
    ax = x.abs()
    m = torch.maximum(torch.maximum(ax[..., 0], ax[..., 1]), ax[..., 2])[..., None]
    m_safe = torch.clamp(m, min=1.0)
    s = x / m_safe
    scaled = s * (2.0 - 1.0 / m_safe)
    return torch.where(m <= 1.0, x, torch.where(ax == m, scaled, s))


def lattice_table(o: torch.Tensor, d: torch.Tensor, t_start: torch.Tensor,
                  t_end: torch.Tensor):
    """Pieces of the contracted arc length S(t) of unbounded rays (``space.lattice_table``,
    the same float32 operations): (brk (N, 14), cum (N, 14), A, B, K (N, 13))."""
    cand = []
    for i, j in ((0, 1), (0, 2), (1, 2)):
        cand.append((o[:, j] - o[:, i]) / (d[:, i] - d[:, j]))
        cand.append(-(o[:, i] + o[:, j]) / (d[:, i] + d[:, j]))
    for i in range(3):
        cand.append((1.0 - o[:, i]) / d[:, i])
        cand.append((-1.0 - o[:, i]) / d[:, i])
    c = torch.stack(cand, 1)
    keep = (c > t_start[:, None]) & (c < t_end[:, None])
    c = torch.sort(torch.where(keep, c, t_end[:, None].expand_as(c)), dim=1).values
    brk = torch.cat([t_start[:, None], c, t_end[:, None]], 1)
    ta, tb = brk[:, :-1], brk[:, 1:]
    tm = ta + (tb - ta) * 0.5
    xm = o[:, None, :] + tm[..., None] * d[:, None, :]
    am = xm.abs()
    mm = torch.maximum(torch.maximum(am[..., 0], am[..., 1]), am[..., 2])
    a = torch.where(am[..., 0] == mm, 0, torch.where(am[..., 1] == mm, 1, 2))[..., None]
    xa = torch.gather(xm, 2, a)[..., 0]
    sg = torch.where(xa > 0, 1.0, -1.0).to(o.dtype)
    p = o[:, None, :] + ta[..., None] * d[:, None, :]
    ma = sg * torch.gather(p, 2, a)[..., 0]
    b = sg * torch.gather(d[:, None, :].expand_as(p), 2, a)[..., 0]
    e = d[:, None, :] * ma[..., None] - p * b[..., None]
    # float32 sqrt, correctly rounded (torch's CPU float32 sqrt is not, measured): in
    # float64, then rounded once to float32, which is exact for sqrt.
    K2 = e[..., 0] * e[..., 0] + e[..., 1] * e[..., 1] + e[..., 2] * e[..., 2] + b * b
    K = torch.sqrt(K2.double()).to(o.dtype)
    inner = mm <= 1.0
    one, zero = torch.ones_like(ma), torch.zeros_like(ma)
    A = torch.where(inner, one, ma * ma)
    B = torch.where(inner, zero, ma * b)
    K = torch.where(inner, one, K)
    tau = tb - ta
    length = K * tau / (A + B * tau)
    cum = [torch.zeros_like(t_start)]
    for q in range(LATTICE_BREAKS - 1):
        cum.append(cum[-1] + length[:, q])
    return brk, torch.stack(cum, 1), A, B, K


def lattice_t(table, sigma: torch.Tensor) -> torch.Tensor:
    """``S^-1(sigma)`` per ray (``space.lattice_t``)."""
    brk, cum, A, B, K = table
    j = (cum[:, 1:LATTICE_BREAKS - 1] <= sigma[:, None]).sum(1)[:, None]
    pick = lambda x: torch.gather(x, 1, j)[:, 0]   # noqa: E731
    t_b = torch.gather(brk, 1, j + 1)[:, 0]
    r = sigma - pick(cum)
    den = pick(K) - pick(B) * r
    t = torch.minimum(pick(brk) + pick(A) * r / den, t_b)
    return torch.where(den > 0, t, t_b)


def ray_box(origins: torch.Tensor, dirs: torch.Tensor, extent: float = 1.0):
    """Entry and exit distances of (N, 3) rays with [-extent, extent]^3 (``space.ray_box``).

    Returns:
        t_in, t_out: (N,) float32; t_in > t_out when the ray misses.
    """
    inv = 1.0 / dirs
    t0 = (-extent - origins) * inv
    t1 = (extent - origins) * inv
    lo, hi = torch.fmin(t0, t1), torch.fmax(t0, t1)
    t_in = torch.fmax(torch.fmax(lo[:, 0], lo[:, 1]), lo[:, 2])
    t_out = torch.fmin(torch.fmin(hi[:, 0], hi[:, 1]), hi[:, 2])
    return t_in, t_out


def to_grid(points: torch.Tensor, extent: float, unbounded: bool) -> torch.Tensor:
    """Grid coordinates u in [0, 1]^3 of (..., 3) world points (``space.to_grid``)."""
    c = contract(points) if unbounded else points
    return (c + extent) / (2.0 * extent)


def cell_index(u: torch.Tensor, res: int) -> torch.Tensor:
    """(..., 3) int64 cell of grid coordinates u at resolution ``res``, clamped."""
    return torch.clamp(torch.floor(u * float(res)), 0, res - 1).to(torch.int64)


def hash_corner(ix: torch.Tensor, iy: torch.Tensor, iz: torch.Tensor, T: int) -> torch.Tensor:
    """Instant-NGP hash into [0, T) (``encoding.hash_corner``), T a power of two <= 2^32.

    int64 products keep the low 32 bits of the uint32 products, which is all the mask keeps
    (negative corners wrap like the uint32 cast in numpy).
    """
    h = (ix * HASH_PRIMES[0]) ^ (iy * HASH_PRIMES[1]) ^ (iz * HASH_PRIMES[2])
    return h & (T - 1)


def sh4(dirs: torch.Tensor) -> torch.Tensor:
    """(N, 16) degree-4 real SH of (N, 3) unit directions (``encoding.sh4``)."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    xy, xz, yz = x * y, x * z, y * z
    x2, y2, z2 = x * x, y * y, z * z
    out = [
        torch.full_like(x, SH_C[0]),
        -SH_C[1] * y,
        SH_C[1] * z,
        -SH_C[1] * x,
        SH_C[2] * xy,
        -SH_C[2] * yz,
        SH_C[3] * z2 - SH_C[4],
        -SH_C[2] * xz,
        SH_C[5] * x2 - SH_C[5] * y2,
        SH_C[6] * y * (-3.0 * x2 + y2),
        SH_C[7] * xy * z,
        SH_C[8] * y * (1.0 - 5.0 * z2),
        SH_C[9] * z * (5.0 * z2 - 3.0),
        SH_C[8] * x * (1.0 - 5.0 * z2),
        SH_C[10] * z * (x2 - y2),
        SH_C[6] * x * (-x2 + 3.0 * y2),
    ]
    return torch.stack(out, dim=-1)


def trilinear_corners(p: torch.Tensor, base: torch.Tensor | None = None):
    """Corners and weights of trilinear interpolation at lattice coordinates ``p``.

    Args:
        p: (N, 3) float32 coordinates in lattice units (``u * R``).
        base: (N, 3) int64 lower corner; default ``floor(p)`` (pass the clamped cell for
            the coarse grid, docs/ngprt.md "Coarse").
    Returns:
        corners: (N, 8, 3) int64 corner coordinates (x slowest).
        weights: (N, 8) float32, weight of corner ``+1`` along an axis is ``p - base``.
    """
    if base is None:
        base = torch.floor(p).to(torch.int64)
    w = p - base.to(p.dtype)
    off = corner_offsets(p.device)
    corners = base[:, None, :] + off[None]
    wsel = torch.where(off[None].bool(), w[:, None, :], 1.0 - w[:, None, :])
    return corners, wsel[..., 0] * wsel[..., 1] * wsel[..., 2]


# -- the step lattice and packed compositing (docs/ngprt.md "Step lattice", "The march") --

def lattice_samples(origins: torch.Tensor, dirs: torch.Tensor, occupancy: torch.Tensor,
                    s: float, near: float, far: float, extent: float, unbounded: bool):
    """The lattice points of each ray that fall in occupied cells (docs/ngprt.md "Step
    lattice"): ``t_k = k * s`` (bounded) or ``S^-1(k * s)`` (unbounded, S the contracted
    arc length from ``near``, :func:`lattice_table`).

    Args:
        origins, dirs: (R, 3) float32 rays (unit directions).
        occupancy: (L_C, L_C, L_C) bool grid; a point is kept when its cell is True.
        s: lattice step (``gamma * s0``), world (bounded) or contracted (unbounded) units.
        near, far, extent, unbounded: from the ModelConfig.
    Returns:
        ray_ids: (M,) int64, non-decreasing; samples of a ray are in marching order.
        k: (M,) int64 lattice index.
        t: (M,) float32 distance along the ray; delta: (M,) float32 interval length
            (docs/ngprt.md "Step lattice": the last unbounded one ends at ``far``).
        u: (M, 3) float32 grid coordinates.
    """
    dev, R = origins.device, occupancy.shape[0]
    s_t = torch.tensor(s, dtype=torch.float32, device=dev)
    if unbounded:
        t_start = torch.full_like(origins[:, 0], near)
        t_end = torch.full_like(origins[:, 0], far)
        table = lattice_table(origins, dirs, t_start, t_end)
        g_end = table[1][:, LATTICE_BREAKS - 1]
        k0 = torch.zeros_like(g_end)
    else:
        t_in, t_end = ray_box(origins, dirs, extent)
        t_start = torch.clamp(t_in, min=near)
        g_end = t_end
        k0 = torch.ceil(t_start / s_t)
    n = torch.clamp(torch.ceil(g_end / s_t) - k0 + 1, min=0)
    n = torch.nan_to_num(n, nan=0.0).to(torch.int64)
    k0 = torch.nan_to_num(k0, nan=0.0).to(torch.int64)
    ray_ids = torch.repeat_interleave(torch.arange(len(origins), device=dev), n)
    first = torch.cumsum(n, 0) - n
    k = k0[ray_ids] + torch.arange(len(ray_ids), device=dev) - first[ray_ids]
    g = k.to(torch.float32) * s_t
    keep = g < g_end[ray_ids]
    ray_ids, k, g = ray_ids[keep], k[keep], g[keep]
    t = lattice_t(tuple(x[ray_ids] for x in table), g) if unbounded else g
    u = to_grid(origins[ray_ids] + t[:, None] * dirs[ray_ids], extent, unbounded)
    cell = cell_index(u, R)
    keep = occupancy[cell[:, 0], cell[:, 1], cell[:, 2]]
    ray_ids, k, t, u = ray_ids[keep], k[keep], t[keep], u[keep]
    g_next = (k + 1).to(torch.float32) * s_t
    if unbounded:   # the last interval ends at the ray's end
        end = g_end[ray_ids]
        t_next = lattice_t(tuple(x[ray_ids] for x in table), torch.minimum(g_next, end))
        t_next = torch.where(g_next < end, t_next, t_end[ray_ids])
    else:
        t_next = g_next
    delta = t_next - t
    return ray_ids, k, t, delta, u


MAX_OPTICAL_DEPTH = 1e4      # exp(-1e4) underflows to 0 in float64


def _segment_exclusive_cumsum(x: torch.Tensor, ray_ids: torch.Tensor, n_rays: int):
    """Per-ray exclusive cumulative sum of packed values x (M,) (float64 accumulation)."""
    cs = torch.cumsum(x.double(), 0)
    excl = cs - x.double()
    counts = torch.bincount(ray_ids, minlength=n_rays)
    first = torch.cumsum(counts, 0) - counts
    return excl - excl[first[ray_ids]]


def composite_weights(sigma: torch.Tensor, delta: torch.Tensor, ray_ids: torch.Tensor,
                      n_rays: int, t_stop: float | None = None, return_T: bool = False):
    """Volume-rendering weights ``w_i = T_i * alpha_i`` of packed samples (M,).

    ``alpha = 1 - exp(-sigma * delta)``; ``T_i = prod_{j<i} (1 - alpha_j)`` within the ray.
    With ``t_stop`` a sample counts only while ``T_i >= t_stop`` (the renderer's early stop).
    With ``return_T`` also returns the transmittance ``T_i`` (M,) in front of each sample.
    The optical depth ``sigma * delta`` is capped at :data:`MAX_OPTICAL_DEPTH`, where
    ``exp(-tau)`` is 0 in float64 already: the same weights and gradients (to the float64
    rounding of the batch's running sum), where one infinite depth (a density that
    overflows float32) would make that sum ``inf - inf`` and every later ray NaN.
    """
    tau = torch.clamp(sigma * delta, max=MAX_OPTICAL_DEPTH)
    T = torch.exp(-_segment_exclusive_cumsum(tau, ray_ids, n_rays)).to(sigma.dtype)
    w = T * (1.0 - torch.exp(-tau))
    if t_stop is not None:
        w = torch.where(T >= t_stop, w, torch.zeros_like(w))
    return (w, T) if return_T else w


def accumulate(values: torch.Tensor, ray_ids: torch.Tensor, n_rays: int) -> torch.Tensor:
    """Per-ray sums of packed values (M, ...) -> (n_rays, ...)."""
    out = torch.zeros((n_rays,) + values.shape[1:], dtype=values.dtype, device=values.device)
    return out.index_add_(0, ray_ids, values)


def distortion_intervals(k: torch.Tensor, t: torch.Tensor, delta: torch.Tensor, s: float,
                         unbounded: bool):
    """(lo, hi) (M,) of each sample's interval in the distortion loss's normalised distance:
    the lattice's ``[k*s, (k+1)*s]`` when bounded; when unbounded mip-NeRF 360's warp of
    the camera distance, ``g(t) = t`` for t <= 1 and ``2 - 1/t`` beyond, of
    ``[t, t + delta]`` (the lattice's contracted arc length would weigh far intervals ~10x
    more and keep the training occupancy from pruning)."""
    if not unbounded:
        lo = k.to(t.dtype) * s
        return lo, lo + s

    def g(x):
        return torch.where(x <= 1.0, x, 2.0 - 1.0 / torch.clamp(x, min=1.0))

    return g(t), g(t + delta)


def distortion_loss(w: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor,
                    ray_ids: torch.Tensor, n_rays: int) -> torch.Tensor:
    """Mip-NeRF 360 distortion loss (S2.2, Eq. S2) per ray (n_rays,) of packed samples with
    weights w and intervals [lo, hi] (M,) (:func:`distortion_intervals`), samples of a ray
    in marching order."""
    m = 0.5 * (lo + hi)
    W = _segment_exclusive_cumsum(w, ray_ids, n_rays).to(w.dtype)
    S = _segment_exclusive_cumsum(w * m, ray_ids, n_rays).to(w.dtype)
    per_sample = 2.0 * w * (m * W - S) + (hi - lo) / 3.0 * w * w
    return accumulate(per_sample, ray_ids, n_rays)


# -- multi-level grid lookups (fused gather; the main training cost on CPU) --

class _WeightedGather(torch.autograd.Function):
    """``out[n] = sum_j w[n, j] * table[idx[n, j]]``; gradient for the table only (sample
    positions are not optimised). Forward is one fused ``embedding_bag``; the backward
    scatters with ``bincount`` on CPU (several times faster there than ``index_add_``)."""

    @staticmethod
    def forward(ctx, table, idx, w):
        ctx.save_for_backward(idx, w)
        ctx.shape = table.shape
        return torch.nn.functional.embedding_bag(idx, table, per_sample_weights=w, mode="sum")

    @staticmethod
    def backward(ctx, g):
        idx, w = ctx.saved_tensors
        n_rows, n_feat = ctx.shape
        flat = idx.reshape(-1)
        if g.device.type == "cpu":
            # One contiguous (N * J,) weight vector per feature: the broadcast (N, J, F)
            # product and its strided columns took twice as long (auxiliary NGP, F = 4).
            grad = torch.stack([torch.bincount(flat, (w * g[:, c, None]).reshape(-1),
                                               minlength=n_rows)
                                for c in range(n_feat)], 1).to(g.dtype)
        else:
            gw = (w[..., None] * g[:, None, :]).reshape(-1, n_feat)
            grad = torch.zeros(ctx.shape, dtype=g.dtype, device=g.device).index_add_(0, flat, gw)
        return grad, None, None


def corner_gather(values: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(N, C) ``sum_j w[n, j] * values[idx[n, j]]`` by indexing (differentiable in
    ``values``): the coarse channels' trilinear sum over the L_C corners (idx (N, 8) into
    the batch's unique corners, values (M, C))."""
    return (values[idx] * w[..., None]).sum(1)


def weighted_gather(table: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(N, F) ``sum_j w[n, j] * table[idx[n, j]]`` for a (rows, F) table, idx (N, J) int64
    and w (N, J); differentiable in ``table`` only (also NDRF's per-vertex features)."""
    return _WeightedGather.apply(table, idx, w)


def _level_indices(base: torch.Tensor, res, T: int, dense: bool,
                   corners: int = 2) -> torch.Tensor:
    """(N, lev, corners^3) table rows of the corners ``base + c`` (c in {0, .., corners-1}^3)
    of a group of levels: the 8 of a cell, or with ``corners=1`` the vertex ``base`` itself.

    Built per axis at (N, lev, corners) and combined by broadcasting, so only a few passes
    touch the full (N, lev, corners^3) size (these passes dominate the training time on CPU).
    """
    c = base[..., None] + torch.arange(corners, device=base.device)  # (N, lev, 3, corners)
    if dense:
        r1 = torch.tensor([int(r) + 1 for r in res], device=base.device)[None, :, None]
        c = torch.minimum(torch.clamp(c, min=0), r1[..., None] - 1)
        x, y, z = c[:, :, 0] * (r1 * r1), c[:, :, 1] * r1, c[:, :, 2]
        return (x[..., :, None, None] + y[..., None, :, None] + z[..., None, None, :]).flatten(2)
    x, y, z = c[:, :, 0] * HASH_PRIMES[0], c[:, :, 1] * HASH_PRIMES[1], c[:, :, 2] * HASH_PRIMES[2]
    h = x[..., :, None, None] ^ y[..., None, :, None] ^ z[..., None, None, :]
    return (h & (T - 1)).flatten(2)


def _group_indices(base: torch.Tensor, resolutions, dense, T: int, corners: int) -> torch.Tensor:
    """(N, lev, corners^3) rows of :func:`_level_indices` for levels whose dense ones come
    first, offset by ``level * T`` within the group."""
    n_dense, n_lev = sum(dense), len(dense)
    parts = []
    if n_dense:
        parts.append(_level_indices(base[:, :n_dense], resolutions[:n_dense], T, True, corners))
    if n_dense < n_lev:
        parts.append(_level_indices(base[:, n_dense:], resolutions[n_dense:], T, False, corners))
    idx = torch.cat(parts, 1) if len(parts) > 1 else parts[0]
    return idx + (torch.arange(n_lev, device=base.device) * T)[None, :, None]


def grid_lookup(tables: torch.Tensor, u: torch.Tensor, resolutions, dense=None,
                on_vertices: int = 0) -> torch.Tensor:
    """Trilinear multi-level grid features at grid coordinates u.

    Args:
        tables: (n_levels, T, F) float32 parameters.
        u: (N, 3) float32 grid coordinates in [0, 1].
        resolutions: n_levels ints; level l samples at ``p = u * R_l``, corners ``floor(p)
            + c`` hashed with :func:`hash_corner` into [0, T) (docs/ngprt.md "Fine level").
        dense: optional n_levels bools; a True level (they must come first) indexes its
            ``(R+1)^3`` corners densely instead (auxiliary NGP levels that fit the table).
        on_vertices: the number of last levels at whose vertices every u lies (``u * R_l``
            integral, as the auxiliary NGP's L_C level at the L_C corners): each reads the
            one row of its vertex, where trilinear reads 8 of which 7 weigh exactly 0
            (the same features and gradients, an eighth of the gather).
    Returns:
        (N, n_levels, F) features.
    """
    n_lev, T, n_feat = tables.shape
    dense = list(dense) if dense is not None else [False] * n_lev
    n_dense = sum(dense)
    if dense != [True] * n_dense + [False] * (n_lev - n_dense):
        raise ValueError(f"grid_lookup: dense levels must come first, got {dense}")
    if not 0 <= on_vertices <= n_lev:
        raise ValueError(f"grid_lookup: on_vertices={on_vertices} must be in [0, {n_lev}]")
    res = torch.tensor([float(r) for r in resolutions], device=u.device)
    p = u[:, None, :] * res[None, :, None]                          # (N, lev, 3)
    base = torch.floor(p)
    w1 = p - base
    base = base.to(torch.int64)
    flat = tables.reshape(n_lev * T, n_feat)
    m = n_lev - on_vertices                                         # trilinear levels
    out = []
    if m:
        idx = _group_indices(base[:, :m], resolutions[:m], dense[:m], T, 2)
        wx = torch.stack([1.0 - w1[:, :m], w1[:, :m]], -1)          # (N, m, 3, 2)
        w = (wx[:, :, 0, :, None, None] * wx[:, :, 1, None, :, None]
             * wx[:, :, 2, None, None, :]).flatten(2)                # (N, m, 8)
        out.append(weighted_gather(flat, idx.reshape(-1, 8), w.reshape(-1, 8))
                   .reshape(len(u), m, n_feat))
    if on_vertices:
        idx = _group_indices(base[:, m:], resolutions[m:], dense[m:], T, 1) + m * T
        ones = torch.ones(idx.numel(), 1, dtype=u.dtype, device=u.device)
        out.append(weighted_gather(flat, idx.reshape(-1, 1), ones)
                   .reshape(len(u), on_vertices, n_feat))
    return torch.cat(out, 1) if len(out) > 1 else out[0]


def aux_values(tables: torch.Tensor, u: torch.Tensor, resolutions, dense, on_vertices: int,
               w0: torch.Tensor, b0: torch.Tensor, w1: torch.Tensor,
               b1: torch.Tensor) -> torch.Tensor:
    """(N, O) auxiliary NGP outputs at grid coordinates u (N, 3): :func:`grid_lookup` of
    tables (n_levels, T, F) flattened to x (N, n_levels * F), then
    ``relu(x @ w0 + b0) @ w1 + b1`` (w0 (I, H), w1 (H, O))."""
    f = grid_lookup(tables, u, resolutions, dense, on_vertices)
    h = torch.relu(f.reshape(len(u), f.shape[1] * f.shape[2]) @ w0 + b0)
    return h @ w1 + b1


def coarse_corners(u: torch.Tensor, res: int):
    """The batch's L_C-cell corners, each once (docs/ngprt.md "Coarse").

    Args:
        u: (N, 3) float32 grid coordinates; the cell is clamped to the grid.
        res: the coarse resolution L_C.
    Returns:
        corners: (M, 3) int64 unique corners, in increasing flat id (x slowest).
        idx: (N, 8) int64 row of each sample's corner in ``corners``.
        w: (N, 8) float32 trilinear weights (:func:`trilinear_corners`).
    """
    R1 = res + 1
    c, w = trilinear_corners(u * float(res), cell_index(u, res))
    ids = (c[..., 0] * R1 + c[..., 1]) * R1 + c[..., 2]
    uniq, inv = torch.unique(ids.reshape(-1), return_inverse=True)
    corners = torch.stack([uniq // (R1 * R1), (uniq // R1) % R1, uniq % R1], -1)
    return corners, inv.reshape(ids.shape), w
