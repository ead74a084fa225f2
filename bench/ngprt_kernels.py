"""Kernel timings of the OpenCL NGP-RT renderer on a random structured baked model.

    python -m bench.ngprt_kernels                       # 400x400, `cpu` preset, 5 repeats
    python -m bench.ngprt_kernels --size 800            # the 800x800 frame
    python -m bench.ngprt_kernels --size 200 --repeats 3 --preset tiny --out results/
    python -m bench.ngprt_kernels --L-C 256             # finer grids: G has more to skip
    python -m bench.ngprt_kernels --exact               # the exact build (tests' build)

For every aggregation variant, with and without the occupancy distance grid G, renders
one orbit view and reports the march and deferred-MLP kernel times (OpenCL profiling
events; median and p10-p90 over the repeats, after one warm-up render), the marching and
occupied points per ray, each stage's bound and the ratio time / bound
(:mod:`bench.limits`: the stage's own counters at the gather and FLOP rates measured on
the device in the same run), and the speed-ups: each variant against ``mlp``, G on
against G off, and OpenCL against the numpy reference. The reference is timed once per
variant (with G) on a smaller frame (``--ref-size``) and scaled by the pixel count; the
table says so. Writes ``<out>/ngprt_kernels.{json,md}``. Never asserts.
"""
from __future__ import annotations

import argparse
import datetime
import json
import time
from pathlib import Path

from bench.limits import deferred_bound, march_bound, measure_limits
from clrender.atomic import write_atomic
from clrender.device import get_runtime
from clrender.metrics import summarize_ms
from clrender.ngprt.config import VARIANTS, preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer
from clrender.ngprt.render_ref import render_reference
from clrender.paths import path_cameras


def _camera(scene: str, size: int):
    return path_cameras(scene, "orbit", 8, size, size)[1]


def measure(model, camera, use_G: bool, repeats: int, device=None, exact: bool = False,
            limits: dict | None = None) -> dict:
    """Kernel times (ms), points per ray and (given ``limits``) each stage's bound of one
    model/camera, G on or off."""
    renderer = Renderer(model, device=device, use_G=use_G, exact=exact)
    stats = renderer.render(camera, stats=True)  # warm-up: first-touch of buffers, caches
    march, deferred = [], []
    for _ in range(repeats):
        out = renderer.render(camera)
        march.append(out["ms_march"])
        deferred.append(out["ms_deferred"])
    total = [a + b for a, b in zip(march, deferred)]
    row = {"march": summarize_ms(march), "deferred": summarize_ms(deferred),
           "total": summarize_ms(total), "marching": float(stats["n_march"].mean()),
           "occupied": float(stats["n_occ"].mean()),
           "covered": float((stats["opacity"] > 0).mean()), "rgb": out["rgb"]}
    if limits is not None:
        n = camera.width * camera.height
        row["bound"] = {
            "march": march_bound(model.config, row["marching"] * n, row["occupied"] * n, limits),
            "deferred": deferred_bound(row["covered"] * n, limits)}
        for stage in ("march", "deferred"):
            row["bound"][stage]["ratio"] = row[stage]["median"] / row["bound"][stage]["ms"]
    return row


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


def markdown(rows: list[dict], meta: dict) -> str:
    head = ["variant", "G", "march ms (p10-p90)", "march bound ms / ratio",
            "deferred ms (p10-p90)", "deferred bound ms / ratio", "total ms",
            "marching/ray", "occupied/ray", "covered", "vs mlp", "G on vs off", "CL vs ref"]
    lim = meta["limits"]
    rates = ", ".join(f"{name} {rate / 1e9:.2f} G/s ({lim['table_bytes'][name] / 2**20:.1f} MiB)"
                      for name, rate in lim["gathers_per_s"].items())
    lines = ["## NGP-RT OpenCL kernels", "",
             f"{meta['device']}; `{meta['preset']}` preset ({meta['config']}), {meta['scene']} "
             f"random structured model, {meta['size']}x{meta['size']} orbit view, "
             f"{meta['build']} build, {meta['repeats']} repeats after a warm-up. Bounds "
             f"(bench/limits.py): each stage's counters at the rates measured in this run "
             f"(random 32-byte gathers from tables of the model's sizes: {rates}; "
             f"{lim['flops_per_s'] / 1e9:.0f} GFLOP/s), gathers and FLOPs not overlapped "
             f"(the separate-v model's tables; other variants differ slightly); ratio = "
             f"time / bound. Speed-ups: time of the other / this row's time, >1 = this row "
             f"is faster. The numpy reference was timed once per variant (with G) on a "
             f"{meta['ref_size']}^2 frame and scaled by pixel count.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join([
            r["variant"], "on" if r["use_G"] else "off", _fmt_t(r["march"]),
            _fmt_bound(r, "march"), _fmt_t(r["deferred"]), _fmt_bound(r, "deferred"),
            f"{r['total']['median']:.1f}", f"{r['marching']:.2f}", f"{r['occupied']:.2f}",
            f"{r['covered']:.2f}", f"{r['vs_mlp']:.2f}x", f"{r['G_speedup']:.2f}x"
            if r["use_G"] else "", f"{r['vs_ref']:.0f}x" if r.get("vs_ref") else ""]) + " |")
    return "\n".join(lines) + "\n"


