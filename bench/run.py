"""Reproduce the papers' tables (NGP-RT, NDRF) on real renders.

    python -m bench.run                     # table4, built-in bounded scene, `cpu` preset
    python -m bench.run table3 --preset tiny
    python -m bench.run all --out results/
    python -m bench.run ndrf-table3 --seeds 3   # mean ± std over seeds 0, 1, 2
    python -m bench.run --list
    python -m bench.run train-curve         # test PSNR vs training minutes, `cpu` and `tiny`
    python -m bench.run train-curve --method ndrf --preset tiny

Trains what is missing (models cached by a hash of config and data, shared across
tables), bakes, renders every test view with the OpenCL renderer and writes
``results/TABLE.{md,csv,json,png}`` plus a sample render per row, then
``results/README.md`` listing every table found there. ``train-curve``
(bench/train_curve.py) writes ``results/train-curve.{csv,png}``.
"""
from __future__ import annotations

import argparse
import datetime
import subprocess
import sys
from pathlib import Path

from tqdm import tqdm

from bench import ablation, cache, report, seeds, train_curve
from clrender import methods
from clrender.cliopts import whole_number


def _git_revision() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True, cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def run_table(table, data: Path, fingerprint: str, args, meta: dict) -> str:
    """Train/bake what is missing, measure every row for each seed, write the table's files."""
    from bench.measure import measure_row
    from clrender.data import load_dataset

    test_set = load_dataset(data, split="test", downscale=args.downscale)
    seed_list = list(range(args.seed, args.seed + args.seeds))
    results = []
    with tqdm(total=len(table.rows) * len(seed_list), desc=table.key, unit="model") as bar:
        for row in table.rows:
            per_seed = []
            for seed in seed_list:
                entry = cache.ensure_model(args.cache, data, fingerprint,
                                           args.preset or table.preset, row.method, row.model,
                                           seed=seed, torch_device=args.torch_device,
                                           downscale=args.downscale)
                m = measure_row(entry.baked, test_set, row.render, device=args.device,
                                repeats=args.repeats, timing_sizes=table.timing_sizes)
                per_seed.append(m.of_model(entry.train_minutes, entry.key))
                bar.update()
            results.append(seeds.aggregate(per_seed, seed_list))
    cam = test_set.cameras[0]
    meta = {**meta, "resolution": f"{cam.width}x{cam.height}"}
    return report.write_table(args.out, table, results, meta)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench.run", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("table", nargs="?", default="table4",
                   help=f"a table name, `all`, or `{train_curve.KEY}`")
    p.add_argument("--list", action="store_true", help="list the tables and exit")
    p.add_argument("--preset", dest="presets", choices=methods.all_presets(), action="append",
                   default=None,
                   help="model/training preset (default: the table's, `cpu`); "
                        f"{train_curve.KEY} takes it more than once "
                        f"(default: {' and '.join(train_curve.PRESETS)})")
    p.add_argument("--method", default=None, choices=methods.names(),
                   help=f"{train_curve.KEY}: the method whose curve is measured "
                        f"(default {methods.DEFAULT})")
    p.add_argument("--scene", default=None,
                   help="builtin-bounded | builtin-unbounded | a dataset folder (default: the table's)")
    p.add_argument("--downscale", type=int, default=1, metavar="N",
                   help="of a --scene folder: read its images_N/, else shrink its images N "
                        "times (tables only; default 1)")
    p.add_argument("--device", default=None, help="OpenCL device spec (see `clrender info`)")
    p.add_argument("--torch-device", default=None, help="torch device for training")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--cache", type=Path, default=None, help="model/scene cache folder")
    p.add_argument("--repeats", type=int, default=5, help="timing passes per row")
    p.add_argument("--seed", type=int, default=0, help="training seed (the first one)")
    p.add_argument("--seeds", type=whole_number("seeds"), default=1,
                   help="train and measure every row for seeds SEED..SEED+N-1 and report "
                        "mean ± std (default 1)")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.list:
        for key in ablation.list_tables():
            t = ablation.load_table(key)
            print(f"{key:16s} {t.title} ({len(t.rows)} rows)")
        print(f"{train_curve.KEY:16s} {train_curve.TITLE} (not in `all`)")
        return 0
    try:
        curve = args.table == train_curve.KEY
        keys = [] if curve else ablation.list_tables() if args.table == "all" else [args.table]
        tables = [ablation.load_table(k) for k in keys]
        if not curve and len(args.presets or ()) > 1:
            raise ValueError(f"a table takes one --preset, got {', '.join(args.presets)}")
        if not curve and args.method is not None:
            raise ValueError(f"--method is for {train_curve.KEY}; a table names its methods")
        args.method = args.method or methods.DEFAULT
        args.preset = None if curve else (args.presets or [None])[0]
        if args.downscale < 1 or (curve and args.downscale != 1):
            raise ValueError(f"--downscale {args.downscale}: expected a whole number >= 1, "
                             f"for tables only (not {train_curve.KEY})")
        args.cache = args.cache or cache.cache_root()
        from clrender.device import get_runtime

        meta = {"device": get_runtime(args.device).name, "git_revision": _git_revision(),
                "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
        if curve:
            print(train_curve.run(args, meta))
        for table in tables:
            scene = args.scene or table.scene
            data = cache.resolve_scene(scene, args.cache)
            fingerprint = cache.data_fingerprint(data, args.downscale)
            meta.update(preset=args.preset or table.preset, scene=scene if args.downscale == 1
                        else f"{scene} (downscale {args.downscale})")
            print(run_table(table, data, fingerprint, args, meta))
        report.write_index(args.out)
        print(f"results written to {args.out}/")
    except ValueError as exc:
        print(f"bench.run: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
