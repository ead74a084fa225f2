"""Kernel timings of the OpenCL NGP-RT renderer on a random structured baked model.

    python -m bench.ngprt_kernels                       # 400x400, `cpu` preset, 5 repeats
    python -m bench.ngprt_kernels --size 200 --repeats 3 --preset tiny --out results/
    python -m bench.ngprt_kernels --L-C 256             # finer grids: G has more to skip

For every aggregation variant, with and without the occupancy distance grid G, renders
one orbit view and reports the march and deferred-MLP kernel times (OpenCL profiling
events; median and p10-p90 over the repeats, after one warm-up render), the marching and
occupied points per ray, and the ratios: each variant against ``mlp``, G on against G
off, and OpenCL against the numpy reference. The reference is timed once per variant
(with G) on a smaller frame (``--ref-size``) and scaled by the pixel count; the table
says so. Writes ``<out>/ngprt_kernels.{json,md}``. Never asserts.
"""
from __future__ import annotations

import argparse
import datetime
import json
import time
from pathlib import Path

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


def measure(model, camera, use_G: bool, repeats: int, device=None) -> dict:
    """Kernel times (ms) and points per ray of one model/camera, G on or off."""
    renderer = Renderer(model, device=device, use_G=use_G)
    stats = renderer.render(camera, stats=True)  # warm-up: first-touch of buffers, caches
    march, deferred = [], []
    for _ in range(repeats):
        out = renderer.render(camera)
        march.append(out["ms_march"])
        deferred.append(out["ms_deferred"])
    total = [a + b for a, b in zip(march, deferred)]
    return {"march": summarize_ms(march), "deferred": summarize_ms(deferred),
            "total": summarize_ms(total), "marching": float(stats["n_march"].mean()),
            "occupied": float(stats["n_occ"].mean()), "rgb": out["rgb"]}


def time_reference(model, camera, ref_size: int, size: int) -> dict:
    """Wall time of the numpy reference on a ref_size^2 frame, scaled to size^2."""
    small = _camera(model.config.scene, ref_size)
    start = time.perf_counter()
    render_reference(model, small, background=(1.0, 1.0, 1.0), use_G=True)
    ms = (time.perf_counter() - start) * 1e3
    return {"ms_measured": ms, "ref_size": ref_size, "ms_scaled": ms * (size / ref_size) ** 2}


def _fmt_t(s: dict) -> str:
    return f"{s['median']:.1f} ({s['p10']:.1f}-{s['p90']:.1f})"


def markdown(rows: list[dict], meta: dict) -> str:
    head = ["variant", "G", "march ms (p10-p90)", "deferred ms (p10-p90)", "total ms",
            "marching/ray", "occupied/ray", "vs mlp", "G on vs off", "CL vs ref"]
    lines = ["## NGP-RT OpenCL kernels", "",
             f"{meta['device']}; `{meta['preset']}` preset ({meta['config']}), {meta['scene']} "
             f"random structured model, {meta['size']}x{meta['size']} orbit view, "
             f"{meta['repeats']} repeats after a warm-up. Ratios are speed-ups "
             f"(time of the other / this row's time, >1 = this row is faster). The numpy "
             f"reference was timed once per variant (with G) on a {meta['ref_size']}^2 frame "
             f"and scaled by pixel count.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join([
            r["variant"], "on" if r["use_G"] else "off", _fmt_t(r["march"]),
            _fmt_t(r["deferred"]), f"{r['total']['median']:.1f}", f"{r['marching']:.2f}",
            f"{r['occupied']:.2f}", f"{r['vs_mlp']:.2f}x", f"{r['G_speedup']:.2f}x"
            if r["use_G"] else "", f"{r['vs_ref']:.0f}x" if r.get("vs_ref") else ""]) + " |")
    return "\n".join(lines) + "\n"


def run(size: int, repeats: int, preset_name: str, scene: str, ref_size: int, out: Path,
        device=None, seed: int = 0, gamma: float = 1.0, L_C: int | None = None) -> list[dict]:
    rows, refs = [], {}
    camera = _camera(scene, size)
    grid = {} if L_C is None else {"L_C": L_C, "G_res": L_C // 2}   # G at L_C / 2 as in S2.5
    for variant in VARIANTS:
        config = preset(preset_name, variant=variant, scene=scene, **grid)
        model = random_baked_model(config, seed, gamma)
        for use_G in (True, False):
            m = measure(model, camera, use_G, repeats, device)
            m.pop("rgb")
            rows.append({"variant": variant, "use_G": use_G, **m})
            print(f"{variant:13s} G={'on ' if use_G else 'off'} total {m['total']['median']:7.1f}"
                  f" ms  march/ray {m['marching']:.2f}  occ/ray {m['occupied']:.2f}", flush=True)
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
    args = p.parse_args(argv)
    run(args.size, args.repeats, args.preset, args.scene, min(args.ref_size, args.size),
        args.out, args.device, L_C=args.L_C)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
