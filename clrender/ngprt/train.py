"""Training NGP-RT (PyTorch, CPU or CUDA).

A run folder (:class:`clrender.runs.RunFolder`) holds ``config.json`` (``"method":
"ngprt"``, model config, train config, data path),
``checkpoint.pt`` (model, optimizer, training occupancy, gamma, step, steps skipped) and
``log.jsonl`` (one JSON line per logged step: loss, psnr, gamma, samples per ray, rays, eta,
lr, steps skipped). A step whose loss or gradients are not finite is skipped, as in every
method (:mod:`clrender.runs`); its ``nonfinite-step-N.pt`` holds the model, the training
occupancy, gamma and the batch's rays.

Examples:
    >>> run = train("/tmp/scn_b", "/tmp/run_b", preset="cpu", variant="separate-v", L=2)
    >>> model, occ, gamma, cfg = load_run(run)

References: NGP-RT (Hu et al., ECCV 2024) S2.2 (loss), S2.3 (step auto-tuning),
S2.4 (optimisation); Instant-NGP / nerfacc occupancy grid.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..runs import RunFolder, finite_step, mse_psnr, pick_device, set_lr, training_data
from . import engine as engines
from . import torch_ops as ops
from .config import ModelConfig, preset as model_preset
from .model import NGPRT, render_rays
from .stages import backward, mark, stage


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation hyper-parameters (S2.2-S2.4); presets change counts, never the method.

    Attributes:
        iterations: optimiser steps.
        max_rays, target_samples: per-batch budget; the ray count adapts so a batch holds
            about ``target_samples`` samples, never more than ``max_rays`` rays (S2.4).
        lr, lr_warmup: peak learning rate, reached linearly over the first ``lr_warmup``
            fraction of iterations, then linear decay to 0.
        eta, eta_warmup: distortion-loss weight, reached linearly over the first
            ``eta_warmup`` fraction of iterations (S2.2, S2.4).
        huber_delta: transition point of the Huber colour loss (the paper does not give
            it; with 0.1 the CPU-sized runs stall near a constant colour, measured, so the
            loss is quadratic over the whole [0, 1] error range).
        n_min, kappa, gamma_min, gamma_init: step auto-tuning (Eq. S3).
        occ_every, occ_warmup, occ_decay, occ_threshold, occ_fraction: training occupancy
            grid: update period, steps during which every cell is re-evaluated, EMA decay,
            alpha threshold, fraction of cells sampled per update after the warm-up.
        checkpoint_every, log_every: in iterations.
    """

    iterations: int = 100_000
    max_rays: int = 8000
    target_samples: int = 1 << 21
    lr: float = 1e-2
    lr_warmup: float = 0.01
    betas: tuple = (0.9, 0.99)
    eps: float = 1e-8
    eta: float = 0.01
    eta_warmup: float = 0.5
    huber_delta: float = 1.0
    n_min: float = 3.0
    kappa: float = 0.001
    gamma_min: float = 0.2217
    gamma_init: float = 1.0
    occ_every: int = 16
    occ_warmup: int = 256
    occ_decay: float = 0.95
    occ_threshold: float = 0.01
    occ_fraction: float = 0.25
    checkpoint_every: int = 1000
    log_every: int = 50


# The cpu preset. Short runs visit each cell far fewer times than 100k iterations would, so the
# occupancy EMA decays faster to prune empty space within the run. An update of the
# cpu preset's 128^3 grid is costly (its 129^3 coarse corners, a quarter of the cells at
# random and as many occupied ones), so it runs every 64 steps; 0.36 = 0.6^2 keeps the
# decay per step of an update every 32 steps with decay 0.6.
# 2^15 samples a batch: the cpu model's step (step_res = 2 L_C) puts ~30 on a bounded
# ray, so a batch holds ~2700 rays; half as many rays a batch lost quality
# (docs/guides/training.md, "Presets").
_CPU = TrainConfig(iterations=1000, max_rays=4096, target_samples=1 << 15, occ_every=64,
                   occ_warmup=128, occ_decay=0.36, occ_fraction=0.25, checkpoint_every=250,
                   log_every=25)
