"""The paper's march with G, one change at a time (issues 45, 46): the G step as it was
(cut at every piece of an unbounded ray's lattice), cut only where the contracted path
jumps, with G of the paper's centre metric, and our march, each against the paper's march
without G; for one or more bakes of a model (e.g. its preset grids and the paper's).

    git archive f7bec39 kernels | tar -x -C /tmp/every-piece     # the step as it was
    python -m bench.studies.ngprt_g_step MODEL.npz --data data/bonsai --downscale 2 \\
        --old-kernels /tmp/every-piece/kernels --out results/
    clrender bake RUN --out paper.npz --grids paper               # the paper's grids
    python -m bench.studies.ngprt_g_step MODEL.npz paper.npz --data data/bonsai --downscale 2

For each row: marching, occupied and empty points per ray and the occupancy + G reads
per ray (means over every test view), PSNR against the test images and against the
march without G (inf: the same image bit for bit), and the march kernel's time against
the march without G as interleaved pairs (:func:`bench.tables.measure.time_pairs`) on the
first ``--views`` test cameras, ``--repeats`` rounds, at the test size and at each
``--sizes``. The centre metric's model is ``MODEL`` with G rebuilt from its occupancy
(what ``clrender bake --G-metric centre`` writes: the bakes differ in G alone). Writes
``OUT/ngprt_g_step_<stems>.{md,json}`` (one table, each model's rows against its own
march without G); asserts nothing.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bench.speed.sizes import at_size, parse_size
from bench.tables.measure import time_pairs
from clrender import methods
from clrender.atomic import write_atomic
from clrender.metrics import psnr

STATS = (("Marching", "n_march"), ("Occupied", "n_occ"), ("Empty", "n_empty"),
         ("Skip reads", "n_skip_reads"))


def centre_variant(model):
    """``model`` with G of the paper's centre metric, rebuilt from its occupancy."""
    from clrender.ngprt.baked import validate, with_G_metric

    out = with_G_metric(model, "centre")
    validate(out, "centre-metric variant")
    return out


def row_stats(renderer, base_images: list, test_set) -> dict:
    """Means over the test views of :data:`STATS`, the mean PSNR against the images and,
    against ``base_images`` (the march without G), whether every view is the same image
    bit for bit and else the lowest PSNR; ``images`` the renders."""
    sums = {name: 0.0 for name, _ in STATS}
    images, vs_truth, vs_base = [], [], []
    for i, (cam, truth) in enumerate(zip(test_set.cameras, test_set.images)):
        out = renderer.render(cam, background=test_set.background, stats=True)
        for name, key in STATS:
            sums[name] += float(out[key].mean())
        images.append(out["rgb"])
        vs_truth.append(psnr(out["rgb"], truth))
        if base_images:
            vs_base.append(psnr(out["rgb"], base_images[i]))      # inf: the same image
    n = len(test_set.cameras)
    worst = float(np.min(vs_base)) if vs_base else None
    return {**{k: v / n for k, v in sums.items()}, "PSNR": float(np.mean(vs_truth)),
            "same image": None if worst is None else bool(np.isinf(worst)),
            "PSNR vs w/o G": None if worst is None or np.isinf(worst) else worst,
            "images": images}


