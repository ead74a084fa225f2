"""Measure one table row: render every test view with the OpenCL renderer."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from clrender.metrics import psnr, ssim, summarize_ms
from clrender.ngprt.baked import load_baked
from clrender.ngprt.render_cl import Renderer


def measure_row(baked_path, test_set, use_G: bool, device=None, repeats: int = 5,
                timing_views: int = 4) -> dict:
    """Quality, speed and marching statistics of a baked model on a dataset's test views.

    Args:
        baked_path: the baked model file.
        test_set: a :class:`clrender.data.Dataset` (test split).
        use_G: march with the occupancy distance grid G.
        repeats: timing passes over the first ``timing_views`` test views.
    Returns:
        dict with PSNR, SSIM (means over test views), ``time`` (kernel ms per frame,
        march + deferred MLP: median/p10/p90/min/n), ``wall_ms`` (median host time per
        frame), Marching / Occupied (mean points per ray over all pixels), ``size_MB``
        (baked file) and ``sample`` (the first view's render, (H, W, 3) float32).
    """
    renderer = Renderer(load_baked(baked_path), device=device, use_G=use_G)
    psnrs, ssims, march, occ, sample = [], [], [], [], None
    for cam, gt in zip(test_set.cameras, test_set.images):
        out = renderer.render(cam, background=test_set.background)
        psnrs.append(psnr(out["rgb"], gt))
        ssims.append(ssim(out["rgb"], gt))
        march.append(out["n_march"].mean())
        occ.append(out["n_occ"].mean())
        sample = out["rgb"] if sample is None else sample
    kernel_ms, wall_ms = [], []
    for _ in range(repeats):
        for cam in test_set.cameras[:timing_views]:
            start = time.perf_counter()
            out = renderer.render(cam, background=test_set.background)
            wall_ms.append((time.perf_counter() - start) * 1e3)
            kernel_ms.append(out["ms_march"] + out["ms_deferred"])
    return {
        "PSNR": float(np.mean(psnrs)), "SSIM": float(np.mean(ssims)),
        "time": summarize_ms(kernel_ms), "wall_ms": float(np.median(wall_ms)),
        "Marching": float(np.mean(march)), "Occupied": float(np.mean(occ)),
        "size_MB": Path(baked_path).stat().st_size / 2**20, "sample": sample,
    }
