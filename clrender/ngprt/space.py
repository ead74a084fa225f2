"""Scene-space geometry shared by the renderers and training (numpy, float32).

Everything here is written so that the NGP-RT kernels (``kernels/ngprt_space.h``,
``ngprt_lattice.h``) can mirror it operation for operation: the OpenCL build disables FP
contraction and asks for correctly rounded division and sqrt, so positions, cells and
lattice indices agree bit for bit.

* Contraction (unbounded scenes): MERF's piecewise-projective map of R^3 into [-2, 2]^3.
* Grid coordinates: ``u = (c + E) / (2E)`` in [0, 1]^3 with E = ``ModelConfig.extent``.
* Step lattice: bounded samples sit at ``t_k = k * s`` (k integer, s = gamma*s0);
  unbounded ones at ``t_k = S^-1(k * s)``, S the contracted arc length from the ray's
  start (:func:`lattice_table`), so the step is ``s`` in contracted space.

References: MERF (Reiser et al. 2023) Eq. 7; NGP-RT S2.3.
"""
from __future__ import annotations

import numpy as np

from .config import LATTICE_BREAKS

F32 = np.float32


def contract(x: np.ndarray) -> np.ndarray:
    """MERF contraction of (..., 3) float32 points into [-2, 2]^3."""
    x = np.asarray(x, F32)
    ax = np.abs(x)
    m = np.maximum(np.maximum(ax[..., 0], ax[..., 1]), ax[..., 2])[..., None]
    m_safe = np.maximum(m, F32(1.0))
    s = x / m_safe
    scaled = s * (F32(2.0) - F32(1.0) / m_safe)
    return np.where(m <= F32(1.0), x, np.where(ax == m, scaled, s)).astype(F32)


def lattice_table(o: np.ndarray, d: np.ndarray, t_start: np.ndarray, t_end: np.ndarray):
    """Per-ray pieces of the contracted arc length ``S(t)`` from ``t_start`` (unbounded).

    Within one projective region of the contraction (the unit cube, or where axis ``a``
    holds ``|x|_inf = sg * x_a = m > 1``) the contracted point moves on a straight segment
    and ``|c(t_a + tau) - c(t_a)| = K tau / (A + B tau)`` with ``p = o + t_a d``,
    ``ma = sg p_a``, ``b = sg d_a``, ``A = ma ma``, ``B = ma b``,
    ``K = sqrt(e_0^2 + e_1^2 + e_2^2 + b^2)``, ``e_j = d_j ma - p_j b`` (``A = K = 1``,
    ``B = 0`` inside the cube). Breakpoints: ``t_start``, then the 12 candidates
    ``(o_j - o_i) / (d_i - d_j)``, ``-(o_i + o_j) / (d_i + d_j)`` (pairs (0,1), (0,2),
    (1,2)) and ``(1 - o_i) / d_i``, ``(-1 - o_i) / d_i``, each replaced by ``t_end``
    unless ``t_start < c < t_end``, sorted; then ``t_end``. A piece's region is that of
    its midpoint ``t_a + (t_b - t_a) * 0.5`` (axis: x before y before z on ties).

    Args:
        o, d: (N, 3) float32 rays; t_start, t_end: (N,) float32, finite.
    Returns:
        (brk (N, 14), cum (N, 14), A, B, K (N, 13)) float32: breakpoints, ``S`` at them.
    """
    o, d = np.asarray(o, F32), np.asarray(d, F32)
    t_start, t_end = np.asarray(t_start, F32), np.asarray(t_end, F32)
    cand = []
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, j in ((0, 1), (0, 2), (1, 2)):
            cand.append((o[:, j] - o[:, i]) / (d[:, i] - d[:, j]))
            cand.append(-(o[:, i] + o[:, j]) / (d[:, i] + d[:, j]))
        for i in range(3):
            cand.append((F32(1.0) - o[:, i]) / d[:, i])
            cand.append((F32(-1.0) - o[:, i]) / d[:, i])
    c = np.stack(cand, axis=1)
    keep = (c > t_start[:, None]) & (c < t_end[:, None])
    c = np.sort(np.where(keep, c, t_end[:, None]), axis=1)
    brk = np.concatenate([t_start[:, None], c, t_end[:, None]], axis=1).astype(F32)
    ta, tb = brk[:, :-1], brk[:, 1:]
    mm, a, sg = _piece_regions(o, d, brk)
    p = o[:, None, :] + ta[..., None] * d[:, None, :]
    ma = sg * np.take_along_axis(p, a[..., None], axis=2)[..., 0]
    b = sg * np.take_along_axis(np.broadcast_to(d[:, None, :], p.shape), a[..., None],
                                axis=2)[..., 0]
    e = d[:, None, :] * ma[..., None] - p * b[..., None]
    K = np.sqrt(e[..., 0] * e[..., 0] + e[..., 1] * e[..., 1] + e[..., 2] * e[..., 2] + b * b)
    inner = mm <= F32(1.0)
    A = np.where(inner, F32(1.0), ma * ma).astype(F32)
    B = np.where(inner, F32(0.0), ma * b).astype(F32)
    K = np.where(inner, F32(1.0), K).astype(F32)
    tau = tb - ta
    length = K * tau / (A + B * tau)
    cum = np.zeros_like(brk)
    for q in range(LATTICE_BREAKS - 1):
        cum[:, q + 1] = cum[:, q] + length[:, q]
    return brk, cum, A, B, K


