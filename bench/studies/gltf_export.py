"""How close a glTF export (``clrender export MODEL --format glb``) comes to the model it
came from: its first mesh rendered at the dataset's test views (Embree first hits,
barycentric vertex colours, the background where rays miss) against the ground truth and
against the model's own render, for each colour source.

    python -m bench.studies.gltf_export ndrf.npz --data data/lego
    python -m bench.studies.gltf_export model.npz --data data/lego --threshold 0.01

Writes ``OUT/gltf-export.{json,md}`` and the ``.glb`` files (``OUT/gltf-<source>.glb``);
never asserts.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from clrender import bakedfile, methods
from clrender.data import load_dataset
from clrender.export.glb import read_glb
from clrender.export.gltf import COLOUR_SOURCES, export_glb
from clrender.export.mesh_colours import render_mesh
from clrender.metrics import psnr, ssim
from clrender.ndrf.hits import HitCaster
from clrender.renderer import Renderer


def score(glb: Path, model, test) -> dict:
    """Mean PSNR / SSIM of the file's first mesh at ``test``'s views against the ground
    truth (``psnr``, ``ssim``) and against ``model``'s render (``psnr_model``, ...)."""
    nodes = {k: v for k, v in read_glb(glb).items() if k != "cameras"}
    mesh = next(iter(nodes.values()))
    v, f, rgb = mesh["POSITION"], mesh["indices"].astype(np.int64), mesh["COLOR_0"]
    caster = HitCaster([(v, f)])
    renderer = Renderer(model)
    rows = []
    for cam, gt in zip(test.cameras, test.images):
        ours = render_mesh(v, f, rgb, cam, test.background, caster)
        theirs = np.clip(renderer.render(cam, test.background)["rgb"], 0.0, 1.0)
        rows.append({"psnr": psnr(ours, gt), "ssim": ssim(ours, gt),
                     "psnr_model": psnr(ours, theirs), "ssim_model": ssim(ours, theirs),
                     "model_psnr": psnr(theirs, gt), "model_ssim": ssim(theirs, gt)})
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    return {**mean, "triangles": int(sum(len(n["indices"]) for n in nodes.values())),
            "vertices": int(sum(len(n["POSITION"]) for n in nodes.values())),
            "meshes": list(nodes), "bytes": glb.stat().st_size, "views": len(rows)}


def run(model_path, data, out: Path, sources=COLOUR_SOURCES, threshold=None,
        downscale: int | None = None) -> list[dict]:
    model = methods.load(model_path)
    downscale = bakedfile.trained_downscale(model_path) if downscale is None else downscale
    test = load_dataset(data, split="test", downscale=downscale)
    rows = []
    for source in sources:
        glb = out / f"gltf-{source}.glb"
        t0 = time.perf_counter()
        export_glb(model_path, glb, data=data, downscale=downscale, colours=source,
                   threshold=threshold)
        seconds = time.perf_counter() - t0
        rows.append({"colours": source, "export_s": round(seconds, 1),
                     **score(glb, model, test)})
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| colours | PSNR vs truth | SSIM | PSNR vs model | model's own PSNR | triangles "
             "| file (MiB) | export (s) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['colours']} | {r['psnr']:.2f} | {r['ssim']:.3f} | "
                     f"{r['psnr_model']:.2f} | {r['model_psnr']:.2f} | {r['triangles']} | "
                     f"{r['bytes'] / 2**20:.1f} | {r['export_s']} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.studies.gltf_export",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("model")
    p.add_argument("--data", required=True, help="dataset folder (training views colour the "
                                                 "mesh, test views score it)")
    p.add_argument("--colours", nargs="+", default=list(COLOUR_SOURCES),
                   choices=COLOUR_SOURCES)
    p.add_argument("--threshold", type=float, default=None, help="NGP-RT's surface level")
    p.add_argument("--downscale", type=int, default=None)
    p.add_argument("--out", default="results")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = run(args.model, args.data, out, args.colours, args.threshold, args.downscale)
    result = {"model": args.model, "data": args.data, "threshold": args.threshold,
              "rows": rows}
    (out / "gltf-export.json").write_text(json.dumps(result, indent=2) + "\n")
    text = table(rows)
    (out / "gltf-export.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
