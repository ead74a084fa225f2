"""The `paper` preset's smoke run: a few training steps of each method at the papers' sizes,
bake, render one small view; the time and peak resident memory of every phase.

    python -m bench.paper_smoke --data /work/data/lego200 --out results/

What it catches is what a GPU user's first `paper` run would die on (a shape, an
allocation, an hour of set-up), at CPU cost. Model sizes, optimiser and batch budget are the
`paper` presets'; only the amounts of work that scale with the number of cells or views and
not with the model are cut, and the cuts are written into the result:
- NGP-RT's occupancy update: the paper re-evaluates all 512^3 cells at every update of its
  first 256 steps (each cell's sample runs the auxiliary NGP at its 8 corners): on 2 CPU
  cores that pass alone is ~10^4 s. Here: no warm-up (``occ_warmup=0``) and a
  ``--occ-fraction`` of the cells per update, so step 0 samples ~2 x 2^27 x fraction cells.
- Visibility culling at bake: ``--cull-rays`` training rays instead of 2^18.
- NDRF: ``--distill-views`` distillation views instead of 1000, from a `tiny` NGP-RT
  teacher trained here (a few-step `paper` teacher has no geometry to extract meshes from;
  the student's sizes do not depend on the teacher's). Its extraction grid is the paper's
  (512^3) unless ``--extract-N`` cuts it.
Each phase runs in a child process of its own (spawned), so its peak resident memory
(``ru_maxrss``) is its own. Since a few-step model occupies few cells, the `paper` batch
(up to 2^21 samples) is measured apart: one training step at full occupancy at two batch
sizes, their peak memory difference per sample extrapolated to 2^21 samples. NDRF's views
are not extrapolated but bounded: the report gives a view's bytes at 800x800 (in memory
within the training's view budget, which ``ndrf_train`` reports) and what a disk-backed
view keeps resident. Writes ``OUT/paper-smoke.json`` and prints it.
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from multiprocessing import get_context
from pathlib import Path

from clrender.atomic import write_atomic

VIEW_SIZE = 64               # the rendered view's side (pixels)
DISK_BACKED_VIEW_BYTES = 96  # = clrender.ndrf.view_memory's (tests/test_paper_smoke.py)


def _phase(fn, *args) -> dict:
    """Run ``fn(*args)`` (a dict of results) in a spawned child; adds ``seconds`` and
    ``peak_rss_GB`` (the child's ``ru_maxrss``)."""
    with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
        return pool.submit(_timed, fn, *args).result()


def _timed(fn, *args) -> dict:
    start = time.perf_counter()
    out = fn(*args)
    return {**out, "seconds": round(time.perf_counter() - start, 1),
            "peak_rss_GB": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, 2)}


def ngprt_train(data: str, run: str, steps: int, occ_fraction: float) -> dict:
    from clrender.ngprt.train import TRAIN_PRESETS, train

    tcfg = replace(TRAIN_PRESETS["paper"], iterations=steps, occ_warmup=0,
                   occ_fraction=occ_fraction, checkpoint_every=steps)
    train(data, run, preset="paper", train_config=tcfg, progress=False)
    log = [json.loads(line) for line in (Path(run) / "log.jsonl").read_text().splitlines()]
    return {"train": {k: v for k, v in asdict(tcfg).items() if k in
                      ("iterations", "occ_warmup", "occ_fraction", "max_rays", "target_samples")},
            "steps": [{k: r[k] for k in ("step", "rays", "samples", "seconds", "occupied")}
                      for r in log]}


def ngprt_batch(data: str, samples: int) -> dict:
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


def ngprt_bake(run: str, out: str, cull_rays: int) -> dict:
    from clrender.ngprt.bake import bake_run

    bake_run(run, out, n_rays=cull_rays)
    return {"cull_rays": cull_rays, "baked_MB": round(Path(out).stat().st_size / 1e6, 1)}


def render_view(baked: str) -> dict:
    import numpy as np

    import clrender

    model = clrender.load(baked)
    cam = clrender.Camera.from_fov(0.69, VIEW_SIZE, VIEW_SIZE,
                                   clrender.look_at([0.0, -3.0, 1.5]))
    out = clrender.Renderer(model).render(cam)
    return {"size": VIEW_SIZE, "ms": round(float(out["ms"]), 1),
            "finite": bool(np.isfinite(out["rgb"]).all())}


def ngprt_teacher(data: str, run: str, out: str) -> dict:
    """A `tiny` NGP-RT teacher with real geometry (a few-step `paper` model has none)."""
    from clrender.ngprt.bake import bake_run
    from clrender.ngprt.train import train

    bake_run(train(data, run, preset="tiny", progress=False), out)
    return {"preset": "tiny", "baked_MB": round(Path(out).stat().st_size / 1e6, 1)}


