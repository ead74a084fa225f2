"""Baking a trained NGP-RT run into the renderer's file (docs/ngprt.md "Baked file").

The rendering occupancy is the training occupancy after visibility culling (cells whose
samples carry weight on some training ray) and a 1-cell dilation, as MERF; the coarse
grid holds the auxiliary NGP at the corners of those cells; the fine tables and MLP
weights are copied as they are. With the paper's grids (``grids="paper"``) the occupancy
mip and G are built finer than L_C, from the trained density inside those cells
(:func:`visible_cells` at both resolutions; docs/ngprt.md "Grids").

Examples:
    >>> bake_run("/tmp/run_b", "/tmp/model_b.npz")
    >>> baked = bake_state(model, occ.binary, gamma, train_set)   # mid-training, in memory

References: NGP-RT (Hu et al., ECCV 2024) §4.1, S2.5; MERF (Reiser et al. 2023) §5.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from .config import with_grids
from .model import NGPRT, render_rays
from .train import RaySampler, load_run

WEIGHT_THRESHOLD = 1e-3     # a cell is visible when one of its samples has more weight
CULL_RAYS = 1 << 18         # training rays rendered for visibility culling (at most)
# Dilation of the paper's finer occupancy, in its cells (docs/ngprt.md "Grids": the
# culling rays mark it more sparsely than the paper's, so one cell loses samples).
FINE_DILATION = 2


@torch.no_grad()
def visible_cells(model: NGPRT, occupancy: torch.Tensor, gamma: float, dataset,
                  n_rays: int = CULL_RAYS, threshold: float = WEIGHT_THRESHOLD,
                  dilation=1, chunk: int = 8192, seed: int = 0,
                  resolutions: tuple[int, ...] | None = None) -> list[np.ndarray]:
    """Rendering occupancy: cells holding a sample of weight > ``threshold`` on one of
    ``n_rays`` training rays (all pixels when there are fewer), dilated by ``dilation``
    cells (an int, or one per resolution), at each of ``resolutions`` (default
    ``(L_C,)``) from one pass over the rays.

    At L_C a sample marks its own cell (the paper's and MERF's culling). A sample stands
    for the ray's interval ``t +- delta / 2``: at a finer resolution, whose cells the
    lattice step may span (3.5 cells at 512^3 for the `cpu` step), the interval is marked
    at ``ceil(step / cell)`` points spread over it, so the cells a visible stretch of a
    ray crosses are marked, not every third one.

    Args:
        occupancy: (L_C,)*3 bool training occupancy.
        dataset: the training Dataset (images, cameras, background).
    Returns:
        [(R, R, R) uint8 0/1 for R in resolutions].
    """
    cfg, dev = model.cfg, occupancy.device
    resolutions = (cfg.L_C,) if resolutions is None else tuple(resolutions)
    sampler = RaySampler(dataset, dev)
    n_pix = sampler.N * sampler.H * sampler.W
    gen = torch.Generator(device=dev).manual_seed(seed)
    pix = torch.randperm(n_pix, device=dev, generator=gen)[:n_rays] if n_pix > n_rays \
        else torch.arange(n_pix, device=dev)
    bg = torch.as_tensor(np.asarray(dataset.background), dtype=torch.float32, device=dev)
    step_u = float(gamma) * cfg.s0 / (2.0 * cfg.extent)       # lattice step, grid units
    points = [1 if R <= cfg.L_C else math.ceil(step_u * R) for R in resolutions]
    visible = [torch.zeros(R ** 3, dtype=torch.bool, device=dev) for R in resolutions]
    for i in range(0, len(pix), chunk):
        o, d = sampler.rays(pix[i:i + chunk])
        r = render_rays(model, o, d, occupancy, gamma, bg)
        keep = r["weights"] > threshold
        for R, n, grid in zip(resolutions, points, visible):
            for j in range(n):
                u = _sample_u(r, o, d, cfg, (j + 0.5) / n - 0.5)[keep]
                c = torch.clamp(torch.floor(u * R), 0, R - 1).to(torch.int64)
                grid[(c[:, 0] * R + c[:, 1]) * R + c[:, 2]] = True
    dilations = (dilation,) * len(resolutions) if isinstance(dilation, int) else dilation
    return [dilated(g.reshape((R,) * 3).cpu().numpy(), r).astype(np.uint8)
            for R, g, r in zip(resolutions, visible, dilations)]


def _sample_u(r: dict, o, d, cfg, offset: float = 0.0) -> torch.Tensor:
    """Grid coordinates of each sample moved ``offset`` times its interval along its ray."""
    from . import torch_ops as ops

    ids = r["ray_ids"]
    t = r["t"] if offset == 0.0 else r["t"] + offset * r["delta"]
    x = o[ids] + t[:, None] * d[ids]
    return ops.to_grid(x, cfg.extent, cfg.scene == "unbounded")


def dilated(a: np.ndarray, r: int) -> np.ndarray:
    """Boolean (R,)*3 ``a`` dilated by ``r`` cells: the max over the (2r+1)^3 cube, one
    axis at a time."""
    a = np.asarray(a, bool)
    for axis in range(3):
        out = a.copy()
        for shift in range(1, r + 1):
            lo, hi = [slice(None)] * 3, [slice(None)] * 3
            lo[axis], hi[axis] = slice(shift, None), slice(None, -shift)
            out[tuple(lo)] |= a[tuple(hi)]
            out[tuple(hi)] |= a[tuple(lo)]
        a = out
    return a


@torch.no_grad()
def corner_values(model: NGPRT, corners: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
    """(M, 8 + n_attention) float32 coarse channels at integer L_C corners (M, 3)."""
    dev = next(model.parameters()).device
    corners = np.asarray(corners).reshape(-1, 3)
    out = [model.corner_values(torch.as_tensor(corners[i:i + chunk], device=dev)).cpu().numpy()
           for i in range(0, len(corners), chunk)]
    return np.concatenate(out).astype(np.float32) if out else \
        np.zeros((0, model.cfg.coarse_channels), np.float32)


def _weights(model: NGPRT) -> dict:
    names = ["deferred_w0", "deferred_b0", "deferred_w1", "deferred_b1", "deferred_w2",
             "deferred_b2", "fine_tables"]
    if model.cfg.variant == "mlp":
        names += ["fusion_w0", "fusion_b0", "fusion_w1", "fusion_b1"]
    if model.cfg.n_inv_attention:
        names += ["attention_inv"]
    return {n: getattr(model, n).detach().cpu().numpy().astype(np.float32) for n in names}


def bake(model: NGPRT, occupancy_0: np.ndarray, gamma: float, G_metric: str = "box",
         grids: str = "preset", fine: np.ndarray | None = None):
    """A :class:`clrender.ngprt.baked.BakedModel` of ``model`` with rendering occupancy
    ``occupancy_0`` ((L_C,)*3 uint8 0/1, which places the coarse blocks), step scaler
    ``gamma``, G of ``G_metric`` (:data:`clrender.ngprt.baked.G_METRICS`) and the
    empty-space grids ``grids`` (:data:`clrender.ngprt.config.GRIDS`): ``preset``, the mip
    and G from ``occupancy_0``; ``paper``, from ``fine`` ((occ_res,)*3 0/1, within
    ``occupancy_0``'s cells: :func:`bake_state` makes it)."""
    from .baked import BakedModel, build_distance_grid, build_mip, sparse_coarse_grid

    cfg = with_grids(model.cfg, grids)
    if (fine is None) != (cfg.occ_res == cfg.L_C):
        raise ValueError(f"grids {grids!r}: need the occupancy at {cfg.occ_res}^3 "
                         f"(fine) exactly when it is finer than L_C = {cfg.L_C}")
    occupancy_0 = (np.asarray(occupancy_0) != 0).astype(np.uint8)
    arrays = _weights(model)
    block_index, blocks = sparse_coarse_grid(lambda c: corner_values(model, c), occupancy_0,
                                             cfg.coarse_block)
    arrays["coarse_block_index"], arrays["coarse_blocks"] = block_index, blocks
    occupancy = occupancy_0 if fine is None else (np.asarray(fine) != 0).astype(np.uint8)
    for lev, grid in enumerate(build_mip(occupancy)):
        arrays[f"occupancy_{lev}"] = grid
    arrays["G"] = build_distance_grid(occupancy, cfg.G_res, G_metric)
    return BakedModel(cfg, float(gamma), arrays, G_metric)


def bake_state(model: NGPRT, occupancy: torch.Tensor, gamma: float, dataset,
               n_rays: int = CULL_RAYS, G_metric: str = "box", grids: str = "preset"):
    """A :class:`clrender.ngprt.baked.BakedModel` of an in-memory training state (what
    :func:`bake_run` bakes from a checkpoint): visibility culling of the training
    ``occupancy`` ((L_C,)*3 bool) on ``n_rays`` rays of ``dataset`` (the training Dataset),
    then :func:`bake`. With ``grids="paper"`` the culling also marks the cells of the
    paper's finer occupancy (dilated by :data:`FINE_DILATION`, kept only within the L_C
    cells). Works on a model in
    training; changes neither it nor the torch RNG."""
    R = with_grids(model.cfg, grids).occ_res
    if R == model.cfg.L_C:
        occupancy_0, = visible_cells(model, occupancy, gamma, dataset, n_rays=n_rays)
        return bake(model, occupancy_0, gamma, G_metric, grids)
    occupancy_0, fine = visible_cells(model, occupancy, gamma, dataset, n_rays=n_rays,
                                      resolutions=(model.cfg.L_C, R),
                                      dilation=(1, FINE_DILATION))
    from .baked import upsampled

    fine &= upsampled(occupancy_0, R // model.cfg.L_C)
    return bake(model, occupancy_0, gamma, G_metric, grids, fine)


def trained_on(conf: dict) -> dict:
    """The manifest's record of a run's data (``config.json``): path and downscale."""
    return {"data": conf.get("data"), "downscale": conf.get("downscale", 1)}


# The last bake of this process, by (run folder, its checkpoint's mtime and size, n_rays,
# grids, device): baking it again with another G metric rebuilds G alone (Table 4 bakes
# both metrics of each model in turn).
_LAST_BAKE: dict = {}


def bake_run(run_dir, out_path, dataset=None, device=None, n_rays: int = CULL_RAYS,
             G_metric: str = "box", grids: str = "preset") -> Path:
    """Bake the checkpoint of ``run_dir`` into ``out_path`` (written atomically). The
    process keeps its last bake (without a ``dataset`` given): the same checkpoint baked
    again with another ``G_metric`` only rebuilds G (the bakes differ in G alone).

    Args:
        dataset: the training Dataset for visibility culling; default: loaded from the
            run's ``config.json``.
        G_metric: what G measures (:data:`clrender.ngprt.baked.G_METRICS`).
        grids: the empty-space grids (:data:`clrender.ngprt.config.GRIDS`).
    Returns:
        the path written.
    """
    from .baked import save_baked, with_G_metric

    stat = (Path(run_dir) / "checkpoint.pt").stat()
    key = (str(Path(run_dir).resolve()), stat.st_mtime_ns, stat.st_size, n_rays, grids,
           str(device))
    model, occ, gamma, conf = load_run(run_dir, device)
    kept = _LAST_BAKE.get(key) if dataset is None else None
    if kept is not None:
        baked = with_G_metric(kept, G_metric)
    elif dataset is not None:
        baked = bake_state(model, occ, gamma, dataset, n_rays=n_rays, G_metric=G_metric,
                           grids=grids)
    else:
        if not conf.get("data"):
            raise ValueError(f"{run_dir}/config.json: no data path; pass the dataset")
        from ..data import load_dataset
        dataset = load_dataset(conf["data"], split="train", downscale=conf.get("downscale", 1))
        baked = bake_state(model, occ, gamma, dataset, n_rays=n_rays, G_metric=G_metric,
                           grids=grids)
        _LAST_BAKE.clear()
        _LAST_BAKE[key] = baked
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    save_baked(baked, out_path, trained_on=trained_on(conf))
    return out_path
