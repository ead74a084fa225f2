"""The `paper` preset's smoke run: a few training steps of each method at the papers' sizes,
bake, render one small view; the time and peak resident memory of every phase.

    python -m bench.speed.paper_smoke --data data/lego --out results/

What it catches is what a GPU user's first `paper` run would die on (a shape, an
allocation, an hour of set-up), at CPU cost. Each method that declares a ``paper_smoke``
(:class:`clrender.contract.PaperSmoke`) runs its own steps; model sizes, optimiser and batch
budget are its `paper` preset's, and only the amounts of work that scale with the number of
cells or views and not with the model are cut, by its declared options (flags here), the
cuts written into the result. NGP-RT's (clrender/ngprt/paper_smoke.py):
- its occupancy update: the paper re-evaluates all 512^3 cells at every update of its
  first 256 steps (each cell's sample runs the auxiliary NGP at its 8 corners): on 2 CPU
  cores that pass alone is ~10^4 s. Here: no warm-up (``occ_warmup=0``) and a
  ``--occ-fraction`` of the cells per update, so step 0 samples ~2 x 2^27 x fraction cells;
- visibility culling at bake: ``--cull-rays`` training rays instead of 2^18;
- since a few-step model occupies few cells, the `paper` batch (up to 2^21 samples) is
  measured apart: one training step at full occupancy at two batch sizes, their peak memory
  difference per sample extrapolated to 2^21 samples.
NDRF's (clrender/ndrf/paper_smoke.py): ``--distill-views`` distillation views instead of
1000, from a `tiny` NGP-RT teacher trained there; its extraction grid is the paper's (512^3)
unless ``--extract-N`` cuts it. Its views are not extrapolated but bounded: the report gives
a view's bytes at 800x800 (in memory within the training's view budget) and what a
disk-backed view keeps resident.
Each phase runs in a child process of its own (spawned), so its peak resident memory
(``ru_maxrss``) is its own. Writes ``OUT/paper-smoke.json`` ({method: {step: result}}) and
prints it.
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

from clrender import methods
from clrender.atomic import write_atomic

VIEW_SIZE = 64               # the rendered view's side (pixels)


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


def render_view(baked: str) -> dict:
    import numpy as np

    import clrender

    model = clrender.load(baked)
    cam = clrender.Camera.from_fov(0.69, VIEW_SIZE, VIEW_SIZE,
                                   clrender.look_at([0.0, -3.0, 1.5]))
    out = clrender.Renderer(model).render(cam)
    return {"size": VIEW_SIZE, "ms": round(float(out["ms"]), 1),
            "finite": bool(np.isfinite(out["rgb"]).all())}


def _render(baked: str) -> dict:
    return _phase(render_view, baked)


def smoked() -> dict:
    """{method: its :class:`clrender.contract.PaperSmoke`} of the methods declaring one."""
    return {n: bench.paper_smoke for n, bench in methods.benched().items()
            if bench.paper_smoke is not None}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench.speed.paper_smoke", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, required=True, help="a bounded dataset folder")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--work", type=Path, default=Path("runs/paper-smoke"),
                   help="run folders and baked files")
    p.add_argument("--steps", type=int, default=3, help="training steps of each method")
    steps = smoked()
    flags = {}
    for name, smoke in steps.items():
        for opt_name, opt in smoke.options.items():
            if opt_name not in flags:
                flags[opt_name] = name
                p.add_argument(opt.cli_flag(opt_name), dest=opt_name, type=opt.type,
                               default=opt.default, nargs=opt.nargs,
                               help=f"{name}: {opt.help} (default: {opt.default})")
    p.add_argument("--methods", nargs="+", default=list(steps), choices=list(steps))
    return p


def main(argv=None) -> int:
    a = build_parser().parse_args(argv)
    w = a.work.resolve()
    w.mkdir(parents=True, exist_ok=True)
    data, cuts = str(a.data.resolve()), vars(a)
    result = {"data": data}
    for name in a.methods:
        (w / name).mkdir(exist_ok=True)
        result[name] = smoked()[name].run(data, w / name, cuts, _phase, _render)
    text = json.dumps(result, indent=2)
    write_atomic(a.out / "paper-smoke.json", text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
