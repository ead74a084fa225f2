"""NDRF's steps of ``bench.speed.paper_smoke`` (its ``PAPER_SMOKE``): a `tiny` NGP-RT teacher with
real geometry (a few-step `paper` teacher has none to extract meshes from; the student's
sizes do not depend on the teacher's), a few `paper` training steps with cut distillation
views (and optionally a cut extraction grid), a bake, a render; and the bounds of a
training view's memory. Each step runs in a child process of its own (``phase``)."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

DISK_BACKED_VIEW_BYTES = 96  # = clrender.ndrf.view_memory's (tests/test_paper_smoke.py)


def run(data: str, work: Path, cuts: dict, phase, render) -> dict:
    """The steps' results by name (see :func:`clrender.ngprt.paper_smoke.run`)."""
    teacher = str(work / "teacher-tiny.npz")
    return {"view_MB_800x800_K2": round(view_bytes(2, 800, 800) / 1e6, 2),
            "view_resident_B_disk_backed": DISK_BACKED_VIEW_BYTES,
            "teacher": phase(tiny_teacher, data, str(work / "teacher-tiny"), teacher),
            "train": phase(train_steps, data, str(work / "ndrf"), teacher, cuts["steps"],
                           cuts["distill_views"], cuts["extract_N"]),
            "bake": phase(bake, str(work / "ndrf"), str(work / "ndrf.npz")),
            "render": render(str(work / "ndrf.npz"))}


def tiny_teacher(data: str, run: str, out: str) -> dict:
    """A `tiny` NGP-RT teacher with real geometry (a few-step `paper` model has none)."""
    from clrender.ngprt.bake import bake_run
    from clrender.ngprt.train import train

    bake_run(train(data, run, preset="tiny", progress=False), out)
    return {"preset": "tiny", "baked_MB": round(Path(out).stat().st_size / 1e6, 1)}


def train_steps(data: str, run: str, teacher: str, steps: int, views: int,
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


def bake(run: str, out: str) -> dict:
    from clrender.ndrf.train import bake_run

    bake_run(run, out)
    return {"baked_MB": round(Path(out).stat().st_size / 1e6, 1)}


def view_bytes(K: int, height: int, width: int) -> int:
    """Bytes of one training view's arrays in NDRF's ViewSet (shader_torch.py): tri (K, H,
    W) int32 + bary (K, H, W, 2) float32 + the (H, W, 3) float32 target (a distillation
    view's float16 target: 6 bytes a pixel less). Held in memory while a training's views fit
    its view budget (by default half the memory available); beyond it they are disk-backed
    (memory-mapped files) and a view holds :data:`DISK_BACKED_VIEW_BYTES` (96) resident."""
    return height * width * (K * (4 + 8) + 12)