def _piece_regions(o: np.ndarray, d: np.ndarray, brk: np.ndarray):
    """The contraction's region of each piece between consecutive breakpoints ``brk``
    (N, LATTICE_BREAKS), from its midpoint ``x = o + (t_a + (t_b - t_a) * 0.5) d``:
    ``mm = |x|_inf`` (inside the unit cube where ``mm <= 1``), the axis ``a`` holding it
    (x before y before z on ties) and the sign ``sg`` of ``x_a``; each (N, 13)."""
    ta, tb = brk[:, :-1], brk[:, 1:]
    tm = ta + (tb - ta) * F32(0.5)
    xm = o[:, None, :] + tm[..., None] * d[:, None, :]
    am = np.abs(xm)
    mm = np.maximum(np.maximum(am[..., 0], am[..., 1]), am[..., 2])
    a = np.where(am[..., 0] == mm, 0, np.where(am[..., 1] == mm, 1, 2))
    xa = np.take_along_axis(xm, a[..., None], axis=2)[..., 0]
    sg = np.where(xa > 0, F32(1.0), F32(-1.0))
    return mm, a, sg


def lattice_jumps(o: np.ndarray, d: np.ndarray, brk: np.ndarray) -> np.ndarray:
    """Where each ray's contracted path jumps (docs/ngprt.md "The paper's step with G").

    The contraction is continuous except across ``|x_a| = |x_b| > 1``, between two outer
    regions of different axis: breakpoint ``q`` (1 .. 12) of a :func:`lattice_table` is a jump where the pieces on
    both sides lie in outer regions (``|x|_inf > 1`` at their midpoints) of a different
    axis or sign. Across any other breakpoint the contracted path is continuous.

    Args:
        o, d: (N, 3) float32 rays; brk: (N, LATTICE_BREAKS) float32 breakpoints of their
            :func:`lattice_table`.
    Returns:
        (N, LATTICE_BREAKS) bool, False at the ray's start and end.
    """
    o, d = np.asarray(o, F32), np.asarray(d, F32)
    mm, a, sg = _piece_regions(o, d, np.asarray(brk, F32))
    region = np.where(mm <= F32(1.0), -1, 2 * a + (sg > 0))
    before, after = region[:, :-1], region[:, 1:]
    jumps = np.zeros(brk.shape, bool)
    jumps[:, 1:-1] = (before >= 0) & (after >= 0) & (before != after)
    return jumps


def lattice_end(table) -> np.ndarray:
    """(N,) contracted length ``S(t_end)`` of the rays of a :func:`lattice_table`."""
    return table[1][:, LATTICE_BREAKS - 1]


def lattice_t(table, sigma: np.ndarray) -> np.ndarray:
    """``S^-1(sigma)``: distance t of contracted length sigma (N,) along each ray, for
    ``0 <= sigma < S(t_end)``: piece ``j`` = the last with ``cum_j <= sigma``,
    ``r = sigma - cum_j``, ``den = K_j - B_j r``,
    ``t = min(brk_j + A_j r / den, brk_{j+1})`` (``brk_{j+1}`` where ``den <= 0``)."""
    brk, cum, A, B, K = table
    sigma = np.asarray(sigma, F32)
    j = (cum[:, 1:LATTICE_BREAKS - 1] <= sigma[:, None]).sum(axis=1)
    rows = np.arange(len(sigma))
    r = sigma - cum[rows, j]
    den = K[rows, j] - B[rows, j] * r
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = np.minimum(brk[rows, j] + A[rows, j] * r / den, brk[rows, j + 1])
    return np.where(den > 0, t, brk[rows, j + 1]).astype(F32)


def lattice_s(table, t: np.ndarray) -> np.ndarray:
    """``S(t)``: contracted length along each ray at distance t (N,) in
    ``[t_start, inf]`` (clamped to ``t_end``): piece ``j`` = the last with
    ``brk_j <= t``, ``tau = t - brk_j``, ``S = cum_j + K_j tau / (A_j + B_j tau)``."""
    brk, cum, A, B, K = table
    t = np.minimum(np.asarray(t, F32), brk[:, LATTICE_BREAKS - 1])
    j = (brk[:, 1:LATTICE_BREAKS - 1] <= t[:, None]).sum(axis=1)
    rows = np.arange(len(t))
    tau = t - brk[rows, j]
    return (cum[rows, j] + K[rows, j] * tau / (A[rows, j] + B[rows, j] * tau)).astype(F32)


def lattice_rows(table, rows):
    """The rows ``rows`` of a :func:`lattice_table`."""
    return tuple(x[rows] for x in table)


def ray_box(origins: np.ndarray, dirs: np.ndarray, extent: float = 1.0):
    """Entry and exit distances of rays with the cube [-extent, extent]^3.

    Args:
        origins, dirs: (N, 3) float32.
    Returns:
        t_in, t_out: (N,) float32; t_in > t_out when the ray misses.
    """
    o, d = np.asarray(origins, F32), np.asarray(dirs, F32)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = F32(1.0) / d
        t0 = (F32(-extent) - o) * inv
        t1 = (F32(extent) - o) * inv
    lo, hi = np.fmin(t0, t1), np.fmax(t0, t1)
    t_in = np.fmax(np.fmax(lo[:, 0], lo[:, 1]), lo[:, 2])
    t_out = np.fmin(np.fmin(hi[:, 0], hi[:, 1]), hi[:, 2])
    return t_in.astype(F32), t_out.astype(F32)


def to_grid(points: np.ndarray, extent: float, unbounded: bool) -> np.ndarray:
    """Grid coordinates u in [0, 1]^3 of (..., 3) world points (float32)."""
    c = contract(points) if unbounded else np.asarray(points, F32)
    return ((c + F32(extent)) / F32(2.0 * extent)).astype(F32)


def cell_index(u: np.ndarray, res: int) -> np.ndarray:
    """(..., 3) int32 cell of grid coordinates u at resolution ``res``, clamped to the grid."""
    return np.clip(np.floor(u * F32(res)), 0, res - 1).astype(np.int32)
