"""Kernel timings of the OpenCL NGP-RT renderer: a random structured model, or a trained one.

    python -m bench.speed.ngprt_kernels                       # 400x400, `cpu` preset, 5 repeats
    python -m bench.speed.ngprt_kernels --size 800            # the 800x800 frame
    python -m bench.speed.ngprt_kernels --size 200 --repeats 3 --preset tiny --out results/
    python -m bench.speed.ngprt_kernels --L-C 256             # finer grids: G has more to skip
    python -m bench.speed.ngprt_kernels --exact               # the exact build (tests' build)
    python -m bench.speed.ngprt_kernels --baseline /tmp/old_kernels --variant separate-v
    python -m bench.speed.ngprt_kernels --model M.npz --data DIR   # trained: test cameras, 3 sizes

Random model: for every aggregation variant (``--variant``: some), with and without the
occupancy distance grid G, renders one orbit view and reports the march and deferred-MLP
kernel times (OpenCL profiling events; median and p10-p90 over the repeats, after one
warm-up render), the marching and occupied points per ray, each stage's bound and the
ratio time / bound (:mod:`bench.speed.limits`: the stage's own counters at the gather and FLOP
rates measured on the device in the same run), and the speed-ups, each the geometric mean
over ``--repeats`` interleaved pairs with its 95% interval
(:func:`bench.tables.measure.time_pairs`, on the frame's kernel time): each variant against
``mlp``, G on against G off. The numpy reference is timed once per variant (with G) on a
smaller frame (``--ref-size``) and scaled by the pixel count: its ratio to the OpenCL time
is a scale, not a paired speed-up; the table says so. Writes
``<out>/ngprt_kernels.{json,md}``.

Trained model (``--model M.npz --data DIR``): its one variant, with G, on the first
``--views`` test cameras of DIR at the test size and at ``--sizes`` (default 800x800 and
1920x1080; each test camera through ``Camera.scaled_to``, the pixel aspect kept:
:func:`bench.speed.sizes.at_size`), the same columns per frame size. Writes
``<out>/ngprt_kernels_<model stem>.{json,md}``.

``--baseline DIR`` renders every row with the kernel sources of DIR too (e.g. a copy of an
older ``kernels/``), interleaved with the installed ones, and adds their time, the
speed-up over those pairs (geometric mean, 95% interval) and whether images and counters
agree. Never asserts.
"""
from __future__ import annotations

import argparse
import datetime
import functools
import json
import time
from pathlib import Path

import numpy as np

from bench.options import shown_path
from bench.speed.ngprt_bounds import (MARCH_PIXEL_BYTES, deferred_bound, march_bound,
                                      measure_limits)
from bench.speed.sizes import at_size, parse_size, trained_test_set
from bench.tables.compare import speedup_cell
from bench.tables.measure import speedup_interval, time_pairs
from clrender.atomic import write_atomic
from clrender.cliopts import whole_number
from clrender.device import get_runtime
from clrender.metrics import summarize_ms
from clrender.ngprt.baked import load_baked
from clrender.ngprt.config import VARIANTS, preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer
from clrender.ngprt.render_ref import render_reference
from clrender.paths import path_cameras


def _camera(scene: str, size: int):
    return path_cameras(scene, "orbit", 8, size, size)[1]


