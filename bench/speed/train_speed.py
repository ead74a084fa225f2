"""Training speed of NGP-RT by stage, for each training engine, in one interleaved run.

    python -m bench.speed.train_speed                               # cpu preset, built-in bounded
    python -m bench.speed.train_speed --data DIR --steps 40 --engines torch,fast

Each engine trains its own copy of the same initial model on the same data, one step of
each in turn, the order swapped every step (``--warmup`` untimed steps, then ``--steps``
timed ones, from step 0, the lattice adapting its ray count to the preset's target
samples). Per stage
(:mod:`clrender.ngprt.stages`: ray sampling, coarse corners and their de-duplication,
auxiliary encoding + MLP, coarse trilinear, fine levels, fusion, compositing, shading,
losses, each stage's backward, the optimiser; the occupancy updates timed per engine
after the steps, one warm-up and one later update, amortised over the preset's run): the
median seconds over the timed steps, and a bound from the stage's counted gathers, streamed bytes and FLOPs at
this machine's rates measured in the same run (:mod:`bench.speed.limits`'s random-gather and
FLOP rates on the OpenCL device, the same CPU; the streaming rate of a torch copy).
"Samples" are the samples entering the loss (the preset's target batch);
``samples_per_s`` = median samples over median step time. Each engine's speed-up over the
first (``speedup``: of a step's samples a second, and of its encoding stages' time) is the
geometric mean over the timed steps, each step of both a pair, with its 95% interval
(:func:`bench.tables.measure.speedup_interval`). Writes
``<out>/train_speed.{md,json}``. Never asserts; the ratios are only as good as the
machine is quiet.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from bench.modelcache import cache
from bench.options import shown_path
from bench.speed.limits import F8_BYTES, flop_rate, gather_rate
from bench.speed.ngprt_bounds import deferred_flops
from bench.tables.compare import speedup_cell
from bench.tables.measure import speedup_interval
from clrender.atomic import write_atomic
from clrender.data import load_dataset
from clrender.ngprt import engine as engines
from clrender.ngprt import fused
from clrender.ngprt import torch_ops as ops
from clrender.ngprt.config import FEATURES, preset as model_preset
from clrender.ngprt.model import NGPRT
from clrender.ngprt.stages import StageClock
from clrender.ngprt.train import (TRAIN_PRESETS, OccupancyGrid, RaySampler, make_optimizer,
                                  next_rays, train_step, tune_gamma)

FORWARD = ("rays", "corners", "aux", "coarse", "fine", "fusion", "compositing", "shading",
           "losses")
BACKWARD = ("losses", "shading", "compositing", "fusion", "fine", "coarse", "aux")
ENCODING = ("corners", "aux", "coarse", "fine")     # the "encoding stages"


class _Trainer:
    """One engine's training state, stepped by :func:`train_step`."""

    def __init__(self, name, cfg, tcfg, sampler, seed):
        torch.manual_seed(seed)
        self.name, self.tcfg, self.sampler = name, tcfg, sampler
        self.model = NGPRT(cfg, engines.get(name, torch.device("cpu")))
        self.opt = make_optimizer(self.model, tcfg)
        self.occ, self.gamma, self.n_rays = OccupancyGrid(cfg, "cpu"), tcfg.gamma_init, 1024
        self.steps: list[dict] = []

    def step(self, i: int, timed: bool) -> None:
        clock = StageClock()
        t0 = time.perf_counter()
        with clock.active():
            out = train_step(self.model, self.opt, self.occ, self.gamma, self.n_rays, i,
                             self.sampler, self.tcfg)
        total = time.perf_counter() - t0
        self.gamma = tune_gamma(self.gamma, out["n_bar"], self.tcfg)
        self.n_rays = next_rays(self.n_rays, out["n_samples"], self.tcfg)
        if timed:
            self.steps.append({"total": total - clock.forward.pop("occupancy", 0.0),
                               "forward": dict(clock.forward), "backward": dict(clock.backward),
                               "samples": out["n_samples"], "rays": len(out["rgb"])})

    def occupancy_seconds(self) -> float:
        """Seconds of the occupancy updates a step carries over the preset's whole run: one
        warm-up update (every cell) and one after (the sampled cells) timed, weighted by
        how many of each the run makes."""
        tc = self.tcfg
        steps = range(0, tc.iterations, tc.occ_every)
        n_warm = sum(1 for s in steps if s < tc.occ_warmup)
        times = []
        for step in (0, tc.occ_warmup):
            t0 = time.perf_counter()
            self.occ.update(self.model, step, tc.occ_warmup, tc.occ_fraction, tc.occ_decay,
                            tc.occ_threshold)
            times.append(time.perf_counter() - t0)
        return (n_warm * times[0] + (len(steps) - n_warm) * times[1]) / tc.iterations