def ndrf_train(data: str, run: str, teacher: str, steps: int, views: int,
               N: int | None) -> dict:
    from clrender.ndrf import mesh
    from clrender.ndrf.view_memory import view_budget
    from clrender.ndrf.train import TRAIN_PRESETS, train
    from clrender.runs import pick_device

    tcfg = replace(TRAIN_PRESETS["paper"], iterations=steps, n_distill=views,
                   checkpoint_every=steps)
    if N is not None:             # a cut extraction grid: a preset of this process only
        mesh.PRESETS["smoke"] = replace(mesh.PRESETS[tcfg.extract], N=N)
        tcfg = replace(tcfg, extract="smoke")
    budget = view_budget(pick_device())          # this process's default, measured here
    train(data, run, teacher=teacher, preset="paper", train_config=tcfg, progress=False,
          view_budget=budget)
    meshes = json.loads((Path(run) / "meshes" / "report.json").read_text())["meshes"]
    return {"train": {"iterations": steps, "n_distill": views,
                      "extract_N": mesh.PRESETS[tcfg.extract].N},
            "view_budget_GB": round(budget / 1e9, 2),
            "meshes": [{k: m[k] for k in ("threshold", "vertices", "faces", "seconds")}
                       for m in meshes]}


def ndrf_bake(run: str, out: str) -> dict:
    from clrender.ndrf.train import bake_run

    bake_run(run, out)
    return {"baked_MB": round(Path(out).stat().st_size / 1e6, 1)}


def view_bytes(K: int, height: int, width: int) -> int:
    """Bytes of one training view's arrays in NDRF's ViewSet (shader_torch.py): tri (K, H,
    W) int32 + bary (K, H, W, 2) float32 + the (H, W, 3) float32 target (a distillation
    view's float16 target: 6 bytes a pixel less). Held in memory while a training's views fit
    its view budget (by default half the memory available); beyond it they are disk-backed
    (memory-mapped files) and a view holds ``DISK_BACKED_VIEW_BYTES`` (96) resident."""
    return height * width * (K * (4 + 8) + 12)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench.paper_smoke", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, required=True, help="a bounded dataset folder")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--work", type=Path, default=Path("runs/paper-smoke"),
                   help="run folders and baked files")
    p.add_argument("--steps", type=int, default=3)
    p.add_argument("--occ-fraction", type=float, default=2.0 ** -12)
    p.add_argument("--cull-rays", type=int, default=1 << 10)
    p.add_argument("--distill-views", type=int, default=4)
    p.add_argument("--extract-N", type=int, default=None,
                   help="NDRF's extraction grid (default: the paper preset's, 512)")
    p.add_argument("--batch-samples", type=int, nargs=2, default=[1 << 14, 1 << 16],
                   metavar=("SMALL", "LARGE"),
                   help="NGP-RT: two batch sizes (samples) whose peak memory difference "
                        "gives the training memory per sample")
    p.add_argument("--methods", nargs="+", default=["ngprt", "ndrf"], choices=["ngprt", "ndrf"])
    return p


def main(argv=None) -> int:
    a = build_parser().parse_args(argv)
    w = a.work.resolve()
    w.mkdir(parents=True, exist_ok=True)
    data, baked = str(a.data.resolve()), str(w / "ngprt.npz")
    result = {"data": data, "ndrf_view_MB_800x800_K2": round(view_bytes(2, 800, 800) / 1e6, 2),
              "ndrf_view_resident_B_disk_backed": DISK_BACKED_VIEW_BYTES}
    if "ngprt" in a.methods:
        small, large = (_phase(ngprt_batch, data, n) for n in a.batch_samples)
        per_sample = (large["peak_rss_GB"] - small["peak_rss_GB"]) * 1e9 / max(
            1, large["samples"] - small["samples"])
        result["ngprt_batch"] = {"runs": [small, large], "bytes_per_sample": round(per_sample),
                                 "paper_batch_2^21_GB": round(per_sample * 2 ** 21 / 1e9, 1)}
        result["ngprt_train"] = _phase(ngprt_train, data, str(w / "ngprt"), a.steps,
                                       a.occ_fraction)
        result["ngprt_bake"] = _phase(ngprt_bake, str(w / "ngprt"), baked, a.cull_rays)
        result["ngprt_render"] = _phase(render_view, baked)
    if "ndrf" in a.methods:
        student_teacher = str(w / "teacher-tiny.npz")
        result["ndrf_teacher"] = _phase(ngprt_teacher, data, str(w / "teacher-tiny"),
                                        student_teacher)
        result["ndrf_train"] = _phase(ndrf_train, data, str(w / "ndrf"), student_teacher,
                                      a.steps, a.distill_views, a.extract_N)
        result["ndrf_bake"] = _phase(ndrf_bake, str(w / "ndrf"), str(w / "ndrf.npz"))
        result["ndrf_render"] = _phase(render_view, str(w / "ndrf.npz"))
    text = json.dumps(result, indent=2)
    write_atomic(a.out / "paper-smoke.json", text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