def measure(model, cameras, use_G: bool, repeats: int, device=None, exact: bool = False,
            limits: dict | None = None, baseline=None, background=(1.0, 1.0, 1.0)) -> dict:
    """Kernel times (ms), points per ray and (given ``limits``) each stage's bound of one
    model over ``cameras`` (one frame each, after a warm-up render that reads the
    counters), G on or off; times are summarised over every camera and repeat, counters
    and bounds are per frame, means over the cameras.

    With ``baseline`` (a folder of kernel sources, e.g. an older ``kernels/``) the same
    renders run with those kernels too, interleaved repeat by repeat (the order swapped
    every repeat), and the row gets their times, ``vs_baseline`` (baseline total / this
    total over the pairs, each rendered back to back so a change in the load of shared
    cores moves both: :func:`bench.tables.measure.speedup_interval`'s geometric mean
    ``ratio`` and 95% interval ``lo``-``hi`` over ``n`` pairs; >1 = these kernels faster),
    the largest rgb difference and whether every pixel's counters agree.
    """
    renderers = {"now": Renderer(model, device=device, use_G=use_G, exact=exact,
                                 count_reads=True)}
    if baseline is not None:
        renderers["baseline"] = Renderer(model, device=device, use_G=use_G, exact=exact,
                                         kernel_dir=str(baseline))
    times = {name: {"march": [], "deferred": []} for name in renderers}
    counts, pairs, rgb_diff, same = [], [], 0.0, True
    for camera in cameras:
        first = {name: r.render(camera, background, stats=True) for name, r in renderers.items()}
        st = first["now"]
        counts.append((st["n_march"].mean(), st["n_occ"].mean(), (st["opacity"] > 0).mean(),
                       st["reads_occupancy"].mean(), st["reads_G"].mean()))
        if baseline is not None:
            old = first["baseline"]
            rgb_diff = max(rgb_diff, float(np.abs(st["rgb"] - old["rgb"]).max()))
            same = same and all(np.array_equal(st[k], old[k]) for k in ("n_march", "n_occ"))
        for i in range(repeats):
            for name in (list(renderers) if i % 2 == 0 else list(renderers)[::-1]):
                out = renderers[name].render(camera, background)
                times[name]["march"].append(out["ms_march"])
                times[name]["deferred"].append(out["ms_deferred"])
            if baseline is not None:
                pairs.append(sum(times["baseline"][k][-1] for k in ("march", "deferred"))
                             / sum(times["now"][k][-1] for k in ("march", "deferred")))
    row = _time_summary(times["now"])
    row.update(marching=float(np.mean([c[0] for c in counts])),
               occupied=float(np.mean([c[1] for c in counts])),
               covered=float(np.mean([c[2] for c in counts])),
               reads={"occupancy": float(np.mean([c[3] for c in counts])),
                      "G": float(np.mean([c[4] for c in counts]))})
    if baseline is not None:
        row["baseline"] = _time_summary(times["baseline"])
        row["vs_baseline"] = speedup_interval(pairs)
        row["baseline_rgb_diff"], row["baseline_same_counts"] = rgb_diff, same
    if limits is not None:
        n = cameras[0].width * cameras[0].height
        row["bound"] = {
            "march": march_bound(model.config, {k: v * n for k, v in row["reads"].items()},
                                 row["occupied"] * n, limits, n),
            "deferred": deferred_bound(row["covered"] * n, limits, n)}
        for stage in ("march", "deferred"):
            row["bound"][stage]["ratio"] = row[stage]["median"] / row["bound"][stage]["ms"]
    return row


def paired_speedup(row: tuple, base: tuple, camera, repeats: int, device=None,
                   exact: bool = False) -> dict:
    """``base``'s frame time over ``row``'s (each a (model, use_G)), rendered as
    ``repeats`` interleaved pairs (:func:`bench.tables.measure.time_pairs`): {ratio, lo, hi
    (95% interval), n}, >1: ``row`` is faster."""
    renderers = [Renderer(model, device=device, use_G=use_G, exact=exact)
                 for model, use_G in (row, base)]
    pairs = time_pairs(*renderers, [camera], repeats, None, (1.0, 1.0, 1.0))
    return {k: pairs[k] for k in ("ratio", "lo", "hi", "n")}


def _time_summary(times: dict) -> dict:
    total = [a + b for a, b in zip(times["march"], times["deferred"])]
    return {"march": summarize_ms(times["march"]), "deferred": summarize_ms(times["deferred"]),
            "total": summarize_ms(total)}


def time_reference(model, camera, ref_size: int, size: int) -> dict:
    """Wall time of the numpy reference on a ref_size^2 frame, scaled to size^2."""
    small = _camera(model.config.scene, ref_size)
    start = time.perf_counter()
    render_reference(model, small, background=(1.0, 1.0, 1.0), use_G=True)
    ms = (time.perf_counter() - start) * 1e3
    return {"ms_measured": ms, "ref_size": ref_size, "ms_scaled": ms * (size / ref_size) ** 2}


def _fmt_t(s: dict) -> str:
    return f"{s['median']:.1f} ({s['p10']:.1f}-{s['p90']:.1f})"


def _fmt_bound(r: dict, stage: str) -> str:
    b = r["bound"][stage]
    return f"{b['ms']:.1f} / {b['ratio']:.2f}x"


PAIRS_NOTE = ("Speed-ups: the other's frame time over this row's (>1: this row is faster), "
              "the geometric mean over interleaved pairs (rendered back to back, the order "
              "swapped every pair) with its 95% interval (t over the pairs' log ratios).")
