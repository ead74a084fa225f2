"""Reproduce the papers' tables (NGP-RT, NDRF) on real renders.

    python -m bench.run                     # table4, built-in bounded scene, `cpu` preset
    python -m bench.run table3 --preset tiny
    python -m bench.run all --out results/
    python -m bench.run ndrf-table3 --seeds 3   # mean ± std over seeds 0, 1, 2
    python -m bench.run --list
    python -m bench.run table3 --seeds 3 --executor ray [--address auto]   # rows as Ray tasks

Trains what is missing (models cached by a hash of config and data, shared across
tables), bakes, renders every test view with the OpenCL renderer and writes
``results/TABLE.{md,csv,json,png}`` plus a sample render per row, then
``results/README.md`` listing every table found there. A table's JSON records the command
that made it (``argv``), its scene and cache folder as a user types them (relative to the
working directory, or ``~/...``: :func:`bench.options.shown_path`). With ``--executor
ray`` the missing models are trained as Ray tasks first (bench/modelcache/cluster.py),
then measured here.
``python -m bench.run train-curve ARGS`` is ``python -m bench.train_curve ARGS``.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

from tqdm import tqdm

from bench import options, train_curve
from bench.modelcache import cache, cluster
from bench.modelcache.fingerprint import code_fingerprint
from bench.tables import ablation, command, report, seeds
from bench.tools import public_scenes
from clrender import methods
from clrender.cli import USER_ERRORS, one_line_error


def run_table(table, data: Path, fingerprint: str, args, meta: dict,
              session: cluster.Session | None = None, started: float | None = None) -> str:
    """Train/bake what is missing (as Ray tasks of ``session`` first, when given), measure
    every row for each seed, write the table's files (their JSON lists the cache entries
    used, each with what trained it, and ``wall_s``: seconds since ``started``, the
    table's start by ``time.monotonic``, default this call's)."""
    from bench.tables.measure import measure_row
    from clrender.data import load_dataset

    started = time.monotonic() if started is None else started
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
                entry = cache.ensure_baked(entry, row.method, row.bake)
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
            "cache": {"root": options.shown_path(args.cache), "models": used},
            "wall_s": round(time.monotonic() - started, 1)}
    return report.write_table(args.out, table, results, meta)


def _pair_rows(table, measured: dict, entries: dict, test_set, seed_list, args) -> None:
    """Each row with a baseline timed against it as interleaved pairs, per seed (the
    baseline's model of the same seed; :func:`bench.tables.measure.measure_pair`), into
    ``measured[row, seed]``'s ``paired_speedup``, ``paired_at`` and ``same_image``; and
    each comparison of a row against another than its baseline, at the test size, into
    its ``paired_with``."""
    from dataclasses import replace

    from bench.tables.measure import measure_pair

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
            if check is not None and not check["identical"] and table.row_same_image(row):
                print(f"bench.run: WARNING: {table.key} row {row.name!r} (seed {seed}) does "
                      f"not render its baseline {base.name!r}'s image: max |diff| "
                      f"{check['max_diff']:.3g}", file=sys.stderr)
    for c in table.comparisons:
        row, other = rows[c.row], rows[c.against]
        if row.baseline == other.name:
            continue
        for seed in seed_list:
            pair = measure_pair(entries[row.name, seed].baked, row.render,
                                entries[other.name, seed].baked, other.render, test_set,
                                device=args.device, repeats=args.repeats,
                                stage=table.paired_stage)["paired_speedup"]
            m = measured[row.name, seed]
            measured[row.name, seed] = replace(m, paired_with={**m.paired_with,
                                                               other.name: pair})


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench.run", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("table", nargs="?", default="table4", help="a table name or `all`")
    p.add_argument("--list", action="store_true", help="list the tables and exit")
    p.add_argument("--preset", dest="presets", choices=methods.all_presets(), action="append",
                   default=None, help="model/training preset (default: the table's, `cpu`)")
    options.add_common(p)
    p.add_argument("--executor", choices=("inprocess", "ray"), default="inprocess",
                   help="where missing models train: one after another in this process "
                        "(default), or as Ray tasks (pip install 'clrender[cluster]'; the "
                        "cache is the driver's)")
    p.add_argument("--address", default=None,
                   help="--executor ray: the cluster to join (`auto`, `ray://HOST:PORT`); "
                        "default: a local Ray instance on this machine's cores")
    p.add_argument("--repeats", type=int, default=5, help="timing passes per row")
    p.add_argument("--bake", action="append", default=[], metavar="NAME=VALUE",
                   help="a bake option of the table's method on every row (e.g. NGP-RT's "
                        "grids=preset or grids=paper); results under TABLE-NAME-VALUE")
    return p


def bake_options(given: list[str]) -> dict:
    """``{name: value}`` of ``--bake NAME=VALUE`` arguments (values as text: the bake
    options that tables vary are choices of words)."""
    out = {}
    for item in given:
        name, sep, value = item.partition("=")
        if not sep or not name or not value:
            raise ValueError(f"--bake {item!r}: expected NAME=VALUE")
        out[name] = value
    return out


def _one_table(argv: list[str], key: str) -> list[str]:
    """The arguments that run the table ``key`` alone: ``all`` replaced by its name."""
    return [key if a == "all" else a for a in argv]


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == [train_curve.KEY]:
        return train_curve.main(argv[1:])
    args = build_parser().parse_args(argv)
    if args.list:
        for key in ablation.list_tables():
            t = ablation.load_table(key)
            print(f"{key:16s} {t.title} ({len(t.rows)} rows)")
        print(f"{train_curve.KEY:16s} {train_curve.TITLE} (python -m bench.train_curve; "
              f"not in `all`)")
        return 0
    try:
        keys = ablation.list_tables() if args.table == "all" else [args.table]
        overrides = bake_options(args.bake)
        tables = [ablation.with_bake(ablation.load_table(k), overrides) for k in keys]
        if len(args.presets or ()) > 1:
            raise ValueError(f"a table takes one --preset, got {', '.join(args.presets)}")
        args.preset = (args.presets or [None])[0]
        if args.executor != "ray" and args.address is not None:
            raise ValueError("--address is for --executor ray")
        args.cache = args.cache or cache.cache_root()
        meta = options.run_meta(args.device)
        if command.is_dirty(meta):
            print(f"bench.run: WARNING: git {meta['git_revision']}: uncommitted changes; the "
                  "results pages mark this run as not reproducible from a commit",
                  file=sys.stderr)
        with (cluster.Session(args.address, args.torch_device) if args.executor == "ray"
              else contextlib.nullcontext()) as session:
            for key, table in zip(keys, tables):
                started = time.monotonic()     # the table's wall time includes its scene
                scene = args.scene or table.scene
                data = cache.resolve_scene(scene, args.cache)
                fingerprint = cache.data_fingerprint(data, args.downscale)
                meta.update(argv=command.recorded(_one_table(argv, key)),
                            preset=args.preset or table.preset,
                            scene=options.shown_scene(scene, args.downscale),
                            public_scene=public_scenes.identify(data))
                print(run_table(table, data, fingerprint, args, meta, session, started))
        report.write_index(args.out)
        print(f"results written to {args.out}/")
    except USER_ERRORS as exc:
        return one_line_error("bench.run", exc)
    except cluster.TaskFailed as exc:
        print(f"bench.run: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
