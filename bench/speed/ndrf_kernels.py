"""Per-stage timings of the NDRF renderer against their bounds, for both hit sources.

    python -m bench.speed.ndrf_kernels                          # random K=2 model, orbit, 200 and 800
    python -m bench.speed.ndrf_kernels --model ndrf.npz --data DIR [--teacher ngprt.npz]

Random model: one orbit view per ``--sizes`` side. Trained model (``--model`` and ``--data``):
the dataset's test cameras at the test size, 800x800 and 1920x1080 (``--frames``), each
camera resized with :func:`bench.speed.sizes.at_size` (the vertical field of view and the
pixel aspect kept: a square test camera at 1920x1080 sees a wider view, not a stretched
one). Stages: ``intersect`` (the rasteriser's kernels, or Embree on the host plus the upload),
``conv0`` (with the gather of the screen pixels) and ``conv1``, kernel times from profiling
events; median and p10-p90 over every camera and repeat after one warm-up frame each.
With ``--teacher`` the NGP-RT teacher renders the same cameras in the same run, as
interleaved pairs with the student (raster path; :func:`bench.tables.measure.time_pairs`):
the student's speed-up is the geometric mean of teacher / student frame time over the pairs,
with its 95% interval.

Bounds, from this device's rates measured here (:mod:`bench.speed.limits`): conv0 and conv1 from
their FLOPs (:func:`counters`: conv0 as the kernel computes it, factored by linearity into
per-vertex projections and a view table) at the measured FLOP rate; conv0's gathers (its
projected vertex rows and table row pairs, one random read each) at the random-gather rate
measured on a table of the projections' size; the rasteriser is reported per triangle and
per covered pixel-layer (it has no single bound: setup per triangle, binning per
(triangle, tile) pair, edge tests per tile row a pair spans). Writes
``<out>/ndrf_kernels[_<model>].{json,md}``.
Never asserts.
"""
from __future__ import annotations

import argparse
import datetime
import json
from pathlib import Path

import numpy as np

from bench.options import shown_path
from bench.speed.limits import flop_rate, gather_rate
from bench.speed.ngprt_kernels import TRAINED_SIZES
from bench.speed.sizes import at_size, parse_size, trained_test_set
from bench.tables.compare import speedup_cell
from bench.tables.measure import time_pairs
from clrender import methods
from clrender.atomic import write_atomic
from clrender.cliopts import whole_number
from clrender.metrics import summarize_ms
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ndrf.render import HIT_SOURCES, Renderer
from clrender.paths import path_cameras
from clrender.renderer import Renderer as AnyRenderer

STAGES = ("intersect", "conv0", "conv1")


def _spread(mask: np.ndarray, radius: int, step: int) -> np.ndarray:
    """(H, W) bool: pixels p with ``mask`` at some p + step * (dx, dy), 0 <= dx, dy <=
    radius (step 1: reached from below/right; -1: from above/left)."""
    h, w = mask.shape
    out = mask.copy()
    for dy in range(radius + 1):
        for dx in range(radius + 1):
            src = mask[dy:, dx:] if step > 0 else mask[:h - dy, :w - dx]
            if step > 0:
                out[:h - dy, :w - dx] |= src
            else:
                out[dy:, dx:] |= src
    return out