STAGE_HEAD = ["march ms, median (p10-p90)", "march bound ms / ratio",
              "deferred ms, median (p10-p90)", "deferred bound ms / ratio", "total ms, median",
              "marching/ray", "occupied/ray", "covered"]
BASELINE_HEAD = ["baseline total ms, median", "speed-up vs baseline (95%)",
                 "baseline max rgb diff / same counts"]


def _stage_cells(r: dict) -> list[str]:
    cells = [_fmt_t(r["march"]), _fmt_bound(r, "march"), _fmt_t(r["deferred"]),
             _fmt_bound(r, "deferred"), f"{r['total']['median']:.1f}", f"{r['marching']:.2f}",
             f"{r['occupied']:.2f}", f"{r['covered']:.2f}"]
    if "baseline" in r:
        cells += [f"{r['baseline']['total']['median']:.1f}", speedup_cell(r["vs_baseline"]),
                  f"{r['baseline_rgb_diff']:.1e} / {'yes' if r['baseline_same_counts'] else 'NO'}"]
    return cells


def _stream_note(limits: dict) -> str:
    """The stream rate and the reference gather rates, where measured."""
    rate, ref = limits.get("stream_bytes_per_s"), limits.get("reference_gathers_per_s", {})
    note = (f"; streamed {rate / 1e9:.1f} GB/s, {MARCH_PIXEL_BYTES} bytes a pixel a stage"
            if rate else "")
    if ref:
        note += "; for reference, gathers " + ", ".join(
            f"{name} {r / 1e9:.2f} G/s" for name, r in ref.items())
    return note


def bounds_note(meta: dict) -> str:
    """The sentence on the bounds and the rates measured in this run."""
    lim = meta["limits"]
    rates = ", ".join(f"{name} {rate / 1e9:.2f} G/s ({lim['table_bytes'][name] / 2**20:.2f} MiB)"
                      for name, rate in lim["gathers_per_s"].items())
    note = (f"Bounds (bench/speed/ngprt_bounds.py): each stage's counters at the rates measured in this "
            f"run (random 32-byte gathers from tables of the model's sizes: {rates}; "
            f"{lim['flops_per_s'] / 1e9:.0f} GFLOP/s{_stream_note(lim)}), gathers, FLOPs "
            f"and streamed bytes not overlapped; ratio = time / bound.")
    if meta.get("baseline"):
        note += (f" Baseline: the kernels of `{meta['baseline']}`, rendered interleaved with "
                 f"these in the same run, the order swapped every repeat; speed-up vs "
                 f"baseline = the geometric mean over the pairs of its total / this total "
                 f"with its 95% interval (>1: these kernels are faster).")
    return note