def _median(xs) -> float:
    return float(np.median(xs)) if len(xs) else 0.0


def counts(model: NGPRT, n_samples: float, n_corners: float, n_rays: float) -> dict:
    """Per stage: random gathers (float8-sized, by table), streamed bytes and FLOPs of a
    step's forward; backwards count each gather as a read and a write (a scatter) and twice
    the FLOPs. Rough by design: the minimum a fused step must move."""
    cfg, aux = model.cfg, model.aux
    C, L, n_aux = cfg.coarse_channels, cfg.L, cfg.aux_levels
    chunks = math.ceil(C / 8)
    aux_reads = (n_aux - aux.on_vertices) * 8 + aux.on_vertices
    mlp = 2 * (n_aux * cfg.aux_features * cfg.aux_hidden + cfg.aux_hidden * C)
    f = 4
    return {
        "rays": {"bytes": n_samples * 36 + n_rays * 48, "flops": n_samples * 40},
        "corners": {"bytes": n_samples * 8 * 8 * 2, "flops": n_samples * 30},
        "aux": {"gathers": {"aux": n_corners * aux_reads * cfg.aux_features / 8},
                "bytes": n_corners * C * f, "flops": n_corners * (mlp + aux_reads * 8)},
        "coarse": {"gathers": {"coarse": n_samples * 8 * chunks},
                   "bytes": n_samples * C * f, "flops": n_samples * (8 * C * 2 + 22)},
        "fine": {"gathers": {"fine": n_samples * 8 * L}, "bytes": n_samples * L * FEATURES * f,
                 "flops": n_samples * L * (8 * 16 + 22)},
        "fusion": {"bytes": n_samples * (L * FEATURES + C + FEATURES) * f,
                   "flops": n_samples * 24 * L},
        "compositing": {"bytes": n_samples * 12 * f, "flops": n_samples * 30},
        "shading": {"bytes": n_rays * 30 * f, "flops": n_rays * deferred_flops()},
        "losses": {"bytes": n_samples * 10 * f, "flops": n_samples * 20},
        "optimiser": {"bytes": sum(p.numel() for p in model.parameters()) * 7 * f,
                      "flops": sum(p.numel() for p in model.parameters()) * 12},
    }


def bound_s(c: dict, rates: dict, backward: bool = False) -> float:
    """Seconds of counts ``c`` at ``rates``; a backward's gathers are scatters (read and
    write) and its FLOPs twice the forward's."""
    k = 2.0 if backward else 1.0
    g = sum(n * k / rates["gathers_per_s"][t] for t, n in c.get("gathers", {}).items())
    return g + c["bytes"] * k / rates["stream_bytes_per_s"] + c["flops"] * k / rates["flops_per_s"]


