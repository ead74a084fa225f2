"""NGP-RT's steps of ``bench.speed.paper_smoke`` (its ``PAPER_SMOKE``): a few `paper` training
steps with a cut occupancy update, one step at full occupancy at two batch sizes (their
memory difference per sample, extrapolated to the paper's 2^21 samples), a bake with cut
visibility culling, a render. Each step runs in a child process of its own (``phase``)."""
from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path


def run(data: str, work: Path, cuts: dict, phase, render) -> dict:
    """The steps' results by name; ``phase(fn, *args)`` runs one in a child (its time and
    peak memory added), ``render(baked)`` renders one view in a child."""
    small, large = (phase(batch_step, data, n) for n in cuts["batch_samples"])
    per_sample = (large["peak_rss_GB"] - small["peak_rss_GB"]) * 1e9 / max(
        1, large["samples"] - small["samples"])
    baked = str(work / "ngprt.npz")
    return {"batch": {"runs": [small, large], "bytes_per_sample": round(per_sample),
                      "paper_batch_2^21_GB": round(per_sample * 2 ** 21 / 1e9, 1)},
            "train": phase(train_steps, data, str(work / "ngprt"), cuts["steps"],
                           cuts["occ_fraction"]),
            "bake": phase(bake, str(work / "ngprt"), baked, cuts["cull_rays"]),
            "render": render(baked)}


def train_steps(data: str, run: str, steps: int, occ_fraction: float) -> dict:
    from clrender.ngprt.train import TRAIN_PRESETS, train

    tcfg = replace(TRAIN_PRESETS["paper"], iterations=steps, occ_warmup=0,
                   occ_fraction=occ_fraction, checkpoint_every=steps)
    train(data, run, preset="paper", train_config=tcfg, progress=False)
    log = [json.loads(line) for line in (Path(run) / "log.jsonl").read_text().splitlines()]
    return {"train": {k: v for k, v in asdict(tcfg).items() if k in
                      ("iterations", "occ_warmup", "occ_fraction", "max_rays", "target_samples")},
            "steps": [{k: r[k] for k in ("step", "rays", "samples", "seconds", "occupied")}
                      for r in log]}


def batch_step(data: str, samples: int) -> dict:
    """One training step of a fresh `paper` NGP-RT at full occupancy (the training grid's
    state before its first update) on a batch of about ``samples`` samples: forward, loss
    (Huber colour + distortion, as training), backward, Adam step."""
    import torch
    import torch.nn.functional as F

    from clrender.data import load_dataset
    from clrender.ngprt import torch_ops as ops
    from clrender.ngprt.config import preset
    from clrender.ngprt.model import NGPRT, render_rays
    from clrender.ngprt.train import RaySampler

    torch.manual_seed(0)
    ds = load_dataset(data, split="train")
    cfg = preset("paper", scene=ds.scene)
    model = NGPRT(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    sampler = RaySampler(ds, "cpu", getattr(ds, "alpha", None))
    occupied = torch.ones((cfg.L_C,) * 3, dtype=torch.bool)
    with torch.no_grad():
        probe = render_rays(model, *sampler.sample(64)[:2], occupied, 1.0, torch.ones(3))
    n_rays = max(1, int(samples * 64 / max(1, len(probe["ray_ids"]))))
    o, d, target, bg = sampler.sample(n_rays)
    r = render_rays(model, o, d, occupied, 1.0, bg)
    lo, hi = ops.distortion_intervals(r["k"], r["t"], r["delta"], float(cfg.s0), False)
    loss = F.huber_loss(r["rgb"], target, delta=1.0) + 0.01 * ops.distortion_loss(
        r["weights"], lo, hi, r["ray_ids"], n_rays).mean()
    loss.backward()
    opt.step()
    return {"rays": n_rays, "samples": len(r["ray_ids"])}


def bake(run: str, out: str, cull_rays: int) -> dict:
    from clrender.ngprt.bake import bake_run

    bake_run(run, out, n_rays=cull_rays)
    return {"cull_rays": cull_rays, "baked_MB": round(Path(out).stat().st_size / 1e6, 1)}
