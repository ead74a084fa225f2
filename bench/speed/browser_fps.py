"""The exported WebGL2 page (``clrender export``), measured in headless Chromium: export
size, page load time, ms a frame at several sizes (beside the OpenCL renderer's kernel
time for the same view on this machine), and PSNR of the page against the
OpenCL renderer on the dataset's test views.

Headless Chromium draws WebGL2 with SwiftShader on the CPU: its frames a second are
indicative of this machine's cores, not of a GPU browser. The page's ms a frame is a full
draw and a one-pixel read that waits for it (``window.clrender.renderView``).

Examples:
    python -m bench.speed.browser_fps lego-ndrf.npz --data data/lego --out results/browser
    python -m bench.speed.browser_fps model.npz --sizes 200 400 --frames 5 --views 3
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

import clrender
from clrender.export import export, serve
from clrender.export.page import open_page, render_view
from clrender.metrics import psnr, summarize_ms

from bench.tools.browser import chromium, missing, webgl_renderer


def measure(model_path, data, sizes, frames: int, views: int, downscale=None) -> dict:
    """One model's row: export MB and seconds, load ms, ms a frame per size, PSNR."""
    from clrender.data.load import scan_dataset
    from clrender.bakedfile import trained_downscale

    cams = []
    if data:
        ds = downscale or trained_downscale(model_path)
        cams = scan_dataset(data, "test", ds).final_cameras()[:views]
    row = {"model": str(model_path), "data": str(data) if data else None}
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        site = export(model_path, Path(tmp) / "site", data=data, downscale=downscale)
        row["export_s"] = time.perf_counter() - start
        row["export_mb"] = sum(f.stat().st_size for f in site.iterdir()) / 1e6
        url, server = serve(site)
        driver = chromium(900, 900)
        try:
            row["load_ms"] = open_page(driver, url, timeout_s=600)["load_ms"]
            row["webgl"] = webgl_renderer(driver)
            base = cams[0] if cams else None
            renderer = clrender.Renderer(clrender.load(model_path))
            row["ms"], row["opencl_ms"] = {}, {}
            for size in sizes:
                cam = (base.scaled_to(size, round(size * base.height / base.width)) if base
                       else clrender.Camera.from_fov(0.69, size, size,
                                                     clrender.look_at([0.0, -3.0, 1.5])))
                render_view(driver, cam)                       # warm-up: shaders, targets
                ms = [render_view(driver, cam)[1] for _ in range(frames)]
                row["ms"][f"{cam.width}x{cam.height}"] = summarize_ms(ms)
                renderer.render(cam)                           # the same view, OpenCL
                row["opencl_ms"][f"{cam.width}x{cam.height}"] = summarize_ms(
                    [renderer.render(cam)["ms"] for _ in range(frames)])
            row["psnr_vs_opencl"] = [psnr(render_view(driver, c)[0], renderer.render(c)["rgb"])
                                     for c in cams]
        finally:
            driver.quit()
            server.shutdown()
            server.server_close()
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("models", nargs="+", help="baked .npz files")
    p.add_argument("--data", nargs="*", default=None,
                   help="dataset folder per model (test cameras: sizes' aspect, PSNR views)")
    p.add_argument("--downscale", type=int, default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[200, 400, 800],
                   help="frame widths to time")
    p.add_argument("--frames", type=int, default=5, help="timed frames per size")
    p.add_argument("--views", type=int, default=3, help="test views compared with OpenCL")
    p.add_argument("--out", required=True, help="folder for browser_fps.json")
    args = p.parse_args(argv)
    reason = missing()
    if reason:
        p.error(reason)
    data = args.data or [None] * len(args.models)
    if len(data) != len(args.models):
        p.error("--data takes one dataset folder per model")
    rows = []
    for model, d in zip(args.models, data):
        rows.append(measure(model, d, args.sizes, args.frames, args.views, args.downscale))
        print(json.dumps(rows[-1], indent=1))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "cpus": os.cpu_count(), "loadavg": os.getloadavg()}
    (out / "browser_fps.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(f"wrote {out / 'browser_fps.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
