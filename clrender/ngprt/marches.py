"""The marches of Table 4 (docs/ngprt.md "The marches"): what each reads from global
memory at a lattice point, and the paper's step with G (Eq. 9).

* ``march="paper"`` (§4.3, Fig. 3a): the occupancy levels are read coarse to fine until one
  is empty (``N_MIP - exit_lev`` byte reads at an empty point, ``N_MIP`` at a sample); an
  empty point moves to the exit of its level-``exit_lev`` cell. With G (``use_G``, Eq. 9)
  G is read where the exit level is coarser than G, and where ``g > 0`` the step ``v * g``
  *replaces* the occupancy step (:func:`paper_g_step_bounded`,
  :func:`paper_g_step_unbounded`).
* ``march="ours"``: one uint16 exit code a point (``render_cl.exit_codes``: the exit level
  and, pre-gathered, G), the step the larger of the two safe skips.

The numpy reference (``render_ref.march_reference``) and the kernels (``ngprt_march.cl``,
``ngprt_paper.h``) count the reads per ray the same way: ``occupancy`` (mip bytes or exit
codes), ``G`` (G bytes read outside the exit code) and ``features`` (per sample the coarse
block index, 8 coarse corners and 8 corners per fine level; a corner is one gather of
``8 + n_attention`` floats; weights of the fusion and the deferred MLP not counted).

References: NGP-RT (Hu et al., ECCV 2024) §4.3, Eq. 9.
"""
from __future__ import annotations

import numpy as np

from .config import N_MIP

F32 = np.float32
MARCHES = ("ours", "paper")
READ_KINDS = ("occupancy", "G", "features")


def check_march(march: str) -> str:
    if march not in MARCHES:
        raise ValueError(f"march {march!r}: expected one of {', '.join(MARCHES)}")
    return march


def g_in_codes(config) -> bool:
    """Whether ``render_cl.exit_codes`` carries G: when ``occ_res / G_res`` is a power of
    two, the G voxel of a point is its finest cell shifted right (scaling by a power of two
    is exact in float32, as for the mip levels)."""
    ratio = config.occ_res // config.G_res
    return ratio & (ratio - 1) == 0


def feature_reads(config) -> int:
    """Global reads of one sample's features: the coarse block index, 8 coarse corners,
    8 corners per fine level."""
    return 1 + 8 + 8 * config.L


def occupancy_reads(march: str, exit_lev: np.ndarray) -> np.ndarray:
    """(M,) int reads of the occupancy at points of exit level ``exit_lev`` (-1: a sample):
    the paper reads levels ``N_MIP - 1 .. exit_lev`` (all ``N_MIP`` at a sample), ours one
    exit code."""
    if march == "ours":
        return np.ones(len(exit_lev), np.int64)
    return np.where(exit_lev < 0, N_MIP, N_MIP - exit_lev)


def g_read(config, exit_lev: np.ndarray, use_G: bool) -> np.ndarray:
    """(M,) bool: the march reads G at empty points of exit level ``exit_lev`` (paper
    §4.3: only where that level is coarser than G)."""
    return np.full(len(exit_lev), bool(use_G)) & ((config.occ_res >> exit_lev) < config.G_res)


def g_reads_counted(config, march: str) -> bool:
    """Whether a G read is a read of its own: always for the paper's march; for ours only
    where the exit code does not carry G (:func:`g_in_codes`)."""
    return march == "paper" or not g_in_codes(config)


def paper_g_step_bounded(config, k, t, g, s, lim) -> np.ndarray:
    """Eq. 9, bounded: the next lattice index after an empty point at ``t`` (world units,
    lattice index ``k``) whose G value ``g`` > 0: the last lattice point within
    ``v * g`` (``v = 2 / G_res`` world units, a G voxel), at least ``k + 1``; ``lim``
    (lattice units) clamps it past the ray's end as every skip."""
    r = F32(2.0) * g.astype(F32) / F32(config.G_res)
    k_G = np.floor(np.minimum((t + r) / s, lim)).astype(np.int64)
    return np.maximum(k + 1, k_G)


def paper_g_step_unbounded(config, k, g, s, table, jumps) -> np.ndarray:
    """Eq. 9, unbounded, in contracted arc length: ``k + floor(4 g / G_res / s)`` lattice
    steps (``4 g / G_res``: G's distance in contracted units, ``c = 4 u - 2``), at least
    ``k + 1`` and at most the first lattice point at or past the next jump of the ray's
    contracted path (``jumps``: the rays' :func:`space.lattice_jumps` rows; ``table``:
    their ``space.lattice_table`` rows). Between jumps the contracted path is continuous
    and straight piece by piece, so its arc length bounds the distance from the point, and
    every point passed lies in G's empty ball; across a jump arc length bounds nothing. A
    lattice point at or just past a jump (the first at or after it) steps to ``k + 1``: it
    may lie on the jump itself, where the contraction takes either side's value, so its
    ball says nothing about the points after it (docs/ngprt.md "The paper's step with G")."""
    cum = table[1]
    sigma = k.astype(F32) * s
    prev = (k - 1).astype(F32) * s
    n = np.floor(F32(4.0) * g.astype(F32) / F32(config.G_res) / s).astype(np.int64)
    cut = np.where(jumps, cum, F32(np.inf))
    first = ((cut > prev[:, None]) & (cut <= sigma[:, None])).any(axis=1)
    end = np.where(cut > sigma[:, None], cut, F32(np.inf)).min(axis=1)
    ahead = np.isfinite(end)
    end = np.where(ahead, end, sigma)
    k_p = np.ceil(end / s).astype(np.int64)
    k_p = np.where((k_p - 1).astype(F32) * s >= end, k_p - 1, k_p)
    step = np.where(ahead, np.minimum(k + n, k_p), k + n)
    return np.where(first, k + 1, np.maximum(k + 1, step))
