"""Measure one table row: render every test view with the method's OpenCL renderer."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from clrender import methods
from clrender.lpips import LPIPSWeightsUnavailable, lpips_alex
from clrender.metrics import psnr, ssim, summarize_ms
from clrender.renderer import Renderer


def _lpips(pred: np.ndarray, target: np.ndarray):
    """LPIPS-Alex of one view, or None where the weights are not installed or the view is
    smaller than the network's receptive field."""
    try:
        return lpips_alex(np.clip(pred, 0.0, 1.0), target)
    except (LPIPSWeightsUnavailable, ValueError):
        return None


def measure_row(baked_path, test_set, render_options: dict, device=None, repeats: int = 5,
                timing_views: int = 4, timing_sizes=()) -> dict:
    """Quality, speed and statistics of a baked model (any method) on a dataset's test views.

    Args:
        baked_path: the baked model file.
        test_set: a :class:`clrender.data.Dataset` (test split).
        render_options: the method's render options (NGP-RT: ``use_G``).
        repeats: timing passes over the first ``timing_views`` test views (rgb only read
            back, as an application would).
        timing_sizes: image widths at which the same views are timed again (cameras scaled,
            aspect kept): ``time_at[width]``.
    Returns:
        dict with PSNR, SSIM, LPIPS (AlexNet v0.1; None without its weights: means over
        test views), ``time`` (the renderer's ms per frame:
        median/p10/p90/min/n), ``stages`` (median ms per stage), ``wall_ms`` (median host
        time per frame), one entry per column of the renderer's ``scalar_stats`` (NGP-RT:
        Marching / Occupied, mean points per ray over all pixels), ``size_MB`` (baked file)
        ``sample`` (the first view's render, (H, W, 3) float32) and ``time_note`` (what the
        time covers, from the renderer).
    """
    renderer = Renderer(methods.load(baked_path), device=device, **render_options)
    columns = renderer.scalar_stats
    psnrs, ssims, lpipss, sample = [], [], [], None
    stat_means = {col: [] for col in columns}
    for cam, gt in zip(test_set.cameras, test_set.images):
        out = renderer.render(cam, background=test_set.background, stats=True)
        psnrs.append(psnr(out["rgb"], gt))
        ssims.append(ssim(out["rgb"], gt))
        lpipss.append(_lpips(out["rgb"], gt))
        for col, key in columns.items():
            stat_means[col].append(out[key].mean())
        sample = out["rgb"] if sample is None else sample
    frame_ms, wall_ms, stages = [], [], {}
    for _ in range(repeats):
        for cam in test_set.cameras[:timing_views]:
            start = time.perf_counter()
            out = renderer.render(cam, background=test_set.background)
            wall_ms.append((time.perf_counter() - start) * 1e3)
            frame_ms.append(out["ms"])
            for k, v in out.items():
                if k.startswith("ms_"):
                    stages.setdefault(k[3:], []).append(v)
    time_at = {}
    for width in timing_sizes:
        cams = [c.scaled_to(width, round(c.height * width / c.width))
                for c in test_set.cameras[:timing_views]]
        renderer.render(cams[0], background=test_set.background)      # warm-up at this size
        time_at[int(width)] = summarize_ms([renderer.render(c, background=test_set.background)["ms"]
                                            for _ in range(repeats) for c in cams])
    return {
        "PSNR": float(np.mean(psnrs)), "time_at": time_at,
        "LPIPS": None if None in lpipss else float(np.mean(lpipss)), "SSIM": float(np.mean(ssims)),
        "time": summarize_ms(frame_ms), "wall_ms": float(np.median(wall_ms)),
        "stages": {k: float(np.median(v)) for k, v in stages.items()},
        **{col: float(np.mean(v)) for col, v in stat_means.items()},
        "size_MB": Path(baked_path).stat().st_size / 2**20, "sample": sample,
        "time_note": renderer.impl.TIME_NOTE,
    }
