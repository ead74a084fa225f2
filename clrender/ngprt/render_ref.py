"""Numpy reference renderer of a baked NGP-RT model: the readable specification.

Follows docs/ngprt.md operation for operation in float32, in the order of the doc's
formulas, so that ``kernels/ngprt_march.cl`` (FP contraction off, correctly rounded
division and sqrt) reproduces positions, cells and lattice indices bit for bit; values
that go through ``exp`` may differ by a few ulps. All active rays march in lockstep, one
lattice point per iteration, with masks.

Examples:
    >>> from clrender.ngprt.random_model import random_baked_model
    >>> out = render_reference(random_baked_model(config), camera)
    >>> out["rgb"].shape, out["n_march"].sum()

References: NGP-RT (Hu et al., ECCV 2024) Eq. 5-9, §4.3, S2.3, S2.5.
"""
from __future__ import annotations

import numpy as np

from ..camera import generate_rays
from .config import N_MIP, T_STOP
from .encoding import hash_corner, sh4
from .marches import (READ_KINDS, check_march, feature_reads, g_read, g_reads_counted,
                      occupancy_reads, paper_g_step_bounded, paper_g_step_unbounded)
from .space import (cell_index, lattice_end, lattice_jumps, lattice_rows, lattice_s, lattice_t,
                    lattice_table, ray_box, to_grid)

F32 = np.float32
# Corner c = 0..7 of a cell is offset ((c >> 2) & 1, (c >> 1) & 1, c & 1): x slowest.
_CORNERS = np.array([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)], np.int64)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (F32(1.0) / (F32(1.0) + np.exp(-x))).astype(F32)


def _lattice_g(k: np.ndarray, s: F32) -> np.ndarray:
    """Lattice distance ``(float)k * s`` of lattice index k: world t (bounded) or
    contracted arc length from the ray's start (unbounded)."""
    return k.astype(F32) * s


def lattice_point(cfg, table, k: np.ndarray, s: F32) -> np.ndarray:
    """Distance t of lattice point k: ``k * s`` (bounded) or ``S^-1(k * s)`` (unbounded,
    ``table`` the rays' :func:`space.lattice_table` rows)."""
    g = _lattice_g(k, s)
    return lattice_t(table, g) if cfg.scene == "unbounded" else g


