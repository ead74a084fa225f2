"""Per-stage timings of the NDRF renderer, and its OpenCL shading against the numpy reference.

    python -m bench.ndrf_kernels                         # random K=2 model, 200 and 800 px
    python -m bench.ndrf_kernels --model ndrf.npz --sizes 200 800 1920 --repeats 5

Renders one orbit view per size: Embree ray casting into the K meshes (``intersect``, wall
time on the host), then the OpenCL passes ``gather``, ``conv0``, ``conv1`` (kernel times
from profiling events); median and p10-p90 over the repeats after one warm-up frame. The
numpy reference shades the same hits once per size; the ratio is reference shading time over
OpenCL shading time (gather + conv0 + conv1), with the largest difference between the two
images. Writes ``<out>/ndrf_kernels.{json,md}``. Never asserts.
"""
from __future__ import annotations

import argparse
import datetime
import json
import time
from pathlib import Path

import numpy as np

from clrender import methods
from clrender.atomic import write_atomic
from clrender.camera import generate_rays
from clrender.metrics import summarize_ms
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ndrf.render import Renderer
from clrender.ndrf.shader_ref import shade_reference
from clrender.paths import path_cameras

STAGES = ("intersect", "gather", "conv0", "conv1")


def measure(renderer: Renderer, size: int, repeats: int) -> dict:
    """Stage times (ms) of one orbit view at ``size`` x ``size``, and the reference ratio."""
    camera = path_cameras("bounded", "orbit", 8, size, size)[1]
    renderer.render(camera)                                    # warm-up: build, first touch
    times = {s: [] for s in STAGES + ("total",)}
    for _ in range(repeats):
        out = renderer.render(camera)
        for s in STAGES:
            times[s].append(out[f"ms_{s}"])
        times["total"].append(out["ms"])
    hits = renderer.caster.cast_camera(camera)
    _, dirs = generate_rays(camera)
    start = time.perf_counter()
    ref = shade_reference(renderer.model, hits.tri, hits.bary, dirs, renderer.model.background)
    ref_ms = (time.perf_counter() - start) * 1e3
    shading = [g + a + b for g, a, b in zip(times["gather"], times["conv0"], times["conv1"])]
    return {"size": size, **{s: summarize_ms(v) for s, v in times.items()},
            "shading": summarize_ms(shading), "reference_shading_ms": ref_ms,
            "vs_ref": ref_ms / float(np.median(shading)),
            "max_abs_diff": float(np.abs(out["rgb"] - ref).max()),
            "coverage": float((hits.tri >= 0).any(axis=0).mean())}


def _fmt(s: dict) -> str:
    return f"{s['median']:.1f} ({s['p10']:.1f}-{s['p90']:.1f})"


def markdown(rows: list[dict], meta: dict) -> str:
    head = ["size", "intersect ms", "gather ms", "conv0 ms", "conv1 ms", "total ms", "FPS",
            "numpy ref shading ms", "CL shading vs ref", "max |CL - ref|", "coverage"]
    lines = ["## NDRF renderer stages", "",
             f"{meta['device']}; {meta['model']}; orbit view; {meta['repeats']} repeats after a "
             "warm-up (median, p10-p90). intersect: Embree on the host (wall time); the other "
             "stages: OpenCL kernel times. CL shading vs ref: numpy reference shading time "
             "over gather + conv0 + conv1.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join(
            [f"{r['size']}x{r['size']}"] + [_fmt(r[s]) for s in STAGES + ("total",)]
            + [f"{1000.0 / r['total']['median']:.1f}", f"{r['reference_shading_ms']:.0f}",
               f"{r['vs_ref']:.0f}x", f"{r['max_abs_diff']:.1e}", f"{r['coverage']:.2f}"]) + " |")
    return "\n".join(lines) + "\n"


def run(sizes, repeats: int, out: Path, model_path=None, device=None, seed: int = 0) -> list[dict]:
    if model_path is None:
        model = random_ndrf_model(NDRFConfig(), seed)
        what = f"random K=2 model (seed {seed})"
    else:
        model = methods.load(model_path)
        what = str(model_path)
    sizes_faces = ", ".join(f"{m['vertices']} V / {m['faces']} F" for m in model.mesh_sizes())
    renderer = Renderer(model, device=device)
    rows = []
    for size in sizes:
        rows.append(measure(renderer, size, repeats))
        r = rows[-1]
        print(f"{size:5d}px  total {r['total']['median']:7.1f} ms  intersect "
              f"{r['intersect']['median']:6.1f}  shading {r['shading']['median']:6.1f}  "
              f"ref {r['reference_shading_ms']:7.0f}", flush=True)
    meta = {"device": renderer.runtime.name, "model": f"{what}: meshes {sizes_faces}",
            "repeats": repeats, "date": datetime.datetime.now().isoformat(timespec="seconds")}
    text = markdown(rows, meta)
    write_atomic(out / "ndrf_kernels.md", text)
    write_atomic(out / "ndrf_kernels.json", json.dumps({"meta": meta, "rows": rows}, indent=2))
    print(text)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.ndrf_kernels", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[200, 800], help="image sides")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--model", default=None, help="a baked NDRF file (default: a random model)")
    p.add_argument("--out", default="results", type=Path)
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)
    run(args.sizes, args.repeats, args.out, args.model, args.device)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
