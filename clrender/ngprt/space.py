"""Scene-space geometry shared by the renderers and training (numpy, float32).

Everything here is written so that ``kernels/ngprt_common.h`` can mirror it operation
for operation: the OpenCL build disables FP contraction and asks for correctly rounded
division and sqrt, so positions, cells and lattice indices agree bit for bit.

* Contraction (unbounded scenes): MERF's piecewise-projective map of R^3 into [-2, 2]^3.
* Grid coordinates: ``u = (c + E) / (2E)`` in [0, 1]^3 with E = ``ModelConfig.extent``.
* Step lattice: samples sit at warped distances ``g_k = k * s`` (k integer, s = gamma*s0)
  where ``g(t) = t`` for bounded scenes and, for unbounded ones, ``g(t) = t`` for t <= 1
  and ``2 - 1/t`` beyond, so the step stays about ``s`` in contracted space.

References: MERF (Reiser et al. 2023) Eq. 7; NGP-RT S2.3.
"""
from __future__ import annotations

import numpy as np

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


def warp(t: np.ndarray, unbounded: bool) -> np.ndarray:
    """Warped distance g(t) (float32); identity for bounded scenes."""
    t = np.asarray(t, F32)
    if not unbounded:
        return t
    return np.where(t <= F32(1.0), t, F32(2.0) - F32(1.0) / np.maximum(t, F32(1.0))).astype(F32)


def unwarp(g: np.ndarray, unbounded: bool) -> np.ndarray:
    """Inverse of :func:`warp`: distance t for warped distance g < 2 (float32)."""
    g = np.asarray(g, F32)
    if not unbounded:
        return g
    return np.where(g <= F32(1.0), g, F32(1.0) / (F32(2.0) - np.maximum(g, F32(1.0)))).astype(F32)


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