def run(size: int, repeats: int, preset_name: str, scene: str, ref_size: int, out: Path,
        device=None, seed: int = 0, gamma: float = 1.0, L_C: int | None = None,
        exact: bool = False) -> list[dict]:
    rows, refs = [], {}
    camera = _camera(scene, size)
    grid = {} if L_C is None else {"L_C": L_C, "G_res": L_C // 2}   # G at L_C / 2 as in S2.5
    limits = measure_limits(random_baked_model(
        preset(preset_name, variant="separate-v", scene=scene, **grid), seed, gamma), device)
    for variant in VARIANTS:
        config = preset(preset_name, variant=variant, scene=scene, **grid)
        model = random_baked_model(config, seed, gamma)
        for use_G in (True, False):
            m = measure(model, camera, use_G, repeats, device, exact, limits)
            m.pop("rgb")
            rows.append({"variant": variant, "use_G": use_G, **m})
            b = m["bound"]
            print(f"{variant:13s} G={'on ' if use_G else 'off'} march {m['march']['median']:7.1f}"
                  f" ms (bound {b['march']['ms']:.1f}, {b['march']['ratio']:.2f}x)  deferred "
                  f"{m['deferred']['median']:6.1f} ms (bound {b['deferred']['ms']:.1f}, "
                  f"{b['deferred']['ratio']:.2f}x)  march/ray {m['marching']:.2f}  "
                  f"occ/ray {m['occupied']:.2f}", flush=True)
        refs[variant] = time_reference(model, camera, ref_size, size)
    mlp = {r["use_G"]: r["total"]["median"] for r in rows if r["variant"] == "mlp"}
    for r in rows:
        r["vs_mlp"] = mlp[r["use_G"]] / r["total"]["median"]
        off = next(x for x in rows if x["variant"] == r["variant"] and not x["use_G"])
        r["G_speedup"] = off["total"]["median"] / r["total"]["median"]
        if r["use_G"]:
            r["reference"] = refs[r["variant"]]
            r["vs_ref"] = refs[r["variant"]]["ms_scaled"] / r["total"]["median"]
    meta = {"device": get_runtime(device).name, "preset": preset_name, "scene": scene,
            "size": size, "repeats": repeats, "ref_size": ref_size, "seed": seed,
            "build": "exact" if exact else "fast", "limits": limits,
            "gamma": gamma, "config": f"L_C={config.L_C}, L={config.L}, log2_T={config.log2_T}, "
                                      f"G_res={config.G_res}",
            "date": datetime.datetime.now().isoformat(timespec="seconds")}
    text = markdown(rows, meta)
    write_atomic(out / "ngprt_kernels.md", text)
    write_atomic(out / "ngprt_kernels.json", json.dumps({"meta": meta, "rows": rows}, indent=2))
    print(text)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.ngprt_kernels", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=int, default=400, help="image width and height")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--preset", default="cpu", help="model config preset (config.PRESETS)")
    p.add_argument("--scene", default="bounded", choices=["bounded", "unbounded"])
    p.add_argument("--ref-size", type=int, default=100,
                   help="frame size for timing the numpy reference (scaled by pixel count)")
    p.add_argument("--out", default="results", type=Path)
    p.add_argument("--device", default=None)
    p.add_argument("--L-C", type=int, default=None,
                   help="coarse grid resolution instead of the preset's (G_res = L_C / 2)")
    p.add_argument("--exact", action="store_true",
                   help="time the exact build (the one tests compare with the reference)")
    args = p.parse_args(argv)
    run(args.size, args.repeats, args.preset, args.scene, min(args.ref_size, args.size),
        args.out, args.device, L_C=args.L_C, exact=args.exact)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
