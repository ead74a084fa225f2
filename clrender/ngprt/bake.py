"""Baking a trained NGP-RT run into the renderer's file (docs/ngprt.md "Baked file").

The rendering occupancy is the training occupancy after visibility culling (cells whose
samples carry weight on some training ray) and a 1-cell dilation, as MERF; the coarse
grid holds the auxiliary NGP at the corners of those cells; the fine tables and MLP
weights are copied as they are.

Examples:
    >>> bake_run("/tmp/run_b", "/tmp/model_b.npz")
    >>> baked = bake_state(model, occ.binary, gamma, train_set)   # mid-training, in memory

References: NGP-RT (Hu et al., ECCV 2024) §4.1, S2.5; MERF (Reiser et al. 2023) §5.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .model import NGPRT, render_rays
from .train import RaySampler, load_run

WEIGHT_THRESHOLD = 1e-3     # a cell is visible when one of its samples has more weight
CULL_RAYS = 1 << 18         # training rays rendered for visibility culling (at most)


@torch.no_grad()
def visible_cells(model: NGPRT, occupancy: torch.Tensor, gamma: float, dataset,
                  n_rays: int = CULL_RAYS, threshold: float = WEIGHT_THRESHOLD,
                  dilation: int = 1, chunk: int = 8192, seed: int = 0) -> np.ndarray:
    """Rendering occupancy: cells holding a sample of weight > ``threshold`` on one of
    ``n_rays`` training rays (all pixels when there are fewer), dilated by ``dilation``.

    Args:
        occupancy: (L_C,)*3 bool training occupancy.
        dataset: the training Dataset (images, cameras, background).
    Returns:
        (L_C, L_C, L_C) uint8 0/1 ``occupancy_0``.
    """
    dev, R = occupancy.device, model.cfg.L_C
    sampler = RaySampler(dataset, dev)
    n_pix = sampler.N * sampler.H * sampler.W
    gen = torch.Generator(device=dev).manual_seed(seed)
    pix = torch.randperm(n_pix, device=dev, generator=gen)[:n_rays] if n_pix > n_rays \
        else torch.arange(n_pix, device=dev)
    bg = torch.as_tensor(np.asarray(dataset.background), dtype=torch.float32, device=dev)
    visible = torch.zeros(R ** 3, dtype=torch.bool, device=dev)
    for i in range(0, len(pix), chunk):
        o, d = sampler.rays(pix[i:i + chunk])
        r = render_rays(model, o, d, occupancy, gamma, bg)
        keep = r["weights"] > threshold
        u = _sample_u(r, o, d, model.cfg)[keep]
        c = torch.clamp(torch.floor(u * R), 0, R - 1).to(torch.int64)
        visible[(c[:, 0] * R + c[:, 1]) * R + c[:, 2]] = True
    grid = visible.reshape(1, 1, R, R, R).float()
    if dilation:
        grid = F.max_pool3d(grid, 2 * dilation + 1, stride=1, padding=dilation)
    return (grid[0, 0] > 0).to(torch.uint8).cpu().numpy()


def _sample_u(r: dict, o, d, cfg) -> torch.Tensor:
    from . import torch_ops as ops

    ids = r["ray_ids"]
    x = o[ids] + r["t"][:, None] * d[ids]
    return ops.to_grid(x, cfg.extent, cfg.scene == "unbounded")


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


def bake(model: NGPRT, occupancy_0: np.ndarray, gamma: float, G_metric: str = "box"):
    """A :class:`clrender.ngprt.baked.BakedModel` of ``model`` with rendering occupancy
    ``occupancy_0`` ((L_C,)*3 uint8 0/1), step scaler ``gamma`` and G of ``G_metric``
    (:data:`clrender.ngprt.baked.G_METRICS`)."""
    from .baked import BakedModel, build_distance_grid, build_mip, sparse_coarse_grid

    cfg = model.cfg
    occupancy_0 = (np.asarray(occupancy_0) != 0).astype(np.uint8)
    arrays = _weights(model)
    block_index, blocks = sparse_coarse_grid(lambda c: corner_values(model, c), occupancy_0,
                                             cfg.coarse_block)
    arrays["coarse_block_index"], arrays["coarse_blocks"] = block_index, blocks
    mip = build_mip(occupancy_0)
    for lev, grid in enumerate(mip.values() if isinstance(mip, dict) else mip):
        arrays[f"occupancy_{lev}"] = np.asarray(grid, np.uint8)
    arrays["G"] = build_distance_grid(occupancy_0, cfg.G_res, G_metric)
    return BakedModel(cfg, float(gamma), arrays, G_metric)


def bake_state(model: NGPRT, occupancy: torch.Tensor, gamma: float, dataset,
               n_rays: int = CULL_RAYS, G_metric: str = "box"):
    """A :class:`clrender.ngprt.baked.BakedModel` of an in-memory training state (what
    :func:`bake_run` bakes from a checkpoint): visibility culling of the training
    ``occupancy`` ((L_C,)*3 bool) on ``n_rays`` rays of ``dataset`` (the training Dataset),
    then :func:`bake`. Works on a model in training; changes neither it nor the torch RNG."""
    occupancy_0 = visible_cells(model, occupancy, gamma, dataset, n_rays=n_rays)
    return bake(model, occupancy_0, gamma, G_metric)


def trained_on(conf: dict) -> dict:
    """The manifest's record of a run's data (``config.json``): path and downscale."""
    return {"data": conf.get("data"), "downscale": conf.get("downscale", 1)}


def bake_run(run_dir, out_path, dataset=None, device=None, n_rays: int = CULL_RAYS,
             G_metric: str = "box") -> Path:
    """Bake the checkpoint of ``run_dir`` into ``out_path`` (written atomically).

    Args:
        dataset: the training Dataset for visibility culling; default: loaded from the
            run's ``config.json``.
        G_metric: what G measures (:data:`clrender.ngprt.baked.G_METRICS`).
    Returns:
        the path written.
    """
    from .baked import save_baked

    model, occ, gamma, conf = load_run(run_dir, device)
    if dataset is None:
        if not conf.get("data"):
            raise ValueError(f"{run_dir}/config.json: no data path; pass the dataset")
        from ..data import load_dataset
        dataset = load_dataset(conf["data"], split="train", downscale=conf.get("downscale", 1))
    baked = bake_state(model, occ, gamma, dataset, n_rays=n_rays, G_metric=G_metric)
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    save_baked(baked, out_path, trained_on=trained_on(conf))
    return out_path
