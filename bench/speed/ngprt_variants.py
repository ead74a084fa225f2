"""The NGP-RT kernels' GPU variants (:class:`clrender.ngprt.render_cl.Tuning`), each paired
against the default build on the stage it changes.

    python -m bench.speed.ngprt_variants --model M.npz --data DIR      # 800x800 and 1920x1080
    python -m bench.speed.ngprt_variants --sizes 400x400 --views 2    # a random `cpu` model
    python -m bench.speed.ngprt_variants --variant half-tables --variant tile-8x8 ...

Per frame size: the default build's stages against their bounds
(:func:`bench.speed.ngprt_kernels.measure`: times, counters, bounds from the gather, FLOP
and stream rates measured in this run), then every variant of :data:`VARIANTS` and the
default rendered as interleaved pairs (:func:`bench.tables.measure.time_pairs`: each camera
by both back to back, the order swapped every pair) on its stage's kernel time, the
speed-up with its 95% interval over the pairs (>1: the variant is faster), and the largest
rgb difference from the default on the first camera (half-tables reads rounded tables: not
zero there). A trained model renders the first ``--views`` test cameras of its dataset,
each resized with :func:`bench.speed.sizes.at_size`; a random structured model
(``--preset``) its orbit views. Writes ``<out>/ngprt_variants[_<model>].{json,md}``. The
bounds are the default build's (a half-tables corner moves 16 bytes, not 32).
Never asserts: the tests hold every variant to the reference (tests/test_render_tuning.py).
"""
from __future__ import annotations

import argparse
import datetime
from pathlib import Path

import numpy as np

from bench.speed.ngprt_bounds import measure_limits
from bench.speed.ngprt_kernels import (STAGE_HEAD, _print_row, _section, _stage_cells,
                                       _write, bounds_note, measure)
from bench.speed.sizes import at_size, parse_size, trained_test_set
from bench.tables.measure import time_pairs
from clrender.cliopts import whole_number
from clrender.device import get_runtime
from clrender.ngprt.baked import load_baked
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer, Tuning
from clrender.paths import path_cameras

# name -> (the variant, the stage whose kernel it changes)
VARIANTS = {
    "half-tables": (Tuning(half_tables=True), "march"),
    "tile-8x4": (Tuning(march_tile=(8, 4)), "march"),
    "tile-8x8": (Tuning(march_tile=(8, 8)), "march"),
    "tile-16x8": (Tuning(march_tile=(16, 8)), "march"),
    "half-tables+tile-8x8": (Tuning(half_tables=True, march_tile=(8, 8)), "march"),
    "occupancy-image": (Tuning(occupancy_image=True), "march"),
    "deferred-local": (Tuning(deferred_local=True), "deferred"),
    "deferred-streamed": (Tuning(deferred_streamed=True), "deferred"),
    "deferred-local+streamed": (Tuning(deferred_local=True, deferred_streamed=True),
                                "deferred"),
}
DEFAULT_SIZES = ("800x800", "1920x1080")


def pair_variant(base: Renderer, tuning: Tuning, stage: str, cameras, repeats: int,
                 background=(1.0, 1.0, 1.0)) -> dict:
    """``tuning`` against ``base`` (the default build, of the same model, device and lanes)
    on ``stage``'s kernel time over ``cameras`` (:func:`time_pairs`), with the largest rgb
    difference on the first camera."""
    row = Renderer(base.model, device=base.runtime, use_G=True, rays=base.rays,
                   tuning=tuning)
    diff = float(np.abs(row.render(cameras[0], background)["rgb"]
                        - base.render(cameras[0], background)["rgb"]).max())
    pairs = time_pairs(row, base, cameras, repeats, stage, background)
    return {**pairs, "max_rgb_diff": diff}


def frames(model_path, data, sizes, views: int | None, downscale, preset_name: str):
    """(model, {size: cameras}, background, description) of a trained model on its test
    cameras, or of a random structured model of ``preset_name`` on orbit views."""
    if model_path is not None:
        model = load_baked(model_path)
        ds = trained_test_set(model_path, data, downscale)
        cams = ds.cameras[:views]
        if not cams:
            raise ValueError(f"{data}: the test split has no cameras")
        at = {s: [at_size(c, *parse_size(s)) for c in cams] for s in sizes}
        return model, at, ds.background, f"`{model_path}` on {len(cams)} test cameras of `{data}`"
    model = random_baked_model(preset(preset_name, variant="separate-v"), 0, 1.0)
    at = {}
    for s in sizes:
        w, h = parse_size(s)
        at[s] = path_cameras("bounded", "orbit", 8, w, h)[:views or 2]
    return model, at, (1.0, 1.0, 1.0), (f"a random `{preset_name}` model on "
                                        f"{len(next(iter(at.values())))} orbit views")


