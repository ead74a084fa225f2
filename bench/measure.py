"""Measure one table row: score every test view (``clrender.evaluate.score_views``) and time
the method's OpenCL renderer."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bench.result import RowResult
from clrender import methods
from clrender.evaluate import score_views
from clrender.metrics import summarize_ms
from clrender.renderer import Renderer


def measure_row(baked_path, test_set, render_options: dict, device=None, repeats: int = 5,
                timing_views: int = 4, timing_sizes=()) -> RowResult:
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
        the :class:`bench.result.RowResult` (``train_minutes`` and ``model_key`` unset).
    """
    renderer = Renderer(methods.load(baked_path), device=device, **render_options)
    per_view, sample = score_views(renderer, test_set, lpips=True)
    lpips = [v["lpips"] for v in per_view]
    stats = {col: float(np.mean([v[s.key] for v in per_view]))
             for col, s in renderer.scalar_stats.items()}
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
    return RowResult(
        psnr=float(np.mean([v["psnr"] for v in per_view])),
        ssim=float(np.mean([v["ssim"] for v in per_view])),
        lpips=None if None in lpips else float(np.mean(lpips)),
        time=summarize_ms(frame_ms), wall_ms=float(np.median(wall_ms)),
        stages={k: float(np.median(v)) for k, v in stages.items()}, stats=stats,
        size_MB=Path(baked_path).stat().st_size / 2**20, time_note=renderer.time_note,
        time_at=time_at, sample=sample)