def _section(title: str, intro: str, head: list[str], rows: list[list[str]]) -> str:
    """A markdown section: the ``## title``, the ``intro`` paragraph and a table of
    ``rows`` (lists of cells) under ``head``."""
    lines = [f"## {title}", "", intro, "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(cells) + " |" for cells in rows]
    return "\n".join(lines) + "\n"


def markdown(rows: list[dict], meta: dict) -> str:
    head = ["variant", "G"] + STAGE_HEAD + ["speed-up vs mlp (95%)",
                                            "speed-up G on vs off (95%)", "ref ms / CL ms"]
    head += BASELINE_HEAD if meta.get("baseline") else []
    intro = (f"{meta['device']}; `{meta['preset']}` preset ({meta['config']}), {meta['scene']} "
             f"random structured model, {meta['size']}x{meta['size']} orbit view, "
             f"{meta['build']} build, {meta['repeats']} repeats after a warm-up. "
             f"{bounds_note(meta)} The bounds use the separate-v model's tables (other "
             f"variants differ slightly). {PAIRS_NOTE} The numpy reference was timed once "
             f"per variant (with G) on a {meta['ref_size']}^2 frame and scaled by pixel "
             f"count: ref ms / CL ms is a scale, not paired.")
    cells = [[r["variant"], "on" if r["use_G"] else "off"] + _stage_cells(r)[:8] + [
        speedup_cell(r.get("vs_mlp")), speedup_cell(r.get("G_speedup")),
        f"{r['vs_ref']:.0f}x" if r.get("vs_ref") else ""] + _stage_cells(r)[8:] for r in rows]
    return _section("NGP-RT OpenCL kernels", intro, head, cells)


def _print_row(label: str, m: dict) -> None:
    b = m["bound"]
    extra = (f"  vs baseline {speedup_cell(m['vs_baseline'])} (rgb diff {m['baseline_rgb_diff']:.1e}, "
             f"same counts {m['baseline_same_counts']})" if "baseline" in m else "")
    print(f"{label} march {m['march']['median']:7.1f} ms (bound {b['march']['ms']:.1f}, "
          f"{b['march']['ratio']:.2f}x)  deferred {m['deferred']['median']:6.1f} ms (bound "
          f"{b['deferred']['ms']:.1f}, {b['deferred']['ratio']:.2f}x)  march/ray "
          f"{m['marching']:.2f}  occ/ray {m['occupied']:.2f}{extra}", flush=True)


def _write(out: Path, name: str, text: str, meta: dict, rows: list[dict]) -> None:
    write_atomic(out / f"{name}.md", text)
    write_atomic(out / f"{name}.json", json.dumps({"meta": meta, "rows": rows}, indent=2))
    print(text)


def run(size: int, repeats: int, preset_name: str, scene: str, ref_size: int, out: Path,
        device=None, seed: int = 0, gamma: float = 1.0, L_C: int | None = None,
        exact: bool = False, variants=VARIANTS, baseline=None) -> list[dict]:
    rows, refs, models = [], {}, {}
    camera = _camera(scene, size)
    grid = {} if L_C is None else {"L_C": L_C, "G_res": L_C // 2}   # G at L_C / 2 as in S2.5
    limits = measure_limits(random_baked_model(
        preset(preset_name, variant="separate-v", scene=scene, **grid), seed, gamma), device)
    for variant in variants:
        config = preset(preset_name, variant=variant, scene=scene, **grid)
        model = models[variant] = random_baked_model(config, seed, gamma)
        for use_G in (True, False):
            m = measure(model, [camera], use_G, repeats, device, exact, limits, baseline)
            rows.append({"variant": variant, "use_G": use_G, **m})
            _print_row(f"{variant:13s} G={'on ' if use_G else 'off'}", m)
        refs[variant] = time_reference(model, camera, ref_size, size)
    pair = functools.partial(paired_speedup, camera=camera, repeats=repeats, device=device,
                             exact=exact)
    for r in rows:
        this = (models[r["variant"]], r["use_G"])
        if "mlp" in models and r["variant"] != "mlp":
            r["vs_mlp"] = pair(this, (models["mlp"], r["use_G"]))
        if r["use_G"]:
            r["G_speedup"] = pair(this, (models[r["variant"]], False))
            r["reference"] = refs[r["variant"]]
            r["vs_ref"] = refs[r["variant"]]["ms_scaled"] / r["total"]["median"]
    meta = {"device": get_runtime(device).name, "preset": preset_name, "scene": scene,
            "size": size, "repeats": repeats, "ref_size": ref_size, "seed": seed,
            "build": "exact" if exact else "fast", "limits": limits, "gamma": gamma,
            "baseline": None if baseline is None else str(baseline),
            "config": f"L_C={config.L_C}, L={config.L}, log2_T={config.log2_T}, "
                      f"G_res={config.G_res}",
            "date": datetime.datetime.now().isoformat(timespec="seconds")}
    _write(out, "ngprt_kernels", markdown(rows, meta), meta, rows)
    return rows


TRAINED_SIZES = ("800x800", "1920x1080")


def trained_markdown(rows: list[dict], meta: dict) -> str:
    head = ["frame", "variant", "G"] + STAGE_HEAD + (BASELINE_HEAD if meta.get("baseline") else [])
    intro = (f"{meta['device']}; `{meta['model']}` ({meta['config']}) on the {meta['views']} "
             f"test cameras of `{meta['data']}`, {meta['build']} build, {meta['repeats']} "
             f"repeats a camera after a warm-up; times over every camera and repeat, counters "
             f"and bounds per frame (means over the cameras). Frames other than the test "
             f"size: each test camera through `Camera.scaled_to`, then fx set so fx / fy "
             f"stays the test camera's (square pixels): the vertical field of view is kept, "
             f"the horizontal one follows the frame's aspect. {bounds_note(meta)}")
    cells = [[r["size"], r["variant"], "on" if r["use_G"] else "off"] + _stage_cells(r)
             for r in rows]
    return _section("NGP-RT OpenCL kernels, trained model", intro, head, cells)


def run_trained(model_path: Path, data: Path, sizes, repeats: int, out: Path, device=None,
                exact: bool = False, views: int | None = None, baseline=None,
                downscale: int | None = None) -> list[dict]:
    """Times a trained model on its dataset's test cameras (at ``downscale``, default the
    model's training one) at the test size and at ``sizes`` ("WxH",
    :func:`bench.speed.sizes.at_size`), with G; writes ``<out>/ngprt_kernels_<model stem>.{md,json}``."""
    model = load_baked(model_path)
    ds = trained_test_set(model_path, data, downscale)
    cameras = ds.cameras[:views]
    if not cameras:
        raise ValueError(f"{data}: the test split has no cameras")
    limits = measure_limits(model, device)
    test_size = f"{cameras[0].width}x{cameras[0].height}"
    rows = []
    for size in [test_size] + [x for x in sizes if x != test_size]:
        w, h = parse_size(size)
        cams = cameras if size == test_size else [at_size(c, w, h) for c in cameras]
        m = measure(model, cams, True, repeats, device, exact, limits, baseline, ds.background)
        c = cams[0]
        rows.append({"size": size, "variant": model.config.variant, "use_G": True,
                     "camera": {"fx": c.fx, "fy": c.fy, "width": c.width, "height": c.height},
                     **m})
        _print_row(f"{size:>9s} {model.config.variant}", m)
    cfg = model.config
    meta = {"device": get_runtime(device).name, "model": shown_path(model_path),
            "data": shown_path(data),
            "views": len(cameras), "repeats": repeats, "build": "exact" if exact else "fast",
            "limits": limits, "baseline": None if baseline is None else str(baseline),
            "config": f"{cfg.variant}, L_C={cfg.L_C}, L={cfg.L}, log2_T={cfg.log2_T}, "
                      f"G_res={cfg.G_res}",
            "date": datetime.datetime.now().isoformat(timespec="seconds")}
    _write(out, f"ngprt_kernels_{Path(model_path).stem}", trained_markdown(rows, meta), meta, rows)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.speed.ngprt_kernels", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=int, default=400, help="image width and height")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--preset", default="cpu", help="model config preset (config.PRESETS)")
    p.add_argument("--scene", default="bounded", choices=["bounded", "unbounded"])
    p.add_argument("--variant", action="append", choices=VARIANTS, dest="variants",
                   help="an aggregation variant to time (repeatable; default all)")
    p.add_argument("--ref-size", type=int, default=100,
                   help="frame size for timing the numpy reference (scaled by pixel count)")
    p.add_argument("--out", default="results", type=Path)
    p.add_argument("--device", default=None)
    p.add_argument("--L-C", type=int, default=None,
                   help="coarse grid resolution instead of the preset's (G_res = L_C / 2)")
    p.add_argument("--exact", action="store_true",
                   help="time the exact build (the one tests compare with the reference)")
    p.add_argument("--baseline", type=Path, default=None,
                   help="a folder of kernel sources (e.g. an older kernels/) rendered "
                        "interleaved with the installed ones, for a speed ratio")
    p.add_argument("--model", type=Path, default=None,
                   help="a trained baked model: time it on --data's test cameras instead")
    p.add_argument("--data", type=Path, default=None, help="the model's dataset folder")
    p.add_argument("--sizes", nargs="+", default=None, metavar="WxH",
                   help=f"with --model: frame sizes besides the test size "
                        f"(default {' '.join(TRAINED_SIZES)})")
    p.add_argument("--views", type=int, default=None,
                   help="with --model: the first N test cameras (default all)")
    p.add_argument("--downscale", type=whole_number(), default=None, metavar="N",
                   help="with --data: read its images_N/ (default: the model's training one)")
    args = p.parse_args(argv)
    if (args.model is None) != (args.data is None):
        p.error("--model and --data go together")
    if args.model is not None:
        run_trained(args.model, args.data, args.sizes or TRAINED_SIZES, args.repeats,
                    args.out, args.device, args.exact, args.views, args.baseline,
                    args.downscale)
        return 0
    run(args.size, args.repeats, args.preset, args.scene, min(args.ref_size, args.size),
        args.out, args.device, L_C=args.L_C, exact=args.exact,
        variants=tuple(args.variants or VARIANTS), baseline=args.baseline)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