def _point_u(cfg, o: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(M, 3) grid coordinates of ``o + t * d``."""
    return to_grid(o + t[:, None] * d, cfg.extent, cfg.scene == "unbounded")


def _cells(u: np.ndarray, res: np.ndarray) -> np.ndarray:
    """:func:`space.cell_index` with a per-row resolution ``res`` (M,) int."""
    r = res.astype(F32)[:, None]
    return np.clip(np.floor(u * r), 0, (res - 1)[:, None]).astype(np.int64)


# ---- ray range --------------------------------------------------------------------

def ray_range(cfg, o: np.ndarray, d: np.ndarray):
    """The ray's distance range ``[t_start, t_end]`` (world units).

    Bounded: ``[max(near, t_in), t_out]`` of the ray/[-1, 1]^3 box; unbounded: [near, far].
    Returns:
        t_start, t_end: (N,) float32; hit: (N,) bool, False where the range is empty
        (a missed box, or NaN from an axis-parallel ray outside it): no lattice point.
    """
    unbounded = cfg.scene == "unbounded"
    if unbounded:
        t_start = np.full(len(o), F32(cfg.near))
        t_end = np.full(len(o), F32(cfg.far))
    else:
        t_in, t_out = ray_box(o, d, 1.0)
        t_start, t_end = np.fmax(F32(cfg.near), t_in), t_out
    hit = t_start <= t_end                      # False also for NaN
    return t_start, t_end, hit


# ---- occupancy --------------------------------------------------------------------

def exit_level(model, u: np.ndarray) -> np.ndarray:
    """(M,) int: the first level, coarse (4) to fine (0), whose cell at u is empty; -1
    when u is occupied at every level (a sample)."""
    mip, R = model.occupancy_mip(), model.config.occ_res
    out = np.full(len(u), -1, np.int64)
    undecided = np.ones(len(u), bool)
    for lev in range(N_MIP - 1, -1, -1):
        i = cell_index(u[undecided], R >> lev)
        empty = mip[lev][i[:, 0], i[:, 1], i[:, 2]] == 0
        rows = np.flatnonzero(undecided)[empty]
        out[rows] = lev
        undecided[rows] = False
    return out


def g_distance(model, u: np.ndarray, exit_lev: np.ndarray, use_G: bool) -> np.ndarray:
    """(M,) int G value at u, read only when the exit level is coarser than G; else 0."""
    cfg = model.config
    g = np.zeros(len(u), np.int64)
    read = g_read(cfg, exit_lev, use_G)
    i = cell_index(u[read], cfg.G_res)
    g[read] = model.arrays["G"][i[:, 0], i[:, 1], i[:, 2]]
    return g


# ---- empty-space skipping ---------------------------------------------------------

# Skip constants (docs/ngprt.md "skip"), shared with kernels/ngprt_skip.h as -D defines
# (render_cl.kernel_defines). A closed-form exit is backed off by K_BACKOFF steps before
# rounding up to a lattice index (the float exit distance may overshoot); a skip's index
# is clamped K_PAST_END steps past the ray's end (any k past it will do, ints stay small).
K_BACKOFF, K_PAST_END = F32(1e-3), F32(2.0)
# Unbounded margins: a box is shrunk by 1/64 of the grid cell it stands for on every
# face; the outer regions of the contraction are left 2^-10 * |x|_inf before the planes
# |x_b| = |x_a| where it switches axis (a jump); the cube inscribed in G's ball has
# half-side 0.57735 (< 1/sqrt(3)) of the ball's radius.
BOX_MARGIN, REGION_SCALE, CUBE = F32(1 / 64), F32(1 - 2**-10), F32(0.57735)


def _in_cell(cfg, o, d, k, s, res, cell) -> np.ndarray:
    """(M,) bool: lattice point k of each ray lies in ``cell`` at resolution ``res``
    (bounded scenes: ``t_k = k * s``), computed exactly as the march places it."""
    return np.all(_cells(_point_u(cfg, o, d, _lattice_g(k, s)), res) == cell, axis=1)


def _first_outside(cfg, o, d, k_in, k_out, s, res, cell) -> np.ndarray:
    """Bisection for the first lattice point outside ``cell``: ``k_in`` is inside it,
    ``k_out > k_in`` outside. Per axis the float32 cell of ``t_k = k * s`` is monotone
    in k (every operation is), so the points inside form one run of k."""
    lo, hi = k_in.copy(), k_out.copy()
    open_ = np.flatnonzero(hi - lo > 1)
    while len(open_):
        mid = lo[open_] + (hi[open_] - lo[open_]) // 2
        inside = _in_cell(cfg, o[open_], d[open_], mid, s, res[open_], cell[open_])
        lo[open_[inside]] = mid[inside]
        hi[open_[~inside]] = mid[~inside]
        open_ = open_[hi[open_] - lo[open_] > 1]
    return hi


def skip_bounded(model, k, t, o, d, u, exit_lev, g, s, g_end) -> np.ndarray:
    """Next lattice index (> k) after an empty point, closed form (Eq. 9).

    ``k_O`` is the first lattice point at or past the exit of the empty mip cell, ``k_G``
    the last one within G's empty ball of radius ``r = 2 g / G_res`` (world units).
    ``k_O`` comes from the float32 exit distance, which is off by up to ~1e-7 / |d_a|
    world units (many steps for a tiny direction component ``d_a``), so it is checked:
    if lattice point ``k_O - 1`` is not in the empty cell any more, ``k_O`` becomes the
    first point outside the cell, found by bisection (docs/ngprt.md "skip").
    """
    cfg = model.config
    res = cfg.occ_res >> exit_lev
    h = F32(2.0) / res.astype(F32)
    cell = _cells(u, res)
    lo = cell.astype(F32) * h[:, None] - F32(1.0)
    hi = lo + h[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_a = (np.where(d > 0, hi, lo) - o) / d
    t_exit = np.where(d != 0, t_a, F32(np.inf)).min(axis=1)
    lim = g_end / s + K_PAST_END
    k_next = np.maximum(k + 1, np.ceil(np.minimum(t_exit / s - K_BACKOFF, lim)).astype(np.int64))
    check = np.flatnonzero(k_next - 1 > k)
    out = check[~_in_cell(cfg, o[check], d[check], k_next[check] - 1, s, res[check],
                          cell[check])]
    if len(out):
        k_next[out] = _first_outside(cfg, o[out], d[out], k[out], k_next[out] - 1, s,
                                     res[out], cell[out])
    r = F32(2.0) * g.astype(F32) / F32(cfg.G_res)
    k_G = np.floor(np.minimum((t + r) / s, lim)).astype(np.int64)
    return np.where(g > 0, np.maximum(k_next, k_G), k_next)


def _box_exit(o, d, t, lo, hi) -> np.ndarray:
    """(M,) the largest t' >= t such that the ray stays in the box [lo, hi] (contracted
    space, (M, 3)) over [t, t'] within the projective region of the contraction it is in
    at t; t where the point at t is outside. Each face is a linear constraint
    f + beta (t' - t) >= 0 there: c = x inside |x|_inf <= 1; outside, with a the axis of
    |x|_inf = sigma x_a = m, c_b = x_b / m and sigma c_a = 2 - 1/m."""
    p = o + t[:, None] * d
    ap = np.abs(p)
    m = ap.max(axis=1)
    rows = np.arange(len(p))
    a = np.where(ap[:, 0] == m, 0, np.where(ap[:, 1] == m, 1, 2))
    sg = np.where(p[rows, a] > 0, F32(1.0), F32(-1.0))
    ms, dm = sg * p[rows, a], sg * d[rows, a]
    inner = m <= F32(1.0)
    dt = np.full(len(p), np.inf, F32)
    inside = np.ones(len(p), bool)

    def constraint(f, beta, where):
        nonlocal dt, inside
        inside &= ~where | (f >= 0)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            dt = np.where(where & (beta < 0), np.minimum(dt, f / -beta), dt)

    for b in range(3):
        pb, db, lb, hb = p[:, b], d[:, b], lo[:, b], hi[:, b]
        constraint(pb - lb, db, inner)
        constraint(hb - pb, -db, inner)
        constraint(F32(1.0) - pb, -db, inner)
        constraint(F32(1.0) + pb, db, inner)
        other = ~inner & (a != b)
        constraint(ms * REGION_SCALE - pb, dm * REGION_SCALE - db, other)
        constraint(ms * REGION_SCALE + pb, dm * REGION_SCALE + db, other)
        constraint(pb - lb * ms, db - lb * dm, other)
        constraint(hb * ms - pb, hb * dm - db, other)
    outer = ~inner
    constraint(ms - F32(1.0), dm, outer)
    lo_a = np.where(sg > 0, lo[rows, a], -hi[rows, a])
    hi_a = np.where(sg > 0, hi[rows, a], -lo[rows, a])
    with np.errstate(divide="ignore"):
        constraint(ms - F32(1.0) / (F32(2.0) - lo_a), dm, outer & (lo_a < 2))
        constraint(F32(1.0) / (F32(2.0) - hi_a) - ms, -dm, outer & (hi_a < 2))
    inside &= ~(outer & (lo_a >= 2))
    return np.where(inside, t + dt, t)


def skip_unbounded(model, k, o, d, u, exit_lev, g, s, g_end, table) -> np.ndarray:
    """Next lattice index (> k) after an empty point (no memory reads): the first lattice
    point outside both the empty mip cell and, when G was read, the ball of radius
    ``g / G_res`` (u units) about u, as a walk point by point would find it, but
    jumping in closed form over the points in the shrunk cell or the shrunk cube
    inscribed in the ball (:func:`_box_exit`); the points after a jump are tested one by
    one until one is outside both or inside a shrunk box again. ``table``: the rays'
    :func:`space.lattice_table` rows; ``g_end`` their ``S(t_end)``."""
    cfg = model.config
    res = cfg.occ_res >> exit_lev
    cell = _cells(u, res)
    radius = g.astype(F32) / F32(cfg.G_res)        # u is in [0, 1]^3
    size = F32(4.0) / res.astype(F32)[:, None]     # a cell, in contracted units
    lo = cell.astype(F32) * size - F32(2.0) + size * BOX_MARGIN
    hi = (cell + 1).astype(F32) * size - F32(2.0) - size * BOX_MARGIN
    half = F32(4.0) * radius * CUBE - F32(4.0) / F32(cfg.G_res) * BOX_MARGIN
    cube = (g > 0) & (half > 0)
    c0 = u * F32(4.0) - F32(2.0)
    lim = g_end / s + K_PAST_END
    k = k.copy()
    walking = np.ones(len(k), bool)
    while walking.any():
        w = np.flatnonzero(walking)
        tw = lattice_rows(table, w)
        t = lattice_t(tw, _lattice_g(k[w], s))
        T = _box_exit(o[w], d[w], t, lo[w], hi[w])
        Tc = _box_exit(o[w], d[w], t, c0[w] - half[w, None], c0[w] + half[w, None])
        T = np.where(cube[w], np.maximum(T, Tc), T)
        x = np.minimum(lattice_s(tw, T) / s - K_BACKOFF, lim[w])
        k[w] = np.maximum(k[w] + 1, np.ceil(x).astype(np.int64))
        uk = _point_u(cfg, o[w], d[w], lattice_t(tw, _lattice_g(k[w], s)))
        same = np.all(_cells(uk, res[w]) == cell[w], axis=1)
        du = uk - u[w]
        dist = np.sqrt(du[:, 0] * du[:, 0] + du[:, 1] * du[:, 1] + du[:, 2] * du[:, 2])
        stay = same | ((g[w] > 0) & (dist < radius[w]))
        walking[w] = stay & (_lattice_g(k[w], s) < g_end[w])
    return k


# ---- features at a sample (Eq. 6-8) -------------------------------------------------

def _trilinear_weights(w: np.ndarray) -> list[np.ndarray]:
    """Weights of the 8 corners (x slowest), each ``wx * wy * wz`` in that order."""
    out = []
    for cx, cy, cz in _CORNERS:
        wx = w[:, 0] if cx else F32(1.0) - w[:, 0]
        wy = w[:, 1] if cy else F32(1.0) - w[:, 1]
        wz = w[:, 2] if cz else F32(1.0) - w[:, 2]
        out.append(wx * wy * wz)
    return out


def coarse_features(model, u: np.ndarray) -> np.ndarray:
    """(M, 8 + n_attention) trilinear coarse channels at u from the sparse coarse grid."""
    cfg, a = model.config, model.arrays
    B = cfg.coarse_block
    i = cell_index(u, cfg.L_C).astype(np.int64)
    w = u * F32(cfg.L_C) - i.astype(F32)
    bi = i // B
    b = a["coarse_block_index"][bi[:, 0], bi[:, 1], bi[:, 2]]
    r = i - bi * B
    blocks = a["coarse_blocks"]
    f = np.zeros((len(u), cfg.coarse_channels), F32)
    for wc, c in zip(_trilinear_weights(w), _CORNERS):
        j = r + c
        f = f + wc[:, None] * blocks[b, j[:, 0], j[:, 1], j[:, 2]]
    return f


def fine_features(model, u: np.ndarray, l: int) -> np.ndarray:
    """(M, 8) trilinear features of hash level l (resolution L_C * 2^(l+1))."""
    cfg = model.config
    p = u * F32(cfg.L_C << (l + 1))
    i = np.floor(p).astype(np.int64)
    w = p - i.astype(F32)
    table = model.arrays["fine_tables"][l]
    f = np.zeros((len(u), 8), F32)
    for wc, c in zip(_trilinear_weights(w), _CORNERS):
        j = i + c
        f = f + wc[:, None] * table[hash_corner(j[:, 0], j[:, 1], j[:, 2], cfg.T)]
    return f


def fuse(model, fine: list[np.ndarray], attention: np.ndarray) -> np.ndarray:
    """(M, 8) fusion of the fine features ``fine[l]`` (M, 8) by the model's variant.

    ``attention``: (M, n_attention) coarse attention logits (``-v`` variants).
    """
    cfg, a = model.config, model.arrays
    v = cfg.variant
    if v == "mlp":
        x = np.concatenate(fine, axis=1)
        h = np.maximum(x @ a["fusion_w0"] + a["fusion_b0"], F32(0.0))
        return (h @ a["fusion_w1"] + a["fusion_b1"]).astype(F32)
    logits = None
    if v in ("shared-v", "separate-v"):
        logits = attention
    elif v in ("shared-inv", "separate-inv"):
        logits = np.broadcast_to(a["attention_inv"], (len(attention),) + a["attention_inv"].shape)
    out = np.zeros_like(fine[0])
    for l, f in enumerate(fine):
        if v == "sum":
            out = out + f
        elif v.startswith("shared"):
            out = out + _sigmoid(logits[:, l])[:, None] * f
        else:  # Eq. 7-8: omega weighs the density channel, beta the 7 colour channels
            omega, beta = _sigmoid(logits[:, 2 * l]), _sigmoid(logits[:, 2 * l + 1])
            weight = np.concatenate([omega[:, None], np.repeat(beta[:, None], 7, 1)], axis=1)
            out = out + weight * f
    return out


def features(model, u: np.ndarray) -> np.ndarray:
    """(M, 8) features ``coarse(u) + fuse(u)`` (Eq. 6): [sigma logit, diffuse, specular]."""
    coarse = coarse_features(model, u)
    fine = [fine_features(model, u, l) for l in range(model.config.L)]
    return coarse[:, :8] + fuse(model, fine, coarse[:, 8:])


# ---- the march --------------------------------------------------------------------

class _Rays:
    """Per-ray march state (N rays)."""

    def __init__(self, n: int):
        self.k = np.zeros(n, np.int64)
        self.T = np.ones(n, F32)
        self.acc = np.zeros((n, 7), F32)
        self.opacity = np.zeros(n, F32)
        self.depth_acc = np.zeros(n, F32)
        self.n_march = np.zeros(n, np.int32)
        self.n_occ = np.zeros(n, np.int32)
        self.reads = np.zeros((n, len(READ_KINDS)), np.int32)   # marches.READ_KINDS


def next_t(model, k: np.ndarray, s: F32, g_end: np.ndarray, table=None) -> np.ndarray:
    """End ``t_{k+1}`` of the interval of lattice point k (world units).

    Unbounded scenes end the last interval at the ray's far end: ``t_{k+1} =
    S^-1((k+1)*s)`` while ``(k+1)*s < g_end = S(far)``, else ``far`` (``table``: the rays'
    lattice_table rows). Bounded scenes use ``(k+1)*s`` as is (it may pass the box,
    harmlessly).
    """
    g = _lattice_g(k + 1, s)
    if model.config.scene != "unbounded":
        return g
    t = lattice_t(table, np.minimum(g, g_end))
    return np.where(g < g_end, t, F32(model.config.far)).astype(F32)


def composite(model, st: _Rays, rows, u, t, s, g_end, table=None) -> None:
    """Alpha-composite the samples of rays ``rows`` at u (distance t) and step on.

    ``g_end``: (len(rows),) lattice end of those rays; ``table``: their lattice_table
    rows (unbounded)."""
    f = features(model, u)
    k = st.k[rows]
    sigma = np.exp(f[:, 0])
    delta = next_t(model, k, s, g_end, table) - t
    alpha = F32(1.0) - np.exp(-sigma * delta)
    T = st.T[rows]
    w = T * alpha
    st.acc[rows] = st.acc[rows] + w[:, None] * f[:, 1:8]
    st.opacity[rows] = st.opacity[rows] + w
    st.depth_acc[rows] = st.depth_acc[rows] + w * t
    st.T[rows] = T * (F32(1.0) - alpha)
    st.n_occ[rows] += 1
    st.k[rows] = k + 1


def march_reference(model, origins: np.ndarray, dirs: np.ndarray, use_G: bool = True,
                    march: str = "ours") -> dict:
    """March rays through a baked model (docs/ngprt.md "The march, per ray").

    Args:
        model: a :class:`clrender.ngprt.baked.BakedModel`.
        origins, dirs: (N, 3) float32 world-space rays, dirs unit length.
        use_G: skip empty space with the occupancy distance grid G as well as the mip.
        march: ``"ours"`` or ``"paper"`` (:mod:`clrender.ngprt.marches`): what is read at
            a point and, with G, the step (ours: the larger skip; the paper: G's replaces
            the mip's where ``G > 0``).
    Returns:
        acc: (N, 7) float32 composited diffuse rgb (3) and specular (4) features;
        opacity: (N,) float32 in [0, 1]; depth: (N,) float32 world units along the ray
        (0 where opacity is 0); n_march, n_occ: (N,) int32 marching / occupied points;
        reads: (N, 3) int32 global-memory reads per ray (occupancy, G, feature corners:
        :data:`clrender.ngprt.marches.READ_KINDS`).
    """
    check_march(march)
    cfg = model.config
    unbounded = cfg.scene == "unbounded"
    o = np.ascontiguousarray(origins, F32).reshape(-1, 3)
    d = np.ascontiguousarray(dirs, F32).reshape(-1, 3)
    s = F32(model.step)
    t_start, t_end, hit = ray_range(cfg, o, d)
    st = _Rays(len(o))
    table = jumps = None
    if unbounded:       # S from t_start: k0 = 0 (docs/ngprt.md "Step lattice")
        table = lattice_table(o, d, t_start, t_end)
        g_end = lattice_end(table)
        if march == "paper" and use_G:
            jumps = lattice_jumps(o, d, table[0])
    else:
        g_end = t_end
        with np.errstate(invalid="ignore", over="ignore"):
            st.k[hit] = np.ceil(t_start[hit] / s).astype(np.int64)
    active = hit & (_lattice_g(st.k, s) < g_end)
    with np.errstate(over="ignore"):
        while active.any():
            rows = np.flatnonzero(active)
            st.n_march[rows] += 1
            tab = lattice_rows(table, rows) if unbounded else None
            t = lattice_point(cfg, tab, st.k[rows], s)
            u = _point_u(cfg, o[rows], d[rows], t)
            lev = exit_level(model, u)
            occ = lev < 0
            st.reads[rows, 0] += occupancy_reads(march, lev).astype(np.int32)
            if occ.any():
                composite(model, st, rows[occ], u[occ], t[occ], s, g_end[rows[occ]],
                          lattice_rows(tab, occ) if unbounded else None)
                st.reads[rows[occ], 2] += feature_reads(cfg)
            e = ~occ
            if e.any():
                if g_reads_counted(cfg, march):
                    st.reads[rows[e], 1] += g_read(cfg, lev[e], use_G)
                _skip(model, st, march, rows[e], o, d, t[e], u[e], lev[e], use_G, s, g_end,
                      lattice_rows(tab, e) if unbounded else None, jumps)
            active[rows] = (_lattice_g(st.k[rows], s) < g_end[rows]) & (st.T[rows] >= F32(T_STOP))
    with np.errstate(invalid="ignore", divide="ignore"):
        depth = np.where(st.opacity > 0, st.depth_acc / st.opacity, F32(0.0)).astype(F32)
    return {"acc": st.acc, "opacity": st.opacity, "depth": depth,
            "n_march": st.n_march, "n_occ": st.n_occ, "reads": st.reads}


def _skip(model, st: _Rays, march: str, r, o, d, t, u, lev, use_G: bool, s, g_end,
          table=None, jumps=None) -> None:
    """Steps the empty points of rays ``r`` (at distance t, grid u, exit level lev) on:
    ours, the larger of the mip's and G's skips; the paper's, G's step where ``G > 0``
    (Eq. 9, :mod:`clrender.ngprt.marches`), else the mip's. ``table``: the rays' lattice
    rows (unbounded); ``jumps``: every ray's :func:`space.lattice_jumps` (the paper's
    unbounded march with G)."""
    g = g_distance(model, u, lev, use_G)
    mine = np.ones(len(r), bool) if march == "ours" else g == 0
    k = st.k[r].copy()
    if mine.any():
        gm = g[mine] if march == "ours" else np.zeros(int(mine.sum()), np.int64)
        rm, tm = r[mine], lattice_rows(table, mine) if table is not None else None
        if table is not None:
            k[mine] = skip_unbounded(model, k[mine], o[rm], d[rm], u[mine], lev[mine], gm, s,
                                     g_end[rm], tm)
        else:
            k[mine] = skip_bounded(model, k[mine], t[mine], o[rm], d[rm], u[mine], lev[mine],
                                   gm, s, g_end[rm])
    jump = ~mine
    if jump.any():
        if table is not None:
            k[jump] = paper_g_step_unbounded(model.config, k[jump], g[jump], s,
                                             lattice_rows(table, jump), jumps[r[jump]])
        else:
            k[jump] = paper_g_step_bounded(model.config, k[jump], t[jump], g[jump], s,
                                           g_end[r[jump]] / s + K_PAST_END)
    st.k[r] = k


# ---- per pixel (Eq. 5) ------------------------------------------------------------

def deferred_reference(model, acc: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """The deferred MLP: (N, 3) float32 rgb in (0, 1) before background blending.

    Args:
        acc: (N, 7) composited features from :func:`march_reference`.
        dirs: (N, 3) float32 unit view directions.
    """
    a = model.arrays
    acc = np.asarray(acc, F32)
    x = np.concatenate([acc[:, 0:3], acc[:, 3:7], sh4(dirs)], axis=1)
    h1 = np.maximum(x @ a["deferred_w0"] + a["deferred_b0"], F32(0.0))
    h2 = np.maximum(h1 @ a["deferred_w1"] + a["deferred_b1"], F32(0.0))
    return _sigmoid(acc[:, 0:3] + h2 @ a["deferred_w2"] + a["deferred_b2"])


def render_reference(model, camera, background=(1.0, 1.0, 1.0), use_G: bool = True,
                     march: str = "ours") -> dict:
    """Render a camera view with the reference renderer (``march``: see
    :func:`march_reference`).

    Returns:
        rgb: (H, W, 3) float32, blended over ``background``; depth, opacity: (H, W)
        float32; n_march, n_occ: (H, W) int32; reads: (H, W, 3) int32.
    """
    origins, dirs = generate_rays(camera)
    H, W = camera.height, camera.width
    out = march_reference(model, origins.reshape(-1, 3), dirs.reshape(-1, 3), use_G, march)
    rgb = deferred_reference(model, out["acc"], dirs.reshape(-1, 3))
    op = out["opacity"][:, None]
    rgb = rgb * op + np.asarray(background, F32) * (F32(1.0) - op)
    res = {"rgb": rgb.astype(F32).reshape(H, W, 3)}
    for name in ("depth", "opacity", "n_march", "n_occ"):
        res[name] = out[name].reshape(H, W)
    res["reads"] = out["reads"].reshape(H, W, len(READ_KINDS))
    return res
