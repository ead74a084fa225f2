"""The baked NGP-RT file: a versioned ``.npz`` of plain arrays plus a JSON manifest.

A baked model is everything the renderers need and nothing else: the sparse coarse grid,
the fine hash tables, the occupancy mip, the occupancy distance grid ``G`` and the small
MLPs (docs/ngprt.md "Baked file"). Files are read with ``allow_pickle=False`` and
validated (names, shapes, dtypes, finite values, index ranges, occupancy consistency)
before anything reaches a kernel.

Examples:
    >>> model = load_baked("lego.npz")           # raises BakedFormatError when invalid
    >>> model.step, model.config.L_C
    >>> save_baked(model, "copy.npz")

References: NGP-RT (Hu et al., ECCV 2024) §4.3, S2.5.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import bakedfile
from ..bakedfile import F32, I32, U8, BakedFormatError, check_arrays, fail
from .config import (DEFERRED_HIDDEN, FEATURES, FUSION_HIDDEN, MAX_LATTICE_POINTS, N_MIP, SH_DIM,
                     ModelConfig)

FORMAT = "clrender-ngprt"
# Version 3 may hold occupancy finer than the coarse grid (config ``occupancy_res``, the
# paper's grids); version 2 records G's metric (``G_metric``); version 1 files hold the
# box metric's G. Older files read as they were written (occupancy at L_C).
VERSION = 3
READ_VERSIONS = (1, 2, 3)
# What G measures (docs/ngprt.md "The occupancy distance grid G"): ``box``, from a voxel's
# closest point to the nearest occupied voxel (no point within G of any point of the voxel
# is occupied: the march takes the samples it takes without G); ``centre``, the paper's,
# from the voxel's centre to the nearest occupied voxel's centre (longer steps that may
# pass an occupied sample).
G_METRICS = ("box", "centre")
_CHUNK = 1 << 18          # coarse corners evaluated per call of a corner-value callable


@dataclass
class BakedModel:
    """A baked NGP-RT model.

    Attributes:
        config: the model's shape.
        gamma: step scaler; the lattice step is ``s = gamma * config.s0`` (S2.3).
        arrays: exactly the arrays of :func:`expected_arrays` (docs/ngprt.md "Baked file").
        G_metric: what ``G`` measures, one of :data:`G_METRICS`.
    """

    config: ModelConfig
    gamma: float
    arrays: dict
    G_metric: str = "box"
    method = "ngprt"          # its entry-point name (clrender.methods, pyproject.toml)

    @property
    def step(self) -> float:
        """The float32 lattice step ``s = gamma * s0`` (as a Python float)."""
        return float(np.float32(self.gamma * self.config.s0))

    @property
    def n_blocks(self) -> int:
        return int(np.shape(self.arrays["coarse_blocks"])[0])

    def occupancy_mip(self) -> list[np.ndarray]:
        """``[occupancy_0 .. occupancy_4]``, uint8 grids of resolution ``occ_res >> lev``."""
        return [self.arrays[f"occupancy_{lev}"] for lev in range(N_MIP)]


def expected_arrays(config: ModelConfig, n_blocks: int) -> dict:
    """``{name: (shape, dtype)}`` of every array of a baked model with ``n_blocks`` blocks."""
    c = config
    nb, h, n_in = c.L_C // c.coarse_block, DEFERRED_HIDDEN, 7 + SH_DIM
    out = {
        "coarse_block_index": ((nb, nb, nb), I32),
        "coarse_blocks": ((n_blocks,) + (c.coarse_block + 1,) * 3 + (c.coarse_channels,), F32),
        "fine_tables": ((c.L, c.T, FEATURES), F32),
    }
    for lev in range(N_MIP):
        out[f"occupancy_{lev}"] = ((c.occ_res >> lev,) * 3, U8)
    out["G"] = ((c.G_res,) * 3, U8)
    for name, shape in (("deferred_w0", (n_in, h)), ("deferred_b0", (h,)),
                        ("deferred_w1", (h, h)), ("deferred_b1", (h,)),
                        ("deferred_w2", (h, 3)), ("deferred_b2", (3,))):
        out[name] = (shape, F32)
    if c.variant == "mlp":
        for name, shape in (("fusion_w0", (FEATURES * c.L, FUSION_HIDDEN)),
                            ("fusion_b0", (FUSION_HIDDEN,)),
                            ("fusion_w1", (FUSION_HIDDEN, FEATURES)), ("fusion_b1", (FEATURES,))):
            out[name] = (shape, F32)
    if c.n_inv_attention:
        out["attention_inv"] = ((c.n_inv_attention,), F32)
    return out


# ---- building the occupancy structures --------------------------------------------

def build_mip(occupancy_0: np.ndarray) -> list[np.ndarray]:
    """The 5-level occupancy mip: ``occupancy_{lev+1}`` is the 2x max-pool of level lev.

    Args:
        occupancy_0: (R, R, R) 0/1 (any dtype; nonzero is occupied), R = occ_res.
    Returns:
        [occupancy_0 .. occupancy_4], uint8 0/1 of resolutions R >> lev.
    """
    level = (np.asarray(occupancy_0) != 0).astype(np.uint8)
    levels = [level]
    for _ in range(N_MIP - 1):
        r = level.shape[0] // 2
        level = level.reshape(r, 2, r, 2, r, 2).max(axis=(1, 3, 5))
        levels.append(level)
    return levels


def upsampled(grid: np.ndarray, factor: int) -> np.ndarray:
    """(R, R, R) ``grid`` with each cell repeated ``factor`` times along each axis (the
    inverse of the pooling: a coarse grid at a finer grid's cells)."""
    for axis in range(3):
        grid = np.repeat(grid, factor, axis=axis)
    return grid


def _pool(grid: np.ndarray, res: int) -> np.ndarray:
    f = grid.shape[0] // res
    return grid.reshape(res, f, res, f, res, f).max(axis=(1, 3, 5))


def build_distance_grid(occupancy_0: np.ndarray, G_res: int, metric: str = "box") -> np.ndarray:
    """The occupancy distance grid G (paper §4.3), in G-voxel units, rounded down.

    A G-voxel is occupied when any ``occupancy_0`` cell inside it is. ``metric``:

    * ``box`` (exact and conservative): the distance from the *closest point* of a voxel
      to the nearest occupied voxel (box to box): for integer offset ``D`` between the
      voxels ``|max(|D| - 1, 0)|``, the centre EDT to the occupied set dilated by one voxel
      (3x3x3). From any point of a voxel every point closer than ``G / G_res`` in u
      (``2 G / G_res`` world units when bounded) is empty.
    * ``centre`` (the paper's wording): the distance from the voxel's centre to the
      nearest occupied voxel's centre, a plain EDT; up to about two voxels more than
      ``box``, so a step may pass an occupied point.

    Capped at 255; 255 everywhere when all is empty.

    Args:
        occupancy_0: (R, R, R) 0/1, R = occ_res; G_res must divide R.
    Returns:
        G: (G_res, G_res, G_res) uint8, in G-voxel units.
    """
    # Imported here: loading and rendering a baked file need numpy and pyopencl alone.
    from scipy.ndimage import binary_dilation, distance_transform_edt

    if metric not in G_METRICS:
        raise ValueError(f"G metric {metric!r}: expected one of {', '.join(G_METRICS)}")
    occ = _pool((np.asarray(occupancy_0) != 0).astype(np.uint8), G_res).astype(bool)
    if not occ.any():
        return np.full((G_res,) * 3, 255, np.uint8)
    if metric == "box":
        occ = binary_dilation(occ, structure=np.ones((3, 3, 3), bool))
    return np.minimum(np.floor(distance_transform_edt(~occ)), 255).astype(np.uint8)


def with_G_metric(model: "BakedModel", metric: str) -> "BakedModel":
    """``model`` with G of ``metric`` rebuilt from its finest occupancy (``model`` itself
    where it has that metric already)."""
    if metric == model.G_metric:
        return model
    G = build_distance_grid(model.arrays["occupancy_0"], model.config.G_res, metric)
    return BakedModel(model.config, model.gamma, {**model.arrays, "G": G}, metric)


def sparse_coarse_grid(corner_values, occupancy_0: np.ndarray, B: int,
                       channels: int | None = None):
    """The sparse coarse grid: blocks of B^3 cells holding (B+1)^3 corner values.

    Only blocks containing an occupied ``occupancy_0`` cell are stored.

    Args:
        corner_values: dense corner values, (L_C+1, L_C+1, L_C+1, C) or ((L_C+1)^3, C),
            or a callable ``f(corners)`` mapping (M, 3) int64 corner indices to (M, C)
            values, called only for corners of present blocks (in chunks).
        occupancy_0: (L_C, L_C, L_C) 0/1.
        B: cells per block side (``ModelConfig.coarse_block``).
        channels: C, needed only for a callable when no block is present (else the
            callable is asked for zero corners).
    Returns:
        block_index: (L_C/B,)*3 int32, -1 for absent blocks, else 0..n_blocks-1 in C order.
        blocks: (n_blocks, B+1, B+1, B+1, C) float32; corner ``i + c`` of the block of
            cell ``i`` is ``blocks[block, i % B + c]``.
    """
    occ = np.asarray(occupancy_0) != 0
    L_C = occ.shape[0]
    nb = L_C // B
    present = _pool(occ.astype(np.uint8), nb).astype(bool)
    block_index = np.full((nb,) * 3, -1, np.int32)
    ids = np.argwhere(present)                       # C order
    block_index[tuple(ids.T)] = np.arange(len(ids), dtype=np.int32)
    local = np.stack(np.meshgrid(*(np.arange(B + 1),) * 3, indexing="ij"), -1).reshape(-1, 3)
    corners = (ids[:, None, :] * B + local[None]).reshape(-1, 3).astype(np.int64)
    if callable(corner_values):
        if len(corners) == 0 and channels is not None:
            values = np.zeros((0, channels), np.float32)
        else:
            parts = [np.asarray(corner_values(corners[a:a + _CHUNK]), np.float32)
                     for a in range(0, max(len(corners), 1), _CHUNK)]
            values = np.concatenate(parts).reshape(len(corners), -1)
    else:
        dense = np.asarray(corner_values, np.float32)
        dense = dense.reshape((L_C + 1,) * 3 + (-1,))
        values = dense[corners[:, 0], corners[:, 1], corners[:, 2]]
    blocks = values.reshape((len(ids),) + (B + 1,) * 3 + (values.shape[-1],))
    return block_index, np.ascontiguousarray(blocks, np.float32)


# ---- validation -------------------------------------------------------------------

def _check_arrays(model: BakedModel, where: str) -> None:
    arrays, cfg = model.arrays, model.config
    blocks = arrays.get("coarse_blocks") if isinstance(arrays, dict) else None
    n_blocks = int(np.shape(blocks)[0]) if blocks is not None and np.ndim(blocks) == 5 else 0
    check_arrays(arrays, expected_arrays(cfg, n_blocks), where, f" (variant {cfg.variant!r})")


def _check_blocks(model: BakedModel, where: str):
    index, n_blocks = model.arrays["coarse_block_index"], model.n_blocks
    if index.size and (index.min() < -1 or index.max() >= n_blocks):
        fail(where, f"coarse_block_index has values in [{index.min()}, {index.max()}], "
                     f"expected -1 or a block in [0, {n_blocks})")
    used = np.sort(index[index >= 0])
    if len(used) != n_blocks or np.any(used != np.arange(n_blocks)):
        fail(where, f"coarse_block_index must reference each of the {n_blocks} blocks "
                     f"exactly once ({len(used)} references, {len(np.unique(used))} distinct)")


def _check_occupancy(model: BakedModel, where: str):
    cfg, mip = model.config, model.occupancy_mip()
    for lev, grid in enumerate(mip):
        if grid.size and grid.max() > 1:
            fail(where, f"occupancy_{lev} has values other than 0 and 1 (max {grid.max()})")
    for lev, (want, grid) in enumerate(zip(build_mip(mip[0]), mip)):
        if not np.array_equal(want, grid):
            fail(where, f"occupancy_{lev} is not the 2x max-pool of occupancy_{lev - 1} "
                         f"({int(np.count_nonzero(want != grid))} cells differ)")
    nb = cfg.L_C // cfg.coarse_block
    covered = _pool(mip[0], nb).astype(bool)
    absent = covered & (model.arrays["coarse_block_index"] < 0)
    if absent.any():
        fail(where, f"{int(absent.sum())} coarse blocks hold occupied occupancy_0 cells "
                     f"but are absent (coarse_block_index == -1)")
    if model.G_metric not in G_METRICS:
        fail(where, f"G_metric {model.G_metric!r}: expected one of {', '.join(G_METRICS)}")
    want_G = build_distance_grid(mip[0], cfg.G_res, model.G_metric)
    over = model.arrays["G"] > want_G
    if over.any():
        fail(where, f"G exceeds its {model.G_metric} metric's bound: {int(over.sum())} "
                     f"voxels exceed the distance to the nearest occupied voxel (max excess "
                     f"{int((model.arrays['G'].astype(int) - want_G).max())})")


def _check_gamma(model: BakedModel, where: str) -> None:
    """gamma a finite number > 0 whose float32 step ``s = gamma * s0`` puts at most
    MAX_LATTICE_POINTS lattice points on a ray (docs/ngprt.md "Step lattice")."""
    cfg, gamma = model.config, model.gamma
    if isinstance(gamma, bool) or not isinstance(gamma, numbers.Real):
        fail(where, f"gamma {gamma!r} is not a number")
    try:
        value = float(gamma)
    except OverflowError:
        fail(where, f"gamma is an integer of {len(str(abs(gamma)))} digits, beyond a float")
    if not (math.isfinite(value) and value > 0):
        fail(where, f"gamma must be finite and > 0, got {gamma!r}")
    step = value * cfg.s0
    if step > float(np.finfo(np.float32).max):
        fail(where, f"gamma={gamma!r} is too large: the step gamma * s0 = {step:.3g} "
                    f"overflows float32")
    s = float(np.float32(step))
    points = cfg.max_ray_length / s if s > 0 else math.inf
    if points > MAX_LATTICE_POINTS:
        fail(where, f"gamma={gamma!r} is too small: the step s = gamma * s0 = {s:.3g} puts "
                    f"up to {points:.3g} lattice points on a ray, more than "
                    f"{MAX_LATTICE_POINTS} (need gamma >= {cfg.min_gamma:.3g} at "
                    f"s0={cfg.s0:.3g}, {cfg.scene})")


def validate(model: BakedModel, where: str = "model") -> None:
    """Check a baked model against docs/ngprt.md; raises :class:`BakedFormatError`.

    Checks: gamma a finite number > 0 with at most ``MAX_LATTICE_POINTS`` lattice points
    per ray, names, shapes and dtypes of the arrays, finite floats, block indices in
    [-1, n_blocks) with every block referenced once, occupancy 0/1 and a consistent mip,
    occupied cells in present blocks, G within its metric's bound (never above G
    recomputed with ``G_metric``).
    (The config checked its own fields when it was made.) ``where`` (e.g. the file
    name) starts every message.
    """
    if not isinstance(model.config, ModelConfig):
        fail(where, f"config is a {type(model.config).__name__}, expected ModelConfig")
    _check_gamma(model, where)
    _check_arrays(model, where)
    _check_blocks(model, where)
    _check_occupancy(model, where)


# ---- files ------------------------------------------------------------------------

def save_baked(model: BakedModel, path, trained_on: dict | None = None) -> Path:
    """Validate ``model`` and write it to ``path`` atomically (temp file + rename).

    ``trained_on`` (``{"data": path, "downscale": N}``) goes into the manifest as is, for
    evaluation to reuse (:func:`clrender.bakedfile.trained_downscale`).

    Returns:
        the path written.
    """
    validate(model, str(path))
    manifest = {"format": FORMAT, "version": VERSION, "config": model.config.to_dict(),
                "gamma": float(model.gamma), "G_metric": model.G_metric}
    if trained_on is not None:
        manifest["trained_on"] = trained_on
    return bakedfile.save(path, manifest, model.arrays)


def load_baked(path) -> BakedModel:
    """Load and validate a baked model; raises :class:`BakedFormatError` naming the file."""
    where = str(path)
    manifest, arrays = bakedfile.read(path, FORMAT, READ_VERSIONS, keys=("config", "gamma"))
    if manifest["version"] >= 2 and "G_metric" not in manifest:
        fail(where, f"manifest has no 'G_metric' (version {manifest['version']} records it)")
    try:
        config = ModelConfig.from_dict(manifest["config"], where=f"{where}: config")
    except (TypeError, ValueError) as e:
        raise BakedFormatError(f"{where}: bad config: {e}") from e
    model = BakedModel(config, manifest["gamma"], arrays, manifest.get("G_metric", "box"))
    validate(model, where)
    model.gamma = float(model.gamma)
    return model