TRAIN_PRESETS: dict[str, TrainConfig] = {
    "paper": TrainConfig(),
    "cpu": _CPU,
    # The cpu counts for about ten minutes of fast-engine steps on a real capture
    # (docs/guides/training.md, "Presets": the time a step on the lego and the bonsai).
    "cpu-long": replace(_CPU, iterations=9000, checkpoint_every=1000, log_every=50),
    "tiny": TrainConfig(iterations=300, max_rays=1024, target_samples=1 << 13, occ_every=16,
                        occ_warmup=32, occ_decay=0.6, occ_fraction=0.5, checkpoint_every=300,
                        log_every=10),
}


def sized(preset: str, variant: str = "separate-v", L: int = 2, scene: str = "bounded",
          log2_T: int | None = None, batch: int | None = None):
    """``(ModelConfig, TrainConfig)`` of ``preset`` with the sizes a run may change (None:
    the preset's): ``log2_T``, the fine tables' 2^log2_T entries a level; ``batch``, the
    samples a batch aims at (``target_samples``), its ray cap ``max_rays`` scaled by the
    same factor (the cap still binds on rays of fewer than target_samples / max_rays
    samples, so the batch grows on every scene)."""
    cfg = model_preset(preset, variant=variant, L=L, scene=scene,
                       **({} if log2_T is None else {"log2_T": int(log2_T)}))
    tcfg = TRAIN_PRESETS[preset]
    if batch is None:
        return cfg, tcfg
    samples = int(batch)
    if samples < 1024:
        raise ValueError(f"batch={batch}: a batch aims at 1024 samples or more")
    return cfg, replace(tcfg, target_samples=samples,
                        max_rays=max(64, round(tcfg.max_rays * samples / tcfg.target_samples)))


def step_scale(cfg: ModelConfig, u: torch.Tensor) -> torch.Tensor:
    """(N,) largest world length of a unit of lattice distance at grid coordinates u
    (N, 3), over directions (1 inside the unit cube). The unbounded lattice is uniform in
    contracted space (docs/ngprt.md "Step lattice"); outside the cube, with ``m = |x|_inf``
    and ``c_b`` the other two contracted coordinates, a contracted step dc is longest in
    world space along the ray through the origin: ``|dx| = m^2 sqrt(1 + c_b^2 + c_b'^2) |dc|``,
    ``m = 1 / (2 - |c|_inf)``."""
    if cfg.scene == "bounded":
        return torch.ones_like(u[:, 0])
    c = u * 2 * cfg.extent - cfg.extent
    mc = c.abs().amax(-1)
    m = 1.0 / torch.clamp(2.0 - mc, min=1e-2)
    rest = torch.clamp((c * c).sum(-1) - mc * mc, min=0.0)
    scale = m * m * torch.sqrt(1.0 + rest)
    return torch.where(mc <= 1.0, torch.ones_like(mc), torch.clamp(scale, max=1e4))