def markdown(stages: list[dict], pairs: list[dict], meta: dict) -> str:
    head = ["frame"] + STAGE_HEAD
    intro = (f"{meta['device']}; {meta['what']} ({meta['config']}), the default build, "
             f"{meta['repeats']} repeats a camera. {bounds_note(meta)}")
    text = _section("NGP-RT stages against their bounds", intro, head,
                    [[r["size"]] + _stage_cells(r) for r in stages])
    intro = ("Each variant and the default build as interleaved pairs on the variant's "
             "stage (its kernel time), the order swapped every pair; speed-up = default / "
             "variant with its 95% t interval over the pairs (>1: the variant is faster); "
             "max rgb diff: against the default on the first camera.")
    cells = [[p["size"], p["variant"], p["stage"], f"{p['ms_baseline']:.2f}",
              f"{p['ms_row']:.2f}", f"{p['ratio']:.3f}x ({p['lo']:.3f}-{p['hi']:.3f})",
              str(p["n"]), f"{p['max_rgb_diff']:.1e}"] for p in pairs]
    return text + "\n" + _section(
        "Variants against the default", intro,
        ["frame", "variant", "stage", "default ms", "variant ms", "speed-up (95%)", "pairs",
         "max rgb diff"], cells)


def run(model_path, data, sizes, views, repeats: int, out: Path, variants, device=None,
        downscale=None, preset_name: str = "cpu") -> dict:
    model, cams_at, background, what = frames(model_path, data, sizes, views, downscale,
                                              preset_name)
    limits = measure_limits(model, device)
    # The default build each variant is paired with, built once: the device's lanes, and
    # one ray a work-item for the occupancy image (a GPU's lane width anyway).
    defaults = {rays: Renderer(model, device=device, use_G=True, rays=rays)
                for rays in {1 if VARIANTS[name][0].occupancy_image else None
                             for name in variants}}
    stages, pairs = [], []
    for size, cams in cams_at.items():
        m = measure(model, cams, True, repeats, device, False, limits, None, background)
        stages.append({"size": size, **m})
        _print_row(f"{size:>9s} default", m)
        for name in variants:
            tuning, stage = VARIANTS[name]
            base = defaults[1 if tuning.occupancy_image else None]
            p = pair_variant(base, tuning, stage, cams, repeats, background)
            pairs.append({"variant": name, **p})
            print(f"{size:>9s} {name:24s} {stage:8s} {p['ms_baseline']:8.2f} -> "
                  f"{p['ms_row']:8.2f} ms  {p['ratio']:.3f}x ({p['lo']:.3f}-{p['hi']:.3f})  "
                  f"rgb diff {p['max_rgb_diff']:.1e}", flush=True)
    cfg = model.config
    meta = {"device": get_runtime(device).name, "what": what, "repeats": repeats,
            "limits": limits, "sizes": list(sizes),
            "config": f"{cfg.variant}, L_C={cfg.L_C}, L={cfg.L}, log2_T={cfg.log2_T}, "
                      f"G_res={cfg.G_res}",
            "date": datetime.datetime.now().isoformat(timespec="seconds")}
    name = "ngprt_variants" + (f"_{Path(model_path).stem}" if model_path else "")
    _write(out, name, markdown(stages, pairs, meta), meta, {"stages": stages, "pairs": pairs})
    return {"stages": stages, "pairs": pairs}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.speed.ngprt_variants", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", type=Path, default=None, help="a trained baked NGP-RT model")
    p.add_argument("--data", type=Path, default=None, help="its dataset folder")
    p.add_argument("--downscale", type=whole_number(), default=None, metavar="N",
                   help="with --data: read its images_N/ (default: the model's training one)")
    p.add_argument("--preset", default="cpu", help="without --model: the random model's preset")
    p.add_argument("--sizes", nargs="+", default=list(DEFAULT_SIZES), metavar="WxH")
    p.add_argument("--views", type=whole_number(), default=None,
                   help="cameras per size (default: every test camera; 2 orbit views)")
    p.add_argument("--repeats", type=whole_number(), default=5)
    p.add_argument("--variant", action="append", choices=list(VARIANTS), dest="variants",
                   help="a variant to pair (repeatable; default all)")
    p.add_argument("--out", default="results", type=Path)
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)
    if (args.model is None) != (args.data is None):
        p.error("--model and --data go together")
    for s in args.sizes:
        parse_size(s)
    run(args.model, args.data, args.sizes, args.views, args.repeats, args.out,
        args.variants or list(VARIANTS), args.device, args.downscale, args.preset)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