def measure(model_path: Path, test_set, old_kernels: Path | None, views: int, repeats: int,
            sizes, device=None) -> list[dict]:
    """Every row's statistics and pairs against the march without G (of ``model_path``)."""
    Renderer = methods.get("ngprt").renderer
    model = methods.load(model_path)
    rows = [("paper w/o G", model, {"use_G": False}),
            ("w/ G, cut at jumps (box)", model, {}),
            ("w/ G, cut at jumps, centre metric", centre_variant(model), {}),
            ("ours (box)", model, {"march": "ours"})]
    if old_kernels is not None:
        rows.insert(1, ("w/ G, cut at every piece (box)", model,
                        {"kernel_dir": str(old_kernels)}))
    base = Renderer(model, device=device, march="paper", use_G=False)
    cams = test_set.cameras[:views]
    out, base_images = [], []
    grids = f"{model.config.occ_res}^3 / G {model.config.G_res}^3"
    for name, m, options in rows:
        r = Renderer(m, device=device, **{"march": "paper", "use_G": True, **options})
        stats = row_stats(r, base_images, test_set)
        base_images = base_images or stats["images"]
        rec = {"row": f"{name}, {grids}", **{k: v for k, v in stats.items() if k != "images"}}
        if options.get("use_G", True):
            rec["pairs"] = {"test": _pairs(r, base, cams, repeats, test_set)}
            for size in sizes:
                w, h = parse_size(size)
                rec["pairs"][size] = _pairs(r, base, [at_size(c, w, h) for c in cams],
                                            repeats, test_set)
        out.append(rec)
    return out


def _pairs(row, base, cams, repeats: int, test_set) -> dict:
    p = time_pairs(row, base, cams, repeats, "march", test_set.background)
    return {k: v for k, v in p.items() if k != "ratios"}


def markdown(rows: list[dict], meta: dict) -> str:
    sizes = list(next(r["pairs"] for r in rows if "pairs" in r))
    head = ["row", *(n for n, _ in STATS), "PSNR", "PSNR vs w/o G",
            *(f"march speed-up at {s}" for s in sizes)]
    lines = [f"# The paper's march with G, one change at a time: {meta['model']}", "",
             f"{meta['data']} (downscale {meta['downscale']}), {meta['views']} test views; "
             f"{meta['device']}; git {meta['git_revision']}, {meta['date']}.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["row"], *(f"{r[n]:.2f}" for n, _ in STATS), f"{r['PSNR']:.2f}",
                 "" if r["same image"] is None else "same image" if r["same image"]
                 else f"{r['PSNR vs w/o G']:.2f} (lowest view)"]
        for s in sizes:
            p = r.get("pairs", {}).get(s)
            cells.append("" if p is None else f"{p['ratio']:.3f}x [{p['lo']:.3f}, "
                         f"{p['hi']:.3f}] ({p['ms_baseline']:.1f} -> {p['ms_row']:.1f} ms, "
                         f"{p['n']} pairs)")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    from bench import options
    from clrender.data import load_dataset

    p = argparse.ArgumentParser(prog="python -m bench.studies.ngprt_g_step",
                                description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("models", type=Path, nargs="+",
                   help="baked NGP-RT models (box metric), e.g. one bake at each grids")
    p.add_argument("--data", type=Path, required=True, help="its dataset folder")
    p.add_argument("--downscale", type=int, default=1)
    p.add_argument("--old-kernels", type=Path, default=None,
                   help="kernel sources of the step cut at every piece (a row of its own)")
    p.add_argument("--views", type=int, default=4, help="test cameras timed (default 4)")
    p.add_argument("--repeats", type=int, default=5, help="rounds of pairs (default 5)")
    p.add_argument("--sizes", nargs="*", default=["1920x1080"], metavar="WxH")
    p.add_argument("--device", default=None)
    p.add_argument("--out", type=Path, default=Path("results"))
    args = p.parse_args(argv)
    test_set = load_dataset(args.data, split="test", downscale=args.downscale)
    rows = [row for path in args.models for row in measure(
        path, test_set, args.old_kernels, args.views, args.repeats, args.sizes, args.device)]
    meta = {**options.run_meta(args.device), "model": ", ".join(map(str, args.models)),
            "data": str(args.data), "downscale": args.downscale,
            "views": len(test_set.cameras)}
    text = markdown(rows, meta)
    stem = args.out / f"ngprt_g_step_{'_'.join(m.stem for m in args.models)}"
    write_atomic(stem.with_suffix(".json"), json.dumps({**meta, "rows": rows}, indent=2))
    write_atomic(stem.with_suffix(".md"), text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