class OccupancyGrid:
    """Training occupancy at L_C: EMA of per-cell alpha (density times step), as
    Instant-NGP / nerfacc; ``binary`` marks cells worth sampling.

    Args:
        cfg: the model config (L_C, scene).
        device: torch device.
    """

    def __init__(self, cfg: ModelConfig, device):
        self.cfg, self.R = cfg, cfg.L_C
        self.ema = torch.zeros(self.R ** 3, device=device)
        self.binary = torch.ones((self.R,) * 3, dtype=torch.bool, device=device)

    @torch.no_grad()
    def update(self, model: NGPRT, step: int, warmup: int, fraction: float, decay: float,
               threshold: float, chunk: int = 1 << 16):
        n = self.R ** 3
        dev = self.ema.device
        if step < warmup:
            cells = None      # every cell, a chunk at a time (not 2^27 int64, 1 GB, at once)
        else:
            m = max(1, int(n * fraction))
            occupied = torch.nonzero(self.binary.reshape(-1))[:, 0]
            pick = occupied[torch.randint(len(occupied), (m,), device=dev)] if len(occupied) \
                else occupied
            # Sorted, each once: neighbouring cells share corners and table rows in cache.
            cells = torch.unique(torch.cat([torch.randint(n, (m,), device=dev), pick]))
        # Every corner once when the corner grid is small (CPU presets); per chunk otherwise.
        corner_grid = model.all_corner_values() if (self.R + 1) ** 3 <= 1 << 23 else None
        for i in range(0, n if cells is None else len(cells), chunk):
            c = torch.arange(i, min(i + chunk, n), device=dev) if cells is None \
                else cells[i:i + chunk]
            ijk = torch.stack([c // (self.R * self.R), (c // self.R) % self.R, c % self.R], -1)
            u = (ijk.to(torch.float32) + torch.rand(len(c), 3, device=dev)) / self.R
            alpha = model.sample(u, corner_grid)[0] * self.cfg.s0 * step_scale(self.cfg, u)
            self.ema[c] = torch.maximum(self.ema[c] * decay, alpha)
        thre = min(threshold, float(self.ema.mean()))
        self.binary = (self.ema > thre).reshape((self.R,) * 3)


class RaySampler:
    """Random training rays across all images (float32, NeRF camera convention).

    With ``alpha`` ((N, H, W) coverage of images with an alpha channel) the targets are
    re-composited on a random background per ray, as Instant-NGP does for synthetic
    scenes: on a fixed background the model can paint empty space in the background
    colour, and the occupancy grid could never prune it.
    """

    def __init__(self, dataset, device, alpha=None):
        self.images = torch.as_tensor(dataset.images, dtype=torch.float32, device=device)
        self.background = torch.as_tensor(np.asarray(dataset.background), dtype=torch.float32,
                                          device=device)
        self.alpha = None if alpha is None else torch.as_tensor(
            alpha, dtype=torch.float32, device=device).reshape(-1, 1)
        self.N, self.H, self.W = self.images.shape[:3]
        cams = dataset.cameras
        self.K = torch.tensor([[c.fx, c.fy, c.cx, c.cy] for c in cams], dtype=torch.float32,
                              device=device)
        self.c2w = torch.tensor(np.stack([c.c2w[:3, :4] for c in cams]), dtype=torch.float32,
                                device=device)

    def sample(self, n: int, generator=None):
        """(origins, dirs, rgb, background), each (n, 3), of ``n`` random pixels."""
        dev = self.images.device
        pix = torch.randint(self.N * self.H * self.W, (n,), device=dev, generator=generator)
        o, d = self.rays(pix)
        rgb = self.images.reshape(-1, 3)[pix]
        if self.alpha is None:
            return o, d, rgb, self.background.expand(n, 3)
        a = self.alpha[pix]
        bg = torch.rand(n, 3, device=dev, generator=generator)
        return o, d, rgb + (1.0 - a) * (bg - self.background), bg

    def rays(self, pix: torch.Tensor):
        """(origins, dirs), each (n, 3), of flat pixel indices ``(image * H + y) * W + x``."""
        i, y, x = pix // (self.H * self.W), (pix // self.W) % self.H, pix % self.W
        K = self.K[i]
        a = (x.float() + 0.5 - K[:, 2]) / K[:, 0]
        b = -((y.float() + 0.5 - K[:, 3]) / K[:, 1])
        local = torch.stack([a, b, -torch.ones_like(a)], -1)
        d = (self.c2w[i, :, :3] @ local[..., None])[..., 0]
        return self.c2w[i, :, 3], d / d.norm(dim=-1, keepdim=True)


def schedule(step: int, tcfg: TrainConfig) -> tuple[float, float]:
    """(lr, eta) at ``step`` (S2.4): LR linear warm-up then linear decay to 0; eta linear
    warm-up over the first ``eta_warmup`` of training, then constant."""
    n = tcfg.iterations
    warm = max(1, int(round(tcfg.lr_warmup * n)))
    lr = tcfg.lr * (step + 1) / warm if step < warm else tcfg.lr * max(0.0, (n - step) / max(1, n - warm))
    eta = tcfg.eta * min(1.0, step / max(1.0, tcfg.eta_warmup * n))
    return lr, eta


def tune_gamma(gamma: float, n_bar: float, tcfg: TrainConfig) -> float:
    """Eq. S3: grow gamma towards 1 while rays keep >= N_min samples, else shrink it."""
    if n_bar >= tcfg.n_min:
        return min(1.0, (1.0 + tcfg.kappa) * gamma)
    return max(tcfg.gamma_min, (1.0 - tcfg.kappa) * gamma)


def load_run(run_dir, device=None):
    """The trained model of a run folder.

    Returns:
        model (eval mode), occupancy (L_C,)*3 bool training occupancy, gamma (float),
        config dict (``config.json``).
    """
    run_dir, dev = Path(run_dir), pick_device(device)
    conf = json.loads((run_dir / "config.json").read_text())
    cfg = ModelConfig.from_dict(conf["model"], where=str(run_dir / "config.json"))
    state = torch.load(run_dir / "checkpoint.pt", map_location=dev, weights_only=True)
    model = NGPRT(cfg).to(dev)
    model.load_state_dict(state["model"])
    model.eval()
    return model, state["occ_binary"].to(dev), float(state["gamma"]), conf


def train(data, out, preset: str = "cpu", variant: str = "separate-v", L: int = 2,
          iterations: int | None = None, seed: int = 0, device=None,
          train_config: TrainConfig | None = None, progress: bool = True,
          on_step=None, downscale: int = 1, engine: str = "fast",
          log2_T: int | None = None, batch: int | None = None) -> Path:
    """Train an NGP-RT model on the dataset folder ``data`` (or a loaded Dataset) into the
    run folder ``out`` (:class:`clrender.runs.RunFolder`).

    An existing checkpoint in ``out`` with the same config is resumed.

    Args:
        engine: ``fast`` or ``torch`` (autograd, the reference; :mod:`clrender.ngprt.engine`;
            the engine that trains is recorded in ``config.json``: ``torch`` where ``fast``
            does not run; a checkpoint resumes under either).
        downscale: the dataset's ``images_{downscale}/`` or its images shrunk that many
            times (:func:`clrender.data.load_dataset`); recorded in ``config.json``.
        log2_T, batch: the preset's table size and batch changed (:func:`sized`; None:
            the preset's); ``train_config``, when given, replaces the batch's config.
        on_step: called as ``on_step(step, model, occ, gamma)`` after every iteration
            ``step`` (0-based, as ``log.jsonl``: its optimiser step and gamma update
            done, its log line and checkpoint written where due), with the :class:`NGPRT`
            in training, its :class:`OccupancyGrid` and the step scaler gamma. It must
            leave them and the torch RNG as it found them (``bench/train_curve.py`` bakes
            and evaluates there).
    Returns:
        the run folder.
    """
    dev = pick_device(device)
    torch.manual_seed(seed)
    ds, data_path = training_data(data, downscale)
    cfg, tcfg = sized(preset, variant, L, ds.scene, log2_T, batch)
    tcfg = train_config or tcfg
    if iterations is not None:
        tcfg = replace(tcfg, iterations=int(iterations))
    engine = engines.get(engine, dev)            # the one that trains, recorded as such
    run = RunFolder(out, {"method": "ngprt", "model": cfg.to_dict(), "train": asdict(tcfg),
                          "data": data_path, "downscale": downscale,
                          "preset": preset, "seed": seed, "engine": engine.name,
                          "background": [float(v) for v in ds.background]},
                    free=("engine",))
    model = NGPRT(cfg, engine).to(dev)
    opt = make_optimizer(model, tcfg)
    occ, gamma, start = OccupancyGrid(cfg, dev), tcfg.gamma_init, 0
    state = run.resume(model, opt, dev)
    if state is not None:
        occ.ema, occ.binary = state["occ_ema"].to(dev), state["occ_binary"].to(dev)
        gamma, start = float(state["gamma"]), int(state["step"])
    run.write_config()
    _loop(model, opt, occ, gamma, start, RaySampler(ds, dev, getattr(ds, "alpha", None)), tcfg,
          run, progress, on_step)
    return run.dir


def make_optimizer(model: NGPRT, tcfg: TrainConfig) -> torch.optim.Adam:
    """Adam over every parameter (S2.4); on the CPU torch's fused Adam, the same update in
    one pass, several times faster than the default, the parameters equal to the default's
    within rounding (docs/results-training.md, "The training engines")."""
    cpu = all(p.device.type == "cpu" for p in model.parameters())
    return torch.optim.Adam(model.parameters(), lr=tcfg.lr, betas=tuple(tcfg.betas),
                            eps=tcfg.eps, fused=True if cpu else None)


def train_step(model, opt, occ, gamma: float, n_rays: int, step: int, sampler, tcfg) -> dict:
    """One iteration: occupancy update where due, a batch of ``n_rays`` rays, the loss
    (S2.2), its backward and, where the loss and gradients are finite, the optimiser step;
    each stage reported to :mod:`clrender.ngprt.stages`.

    Returns:
        dict with ``loss`` (0-d tensor), ``rgb`` (R, 3) and ``target`` (R, 3) detached,
        ``n_samples``, ``n_bar`` (samples per ray with samples), ``eta``, ``lr``,
        ``finite`` (False: the step was skipped) and ``batch`` (the rays' origins,
        directions (R, 3), targets (R, 3) and background (3,)).
    """
    if step % tcfg.occ_every == 0:
        with stage("occupancy"):
            occ.update(model, step, tcfg.occ_warmup, tcfg.occ_fraction, tcfg.occ_decay,
                       tcfg.occ_threshold)
    lr, eta = schedule(step, tcfg)
    set_lr(opt, lr)
    with stage("rays"):
        o, d, target, bg = sampler.sample(n_rays)
    r = render_rays(model, o, d, occ.binary, gamma, bg)
    with stage("losses"):
        s = float(torch.tensor(gamma * model.cfg.s0, dtype=torch.float32))
        lo, hi = ops.distortion_intervals(r["k"], r["t"], r["delta"], s,
                                          model.cfg.scene == "unbounded")
        dist = ops.distortion_loss(mark(r["weights"], "compositing"), lo, hi, r["ray_ids"],
                                   n_rays)
        colour = F.huber_loss(r["rgb"], target, delta=tcfg.huber_delta)
        loss = colour + eta * dist.mean()
    opt.zero_grad(set_to_none=True)
    backward(loss)
    with stage("optimiser"):
        finite = finite_step(loss, model.parameters())
        if finite:
            opt.step()
    n_samples, hit = len(r["ray_ids"]), int((r["n_occ"] > 0).sum())
    # Rays that cross only empty space (background) carry no samples at any step
    # size, so the average of Eq. S3 is taken over the rays that have samples.
    return {"loss": loss.detach(), "rgb": r["rgb"].detach(), "target": target,
            "n_samples": n_samples, "n_bar": n_samples / max(1, hit), "eta": eta, "lr": lr,
            "finite": finite, "batch": (o, d, target, bg)}


def nonfinite_step_state(out: dict, model, occ, gamma: float) -> dict:
    """What reproduces a skipped step (:meth:`clrender.runs.RunFolder.count_step`): the
    model it left unchanged, the training occupancy it marched, gamma, the batch's rays."""
    o, d, target, bg = out["batch"]
    return {"model": model.state_dict(), "occ_binary": occ.binary, "gamma": float(gamma),
            "origins": o, "dirs": d, "target": target, "background": bg}


def next_rays(n_rays: int, n_samples: int, tcfg: TrainConfig) -> int:
    """Rays of the next batch: scaled so it holds about ``target_samples`` samples (S2.4)."""
    return int(min(tcfg.max_rays, max(64, n_rays * tcfg.target_samples / max(1, n_samples))))


def _loop(model, opt, occ, gamma, start, sampler, tcfg, run, progress, on_step=None):
    n_rays = min(tcfg.max_rays, 1024)
    for step in run.steps(start, tcfg.iterations, tcfg.log_every, tcfg.checkpoint_every,
                          "train", progress):
        out = train_step(model, opt, occ, gamma, n_rays, step, sampler, tcfg)
        run.count_step(step, out["finite"],
                       lambda: nonfinite_step_state(out, model, occ, gamma))
        loss, n_bar, n_samples, lr, eta = (out[k] for k in ("loss", "n_bar", "n_samples", "lr",
                                                            "eta"))
        gamma = tune_gamma(gamma, n_bar, tcfg)
        n_rays_used = len(out["rgb"])
        n_rays = next_rays(n_rays, n_samples, tcfg)
        psnr = mse_psnr(float(F.mse_loss(out["rgb"], out["target"])))
        run.bar.set_postfix(loss=f"{float(loss):.4f}", psnr=f"{psnr:.2f}",
                            gamma=f"{gamma:.3f}", spr=f"{n_bar:.1f}")
        run.after_step(step, lambda: {
            "loss": float(loss), "psnr": psnr, "gamma": gamma,
            "samples_per_ray": n_bar, "rays": n_rays_used, "samples": n_samples, "eta": eta,
            "lr": lr, "occupied": float(occ.binary.float().mean())},
            lambda: {"model": model.state_dict(), "optimizer": opt.state_dict(),
                     "occ_ema": occ.ema, "occ_binary": occ.binary, "gamma": float(gamma)})
        if on_step is not None:
            on_step(step, model, occ, gamma)
