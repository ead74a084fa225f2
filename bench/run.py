"""Reproduce the papers' tables (NGP-RT, NDRF) on real renders.

    python -m bench.run                     # table4, built-in bounded scene, `cpu` preset
    python -m bench.run table3 --preset tiny
    python -m bench.run all --out results/
    python -m bench.run ndrf-table3 --seeds 3   # mean ± std over seeds 0, 1, 2
    python -m bench.run --list
    python -m bench.run train-curve         # test PSNR vs training minutes, `cpu` and `tiny`
    python -m bench.run train-curve --method ndrf --preset tiny
    python -m bench.run table3 --seeds 3 --executor ray [--address auto]   # rows as Ray tasks

Trains what is missing (models cached by a hash of config and data, shared across
tables), bakes, renders every test view with the OpenCL renderer and writes
``results/TABLE.{md,csv,json,png}`` plus a sample render per row, then
``results/README.md`` listing every table found there. With ``--executor ray`` the missing
models are trained as Ray tasks first (bench/cluster.py), then measured here. ``train-curve``
(bench/train_curve.py) writes ``results/train-curve.{csv,png}``.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import sys
from pathlib import Path

from tqdm import tqdm

from bench import ablation, cache, cluster, provenance, report, seeds, train_curve
from bench.fingerprint import code_fingerprint
from clrender import methods
from clrender.cliopts import whole_number


def run_table(table, data: Path, fingerprint: str, args, meta: dict,
              session: cluster.Session | None = None) -> str:
    """Train/bake what is missing (as Ray tasks of ``session`` first, when given), measure
    every row for each seed, write the table's files (their JSON lists the cache entries
    used, each with what trained it)."""
    from bench.measure import measure_row
    from clrender.data import load_dataset

    test_set = load_dataset(data, split="test", downscale=args.downscale)
    seed_list = list(range(args.seed, args.seed + args.seeds))
    if session is not None:
        session.train_all([cache.plan_model(args.cache, data, fingerprint,
                                            args.preset or table.preset, row.method, row.model,
                                            seed=seed, downscale=args.downscale)
                           for row in table.rows for seed in seed_list], f"{table.key} train")
    measured, entries, used = {}, {}, {}
    with tqdm(total=len(table.rows) * len(seed_list), desc=table.key, unit="model") as bar:
        for row in table.rows:
            for seed in seed_list:
                entry = cache.ensure_model(args.cache, data, fingerprint,
                                           args.preset or table.preset, row.method, row.model,
                                           seed=seed, torch_device=args.torch_device,
                                           downscale=args.downscale)
                m = measure_row(entry.baked, test_set, row.render, device=args.device,
                                repeats=args.repeats, timing_sizes=table.timing_sizes)
                measured[row.name, seed] = m.of_model(entry.train_minutes, entry.key)
                entries[row.name, seed] = entry
                used[entry.key] = entry.trained_by
                bar.update()
    _pair_rows(table, measured, entries, test_set, seed_list, args)
    results = [seeds.aggregate([measured[row.name, seed] for seed in seed_list], seed_list)
               for row in table.rows]
    cam = test_set.cameras[0]
    meta = {**meta, "resolution": f"{cam.width}x{cam.height}",
            "code": {m: code_fingerprint(m) for m in sorted({r.method for r in table.rows})},
            "cache": {"root": str(args.cache), "models": used}}
    return report.write_table(args.out, table, results, meta)


def _pair_rows(table, measured: dict, entries: dict, test_set, seed_list, args) -> None:
    """Each row with a baseline timed against it as interleaved pairs, per seed (the
    baseline's model of the same seed; :func:`bench.measure.measure_pair`), into
    ``measured[row, seed]``'s ``paired_speedup``, ``paired_at`` and ``same_image``."""
    from dataclasses import replace

    from bench.measure import measure_pair

    rows = {row.name: row for row in table.rows}
    for row in table.rows:
        if row.baseline is None or row.baseline == row.name:
            continue
        base = rows[row.baseline]
        for seed in seed_list:
            pair = measure_pair(entries[row.name, seed].baked, row.render,
                                entries[base.name, seed].baked, base.render, test_set,
                                device=args.device, repeats=args.repeats,
                                stage=table.paired_stage, sizes=table.paired_sizes,
                                same_image=table.same_image)
            measured[row.name, seed] = replace(measured[row.name, seed], **pair)
            check = pair["same_image"]
            if check is not None and not check["identical"]:
                print(f"bench.run: WARNING: {table.key} row {row.name!r} (seed {seed}) does "
                      f"not render its baseline {base.name!r}'s image: max |diff| "
                      f"{check['max_diff']:.3g}", file=sys.stderr)


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
                        f"(default {methods.default()})")
    p.add_argument("--scene", default=None,
                   help="builtin-bounded | builtin-unbounded | a dataset folder (default: the table's)")
    p.add_argument("--downscale", type=int, default=1, metavar="N",
                   help="of a --scene folder: read its images_N/, else shrink its images N "
                        "times (default 1)")
    p.add_argument("--option", action="append", default=None, metavar="NAME=V1,V2",
                   help=f"{train_curve.KEY}: a curve for each value of one of the method's "
                        f"training options (e.g. engine=torch,fast), compared with the first "
                        f"at equal steps when --seeds >= 2; repeated, options of one value "
                        f"hold for every curve (--option L=4 --option variant=separate-v,sum)")
    p.add_argument("--test-stride", type=whole_number("test stride"), default=1, metavar="K",
                   help=f"{train_curve.KEY}: score every K-th test view (default 1: all)")
    p.add_argument("--points", type=whole_number("points"), default=train_curve.N_POINTS,
                   metavar="N", help=f"{train_curve.KEY}: evaluations along a run, the first "
                                     f"and last step included (default {train_curve.N_POINTS})")
    p.add_argument("--iterations", type=whole_number("iterations"), default=None, metavar="N",
                   help=f"{train_curve.KEY}: train N steps instead of the preset's (a budget of "
                        f"equal minutes for presets or engines of different step times)")
    p.add_argument("--device", default=None, help="OpenCL device spec (see `clrender info`)")
    p.add_argument("--torch-device", default=None, help="torch device for training")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--cache", type=Path, default=None,
                   help="model/scene cache folder (default $CLRENDER_CACHE, else "
                        "~/.cache/clrender); with --executor ray the driver's")
    p.add_argument("--executor", choices=("inprocess", "ray"), default="inprocess",
                   help="where missing models train: one after another in this process "
                        "(default), or as Ray tasks (pip install 'clrender[cluster]')")
    p.add_argument("--address", default=None,
                   help="--executor ray: the cluster to join (`auto`, `ray://HOST:PORT`); "
                        "default: a local Ray instance on this machine's cores")
    p.add_argument("--repeats", type=int, default=5, help="timing passes per row")
    p.add_argument("--seed", type=int, default=0, help="training seed (the first one)")
    p.add_argument("--seeds", type=whole_number("seeds"), default=1,
                   help="train and measure every row for seeds SEED..SEED+N-1 (fixed before "
                        "the run) and report mean ± std and the paper's claims' verdicts "
                        "(default 1)")
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
        args.method = args.method or methods.default()
        args.preset = None if curve else (args.presets or [None])[0]
        if args.downscale < 1:
            raise ValueError(f"--downscale {args.downscale}: expected a whole number >= 1")
        if not curve and (args.option is not None or args.test_stride != 1
                          or args.points != train_curve.N_POINTS or args.iterations is not None):
            raise ValueError(f"--option, --test-stride, --points and --iterations are for "
                             f"{train_curve.KEY}")
        if (curve or args.executor != "ray") and args.address is not None:
            raise ValueError("--address is for --executor ray")
        if curve and args.executor == "ray":
            raise ValueError(f"--executor ray is for tables, not {train_curve.KEY}")
        args.cache = args.cache or cache.cache_root()
        from clrender.device import get_runtime

        meta = {"device": get_runtime(args.device).name, "git_revision": provenance.git_revision(),
                "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
        if curve:
            print(train_curve.run(args, meta))
        with (cluster.Session(args.address, args.torch_device) if args.executor == "ray"
              else contextlib.nullcontext()) as session:
            for table in tables:
                scene = args.scene or table.scene
                data = cache.resolve_scene(scene, args.cache)
                fingerprint = cache.data_fingerprint(data, args.downscale)
                meta.update(preset=args.preset or table.preset, scene=scene
                            if args.downscale == 1 else f"{scene} (downscale {args.downscale})")
                print(run_table(table, data, fingerprint, args, meta, session))
        report.write_index(args.out)
        print(f"results written to {args.out}/")
    except ValueError as exc:
        print(f"bench.run: error: {exc}", file=sys.stderr)
        return 2
    except cluster.TaskFailed as exc:
        print(f"bench.run: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