def _shifted(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """(H, W): a at p + (dy, dx), zero outside the image."""
    out = np.zeros_like(a)
    h, w = a.shape
    out[:h - dy, :w - dx] = a[dy:, dx:]
    return out


def counters(model, out: dict) -> dict:
    """What one frame must compute: conv0 / conv1 FLOPs and conv0's gathered rows.

    conv0 (kernels/ndrf_shade.cl, factored; fast build): for each pixel it computes (read by
    a covered pixel) and tap, 3 projected vertex rows of H channels blended per mesh hit at
    the tap's input pixel (2 FLOPs a channel) and 3 view-table lerps (value + fraction x
    step, accumulated: 3 FLOPs a channel) for an input pixel inside the image; gathers:
    those rows (3 per hit, one value-and-step row pair per lerp; one random read each, its
    floats contiguous). conv1: covered pixels x H x S^2 x 3 x 2.
    """
    cfg = model.config
    S, H, r = cfg.kernel_size, cfg.hidden, cfg.kernel_size - 1
    coverage = out["coverage"] > 0
    needed = _spread(coverage, r, 1)          # conv1 at p reads hidden at p - (0..r)
    n_hits = out["n_hits"].astype(np.float64)
    inside = np.ones_like(n_hits)
    tap_hits = sum(_shifted(n_hits, dy, dx)[needed].sum() for dy in range(S) for dx in range(S))
    tap_inside = sum(_shifted(inside, dy, dx)[needed].sum() for dy in range(S) for dx in range(S))
    return {"covered": int(coverage.sum()), "conv0_pixels": int(needed.sum()),
            "conv0_flops": float(tap_hits * 3 * H * 2 + tap_inside * 3 * H * 3),
            "conv1_flops": float(coverage.sum()) * H * S * S * 3 * 2,
            "gathers": float(tap_hits * 3 + tap_inside * 3),
            "hit_layers": int(out["n_hits"].sum())}


def measure(renderer, cameras, repeats: int) -> dict:
    """Stage times over ``cameras`` x ``repeats`` (a warm-up frame each) and the counters of
    the first camera."""
    times = {s: [] for s in STAGES + ("total",)}
    for camera in cameras:
        renderer.render(camera)
        for _ in range(repeats):
            out = renderer.render(camera)
            for s in STAGES:
                times[s].append(out[f"ms_{s}"])
            times["total"].append(out["ms"])
    first = renderer.render(cameras[0], stats=True)
    return {**{s: summarize_ms(v) for s, v in times.items()},
            "counters": counters(renderer.model, first)}


def teacher_pairs(teacher_path, student, cameras, repeats: int, device=None) -> dict:
    """The NGP-RT teacher (default render options) against ``student`` (a renderer) on
    the same cameras as interleaved pairs (:func:`bench.tables.measure.time_pairs`):
    ``ratio`` (teacher / student, >1: the student is faster), its 95% interval ``lo``-``hi``
    over ``n`` pairs, the medians ``ms_baseline`` (teacher) and ``ms_row`` (student)."""
    pairs = time_pairs(student, AnyRenderer(teacher_path, device=device), cameras, repeats,
                       None)
    return {k: v for k, v in pairs.items() if k != "ratios"}


def bounds(row: dict, rates: dict) -> dict:
    """Bound (ms) of each stage from its counters at the measured rates."""
    c = row["counters"]
    return {"conv0": c["conv0_flops"] / rates["flops_per_s"] * 1e3,
            "conv1": c["conv1_flops"] / rates["flops_per_s"] * 1e3,
            "gather": c["gathers"] / rates["gathers_per_s"] * 1e3}


def _fmt(s: dict) -> str:
    return f"{s['median']:.1f} ({s['p10']:.1f}-{s['p90']:.1f})"


def markdown(rows: list[dict], meta: dict) -> str:
    head = ["frame", "hits", "intersect ms", "conv0 ms (bound)", "conv1 ms (bound)",
            "total ms", "FPS", "raster ns / triangle, / hit", "teacher ms, median (paired)",
            "speed-up vs teacher (95%)"]
    lines = ["## NDRF renderer stages", "",
             f"{meta['device']}; {meta['model']}; {meta['views']}; {meta['repeats']} repeats "
             f"after a warm-up; stage times: median (p10-p90). Rates measured here: "
             f"{meta['rates']['flops_per_s'] / 1e9:.0f} GFLOP/s, "
             f"{meta['rates']['gathers_per_s'] / 1e9:.2f} G random float8 gathers/s. "
             "Bounds: conv0 at the FLOP rate (+ the time of its gathered rows at the "
             "random-gather rate, an upper estimate: neighbouring pixels share vertices, so "
             "most rows come from cache), conv1 at the FLOP rate. Speed-up: the "
             "NGP-RT teacher's frame time over this row's, rendered as interleaved pairs on "
             "the same cameras (the order swapped every pair): the geometric mean over the "
             "pairs with its 95% interval.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        b, c, t = r["bound"], r["counters"], r["total"]["median"]
        per_tri = (f"{r['intersect']['median'] * 1e6 / meta['faces']:.0f}, "
                   f"{r['intersect']['median'] * 1e6 / max(c['hit_layers'], 1):.0f}"
                   if r["hits"] == "raster" else "")
        teacher = r.get("teacher")
        lines.append("| " + " | ".join([
            r["frame"], r["hits"], _fmt(r["intersect"]),
            f"{_fmt(r['conv0'])} ({b['conv0']:.1f} + {b['gather']:.1f})",
            f"{_fmt(r['conv1'])} ({b['conv1']:.1f})", _fmt(r["total"]), f"{1000.0 / t:.1f}",
            per_tri, f"{teacher['ms_baseline']:.1f}" if teacher else "",
            speedup_cell(teacher)]) + " |")
    return "\n".join(lines) + "\n"


def run(model, frames: dict, repeats: int, out: Path, name: str, views: str, device=None,
        teacher=None) -> list[dict]:
    """Measure ``model`` on ``frames`` ({label: cameras}) with both hit sources."""
    renderers = {h: Renderer(model, device=device, hits=h) for h in HIT_SOURCES}
    runtime = renderers["raster"].runtime
    proj_bytes = int(renderers["raster"].shader.projection_bytes)
    rates = {"flops_per_s": flop_rate(runtime), "gathers_per_s": gather_rate(proj_bytes,
                                                                            runtime)}
    rows = []
    for label, cameras in frames.items():
        t = (teacher_pairs(teacher, renderers["raster"], cameras, repeats, runtime)
             if teacher else None)
        for hits, renderer in renderers.items():
            row = {"frame": label, "hits": hits, **measure(renderer, cameras, repeats)}
            row["bound"] = bounds(row, rates)
            if t and hits == "raster":
                row["teacher"] = t
            rows.append(row)
            print(f"{label:>10s} {hits:6s} total {row['total']['median']:7.1f} ms  intersect "
                  f"{row['intersect']['median']:6.1f}  conv0 {row['conv0']['median']:6.1f} "
                  f"(bound {row['bound']['conv0']:.1f})", flush=True)
    sizes = ", ".join(f"{m['vertices']} V / {m['faces']} F" for m in model.mesh_sizes())
    meta = {"device": runtime.name, "hit_source": renderers["raster"].hit_source,
            "model": f"{name}: meshes {sizes}", "faces": sum(m["faces"] for m in
                                                             model.mesh_sizes()),
            "views": views, "repeats": repeats, "rates": rates,
            "date": datetime.datetime.now().isoformat(timespec="seconds")}
    text = markdown(rows, meta)
    stem = "ndrf_kernels" + ("" if name.startswith("random") else "_" + Path(name).stem)
    write_atomic(out / f"{stem}.md", text)
    write_atomic(out / f"{stem}.json", json.dumps({"meta": meta, "rows": rows}, indent=2))
    print(text)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.speed.ndrf_kernels", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[200, 800],
                   help="image sides of the random model's orbit view")
    p.add_argument("--model", default=None, help="a baked NDRF file (default: a random model)")
    p.add_argument("--data", default=None, type=Path, help="its dataset (test cameras)")
    p.add_argument("--frames", nargs="+", default=list(TRAINED_SIZES),
                   help="frame sizes WxH besides the test size (trained model)")
    p.add_argument("--downscale", type=whole_number(), default=None, metavar="N",
                   help="with --data: read its images_N/ (default: the model's training one)")
    p.add_argument("--teacher", default=None, help="a baked NGP-RT model to time beside it")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", default="results", type=Path)
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)
    if args.model is None:
        model = random_ndrf_model(NDRFConfig(), 0)
        frames = {f"{s}x{s}": [path_cameras("bounded", "orbit", 8, s, s)[1]] for s in args.sizes}
        run(model, frames, args.repeats, args.out, "random K=2 model (seed 0)", "orbit view",
            args.device, args.teacher)
        return 0
    if args.data is None:
        p.error("--model needs --data (the dataset whose test cameras to render)")
    model = methods.load(args.model)
    cams = trained_test_set(args.model, args.data, args.downscale).cameras
    frames = {f"{cams[0].width}x{cams[0].height}": cams}
    for text in args.frames:
        w, h = parse_size(text)
        frames[f"{w}x{h}"] = [at_size(c, w, h) for c in cams]
    run(model, frames, args.repeats, args.out, shown_path(args.model),
        f"{len(cams)} test cameras of {shown_path(args.data)}", args.device, args.teacher)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
