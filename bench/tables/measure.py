"""Measure one table row: score every test view (``clrender.evaluate.score_views``) and time
the method's OpenCL renderer."""
from __future__ import annotations

import functools
import time
from pathlib import Path

import numpy as np

from bench.tables.result import RowResult
from clrender import methods
from clrender.evaluate import score_views
from clrender.metrics import summarize_ms
from clrender.renderer import Renderer


def load_model(path):
    """The baked model at ``path``, loaded (and validated) once while the file is unchanged:
    a table's rows and pairs read a few files many times, and validating a file with the
    paper's grids recomputes its 256^3 G."""
    st = Path(path).stat()
    return _loaded(str(Path(path).resolve()), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=2)
def _loaded(path: str, mtime_ns: int, size: int):
    return methods.load(path)


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
        the :class:`bench.tables.result.RowResult` (``train_minutes`` and ``model_key`` unset).
    """
    renderer = Renderer(load_model(baked_path), device=device, **render_options)
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


def speedup_interval(ratios) -> dict:
    """The speed-up from paired timings: ``ratio`` = exp(mean log ratio) and its 95%
    interval ``lo``-``hi`` = exp(mean ± t(0.975, n - 1) * sd / sqrt(n)) over the ``n``
    pairs (each baseline time / row time, >1 = the row is faster); lo = hi = ratio for one
    pair."""
    from scipy import stats

    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.log(np.asarray(ratios, np.float64))
    n = len(logs)
    if n == 0 or not np.all(np.isfinite(logs)):
        raise ValueError(f"speed-up interval: needs finite positive ratios, got {list(ratios)}")
    mean = float(logs.mean())
    half = float(stats.t.ppf(0.975, n - 1) * logs.std(ddof=1) / np.sqrt(n)) if n > 1 else 0.0
    return {"ratio": float(np.exp(mean)), "lo": float(np.exp(mean - half)),
            "hi": float(np.exp(mean + half)), "n": n}


def time_pairs(row, base, cameras, repeats: int, stage: str | None, background=None) -> dict:
    """Times ``row`` and ``base`` (two renderers) as interleaved pairs on the same cameras:
    each camera rendered by both back to back, the order swapped every pair, after one
    warm-up render each; the time is the renderer's ``ms_<stage>`` (``stage`` None: the
    frame's ``ms``). Returns :func:`speedup_interval` of base / row with ``stage``,
    ``size`` ("WxH"), ``ms_row``, ``ms_baseline`` (medians over the pairs) and ``ratios``
    (each pair's, so seeds pool their pairs: :func:`bench.tables.seeds.aggregate`)."""
    key = "ms" if stage is None else f"ms_{stage}"
    for cam in cameras[:1]:
        row.render(cam, background=background)
        base.render(cam, background=background)
    mine, theirs = [], []
    for i in range(repeats):
        for j, cam in enumerate(cameras):
            order = ((row, mine), (base, theirs))
            for r, times in (order if (i + j) % 2 == 0 else order[::-1]):
                times.append(r.render(cam, background=background)[key])
    out = speedup_interval(np.asarray(theirs) / np.asarray(mine))
    cam = cameras[0]
    return {**out, "stage": stage or "frame", "size": f"{cam.width}x{cam.height}",
            "ms_row": float(np.median(mine)), "ms_baseline": float(np.median(theirs)),
            "ratios": [float(r) for r in np.asarray(theirs) / np.asarray(mine)]}


def compare_images(row, base, test_set) -> dict:
    """Every test view rendered by both renderers: ``identical`` (bit for bit), the largest
    absolute rgb difference ``max_diff`` and the number of ``views``."""
    diff = 0.0
    same = True
    for cam in test_set.cameras:
        a = row.render(cam, background=test_set.background)["rgb"]
        b = base.render(cam, background=test_set.background)["rgb"]
        same = same and np.array_equal(a, b)
        diff = max(diff, float(np.abs(a - b).max()))
    return {"identical": bool(same), "max_diff": diff, "views": len(test_set.cameras)}


def measure_pair(row_baked, row_render: dict, base_baked, base_render: dict, test_set,
                 device=None, repeats: int = 5, timing_views: int = 4, stage: str | None = None,
                 sizes=(), same_image: bool = False) -> dict:
    """A row against its baseline, timed as interleaved pairs (:func:`time_pairs`) on the
    first ``timing_views`` test cameras, at the test size and at each of ``sizes``
    ("WxH", the cameras through :func:`bench.speed.sizes.at_size`); with ``same_image`` the
    test views' images compared (:func:`compare_images`).

    Returns:
        {"paired_speedup": the test size's pairs, "paired_at": {size: pairs},
        "same_image": :func:`compare_images` or None}.
    """
    from bench.speed.sizes import at_size, parse_size

    row = Renderer(load_model(row_baked), device=device, **row_render)
    base = Renderer(load_model(base_baked), device=device, **base_render)
    cams = test_set.cameras[:timing_views]
    bg = test_set.background
    out = {"paired_speedup": time_pairs(row, base, cams, repeats, stage, bg), "paired_at": {}}
    for size in sizes:
        w, h = parse_size(size)
        out["paired_at"][size] = time_pairs(row, base, [at_size(c, w, h) for c in cams],
                                            repeats, stage, bg)
    out["same_image"] = compare_images(row, base, test_set) if same_image else None
    return out