def torch_copy_rate(nbytes: int = 1 << 27, repeats: int = 7) -> float:
    """Bytes per second of a torch copy (read + write) of a ``nbytes`` float32 tensor, the
    best of ``repeats`` (a bound wants the machine's best)."""
    a = torch.rand(nbytes // 4)
    b = torch.empty_like(a)
    ts = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        b.copy_(a)
        ts.append(time.perf_counter() - t0)
    return 2 * nbytes / min(ts[1:])


def measure_rates(model: NGPRT, n_corners: int) -> dict:
    cfg = model.cfg
    sizes = {"fine": cfg.L * cfg.T * FEATURES * 4,
             "aux": cfg.aux_levels * model.aux.T * cfg.aux_features * 4,
             "coarse": max(F8_BYTES, int(n_corners) * cfg.coarse_channels * 4)}
    return {"gathers_per_s": {k: gather_rate(v) for k, v in sizes.items()},
            "flops_per_s": flop_rate(), "stream_bytes_per_s": torch_copy_rate()}


def _corner_count(model: NGPRT, t: _Trainer) -> tuple[float, float]:
    """(samples, unique L_C corners) of one batch of ``t``'s current state."""
    o, d, _, _ = t.sampler.sample(t.n_rays)
    cfg = model.cfg
    s = float(torch.tensor(t.gamma * cfg.s0, dtype=torch.float32))
    u = ops.lattice_samples(o, d, t.occ.binary, s, cfg.near, cfg.far, cfg.extent,
                            cfg.scene == "unbounded")[4]
    return float(len(u)), float(len(ops.coarse_corners(u, cfg.L_C)[0]))


def summarise(t: _Trainer, occ_s: float) -> dict:
    """``t``'s medians by stage; ``occ_s`` the occupancy seconds a step carries."""
    fw = {s: _median([st["forward"].get(s, 0.0) for st in t.steps]) for s in FORWARD}
    fw["optimiser"] = _median([st["forward"].get("optimiser", 0.0) for st in t.steps])
    bw = {s: _median([st["backward"].get(s, 0.0) for st in t.steps]) for s in BACKWARD}
    step_s = _median([st["total"] for st in t.steps]) + occ_s
    samples = _median([st["samples"] for st in t.steps])
    return {"forward_s": fw, "backward_s": bw, "occupancy_s": occ_s,
            "step_s": step_s, "samples": samples,
            "rays": _median([st["rays"] for st in t.steps]),
            "samples_per_s": samples / step_s,
            "encoding_s": sum(fw[s] for s in ENCODING) + sum(bw[s] for s in ENCODING
                                                             if s in bw)}


def paired_speedups(base: _Trainer, t: _Trainer, occ: dict) -> dict:
    """``t`` against ``base`` over their timed steps, step k of both a pair: {"step": of the
    samples a second (the amortised occupancy seconds ``occ[name]`` added to each step),
    "encoding": of the encoding stages' seconds}, each
    :func:`bench.tables.measure.speedup_interval` (>1: ``t`` faster)."""
    def rate(tr, st):
        return st["samples"] / (st["total"] + occ[tr.name])

    def encoding(st):
        return sum(st["forward"].get(s, 0.0) + st["backward"].get(s, 0.0) for s in ENCODING)

    pairs = list(zip(base.steps, t.steps))
    return {"step": speedup_interval([rate(t, b) / rate(base, a) for a, b in pairs]),
            "encoding": speedup_interval([encoding(a) / encoding(b) for a, b in pairs])}


def markdown(res: dict, meta: dict) -> str:
    names = list(res)
    head = "| stage | " + " | ".join(f"{n} ms" for n in names) + " | bound ms | " + \
        " | ".join(f"{n} / bound" for n in names) + " |"
    lines = [f"# Training speed by stage ({meta['preset']} preset, {meta['variant']}, "
             f"L = {meta['L']}, {meta['data']})", "",
             f"{meta['date']}; {meta['steps']} timed steps after {meta['warmup']}, engines "
             f"interleaved; median per stage; torch threads {meta['threads']}. Bounds: the "
             "stage's counted gathers, streamed bytes and FLOPs at this machine's measured "
             "rates (bench/speed/train_speed.py `counts`).", "",
             head, "|" + "---|" * (2 + 2 * len(names))]
    rows = [(f"{s}", "forward_s", s) for s in FORWARD] + [("optimiser", "forward_s", "optimiser")] \
        + [(f"{s} backward", "backward_s", s) for s in BACKWARD]
    for label, kind, s in rows:
        b = meta["bounds_s"][f"{s} backward" if kind == "backward_s" else s]
        ts = [res[n][kind][s] for n in names]
        lines.append(f"| {label} | " + " | ".join(f"{1e3 * t:.1f}" for t in ts) +
                     f" | {1e3 * b:.2f} | " + " | ".join(f"{t / b:.0f}x" if b else "-" for t in ts)
                     + " |")
    lines.append("| occupancy (amortised) | " + " | ".join(
        f"{1e3 * res[n]['occupancy_s']:.1f}" for n in names) + " | | |" + " |" * (len(names) - 1))
    lines += ["", f"| engine | step ms, median | samples | samples/s | encoding ms, median | "
              f"speed-up vs {names[0]} (samples/s, 95%) | speed-up vs {names[0]} (encoding, "
              "95%) |", "|---|---|---|---|---|---|---|"]
    for n in names:
        r, x = res[n], res[n].get("speedup") or {}
        lines.append(f"| {n} | {1e3 * r['step_s']:.1f} | {r['samples']:.0f} | "
                     f"{r['samples_per_s']:.0f} | {1e3 * r['encoding_s']:.1f} | "
                     f"{speedup_cell(x.get('step'))} | {speedup_cell(x.get('encoding'))} |")
    return "\n".join(lines + ["", "Speed-up: the geometric mean over the timed steps (each "
                               "step of both engines a pair, the order swapped every step) "
                               "with its 95% interval (t over the pairs' log ratios)."]) + "\n"


def run(preset: str, data, steps: int, warmup: int, out: Path, names, variant: str = "separate-v",
        L: int = 2, seed: int = 0) -> dict:
    ds = load_dataset(data, split="train")
    cfg = model_preset(preset, variant=variant, L=L, scene=ds.scene)
    tcfg = TRAIN_PRESETS[preset]
    sampler = RaySampler(ds, "cpu", getattr(ds, "alpha", None))
    build_s = fused.build() if "fast" in names else 0.0
    trainers = [_Trainer(n, cfg, tcfg, sampler, seed) for n in names]
    for i in range(warmup + steps):
        for t in (trainers if i % 2 == 0 else trainers[::-1]):
            t.step(i, timed=i >= warmup)
    occ = {t.name: t.occupancy_seconds() for t in trainers}
    n_samples, n_corners = _corner_count(trainers[0].model, trainers[0])
    res = {t.name: summarise(t, occ[t.name]) for t in trainers}
    for t in trainers[1:]:
        res[t.name]["speedup"] = paired_speedups(trainers[0], t, occ)
    rates = measure_rates(trainers[0].model, n_corners)
    c = counts(trainers[0].model, res[names[0]]["samples"],
               n_corners * res[names[0]]["samples"] / max(1.0, n_samples),
               res[names[0]]["rays"])
    bounds = {s: bound_s(c[s], rates) for s in c}
    bounds.update({f"{s} backward": bound_s(c[s], rates, True) for s in BACKWARD})
    meta = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "preset": preset, "variant": variant, "L": L, "data": shown_path(data), "steps": steps,
            "warmup": warmup, "threads": torch.get_num_threads(), "rates": rates,
            "counts": c, "bounds_s": bounds, "fast_build_s": build_s,
            "unique_corners_per_sample": n_corners / max(1.0, n_samples)}
    text = markdown(res, meta)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "train_speed.md", text)
    write_atomic(out / "train_speed.json", json.dumps({"meta": meta, **res}, indent=2))
    print(text)
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.speed.train_speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="cpu", choices=sorted(TRAIN_PRESETS))
    p.add_argument("--data", default="builtin-bounded",
                   help="dataset folder or built-in scene (default builtin-bounded)")
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--warmup", type=int, default=5)
    p.add_argument("--engines", default="torch,fast")
    p.add_argument("--variant", default="separate-v")
    p.add_argument("--levels", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--cache", type=Path, default=None, help="model cache root (scenes)")
    args = p.parse_args(argv)
    data = cache.resolve_scene(args.data, args.cache or cache.cache_root())
    run(args.preset, data, args.steps, args.warmup, args.out, args.engines.split(","),
        args.variant, args.levels)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
