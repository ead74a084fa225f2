"""Evaluating any method's baked model on a dataset split with its OpenCL renderer: the one
render-and-score loop of the CLI (``clrender eval``) and the benchmark (``bench.tables.measure``).

Examples:
    >>> result = evaluate("/tmp/model_b.npz", "/tmp/scn_b")
    >>> result["mean"]["psnr"], result["mean"]["ms"]
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .metrics import psnr, ssim
from .renderer import Renderer
from .video import to_uint8, write_png


def _lpips(rgb: np.ndarray, gt: np.ndarray):
    """LPIPS-Alex of one view, or None where the weights are not installed or the view is
    smaller than the network's receptive field."""
    from .lpips import LPIPSWeightsUnavailable, lpips_alex

    try:
        return lpips_alex(rgb, gt)
    except (LPIPSWeightsUnavailable, ValueError):
        return None


def score_views(renderer: Renderer, ds, lpips: bool = False, out_dir=None, prefix: str = "test"):
    """Render every view of ``ds`` with statistics and score it against its image.

    Args:
        renderer: a :class:`clrender.Renderer`.
        ds: a :class:`clrender.data.Dataset` (its views, images and background).
        lpips: also score LPIPS-Alex (``lpips``: None where unavailable).
        out_dir: when given, the renderings are written there as ``{prefix}_{i:03d}.png``.
    Returns:
        (per_view, first): one dict per view (``view``, ``psnr``, ``ssim``, ``ms_wall``
        (wall time of ``render`` with statistics read back), the renderer's ``ms`` and
        ``ms_<stage>``, the mean over pixels of each :attr:`Renderer.scalar_stats` key),
        and the first view's render, (H, W, 3) float32 clipped to [0, 1].
    """
    per_view, first = [], None
    for i, (cam, gt) in enumerate(zip(ds.cameras, ds.images)):
        t0 = time.perf_counter()
        out = renderer.render(cam, background=ds.background, stats=True)
        wall = 1e3 * (time.perf_counter() - t0)
        rgb = np.clip(out["rgb"], 0.0, 1.0)
        view = {"view": i, "psnr": psnr(rgb, gt), "ssim": ssim(rgb, gt), "ms_wall": wall}
        if lpips:
            view["lpips"] = _lpips(rgb, gt)
        view.update({k: float(v) for k, v in out.items() if k.startswith("ms")})
        view.update({s.key: float(np.mean(out[s.key])) for s in renderer.scalar_stats.values()})
        per_view.append(view)
        first = rgb if first is None else first
        if out_dir is not None:
            write_png(Path(out_dir) / f"{prefix}_{i:03d}.png", to_uint8(rgb))
    return per_view, first


def evaluate(model, data, device=None, split: str = "test", out_dir=None, downscale: int = 1,
             lpips: bool = False, **render_options) -> dict:
    """PSNR, SSIM and ms/frame of a baked model on every view of ``split``.

    Args:
        model: a baked ``.npz`` of any method (or a loaded model).
        data: dataset folder (or a loaded Dataset).
        device: OpenCL device spec.
        out_dir: when given, the renderings are written there as ``{split}_{i:03d}.png``.
        downscale: of a dataset folder (:func:`clrender.data.load_dataset`).
        lpips: also score LPIPS-Alex; its mean is None where a view could not be scored.
        **render_options: the method's render options (NGP-RT: ``use_G``).
    Returns:
        ``{"mean": {psnr, ssim, [lpips,] ms, ms_wall, ms_<stage>..., <stats>...}, "per_view": [...],
        "device": str}``; ``ms`` is the renderer's frame time (kernel times from OpenCL
        events, plus ray casting for NDRF), ``ms_wall`` the wall time of ``render`` with
        statistics read back; the method's statistics are means over pixels (NGP-RT:
        ``n_march``/``n_occ``, marching points / occupied samples per ray, Table 4).
    """
    from .data import load_dataset

    ds = data if hasattr(data, "images") else load_dataset(data, split=split, downscale=downscale)
    if not ds.cameras:
        raise ValueError(f"{getattr(ds, 'path', data)}: split {split!r} has no views")
    renderer = Renderer(model, device=device, **render_options)
    per_view, _ = score_views(renderer, ds, lpips=lpips, out_dir=out_dir, prefix=split)
    mean = {k: float(np.mean([v[k] for v in per_view])) for k in per_view[0]
            if k not in ("view", "lpips")}
    if lpips:
        scores = [v["lpips"] for v in per_view]
        mean["lpips"] = None if None in scores else float(np.mean(scores))
    # The first frame may pay for buffers sized to its image: report the median time too.
    mean["ms_median"] = float(np.median([v["ms"] for v in per_view]))
    mean["ms_wall_median"] = float(np.median([v["ms_wall"] for v in per_view]))
    return {"mean": mean, "per_view": per_view, "split": split, "n_views": len(per_view),
            "device": renderer.device_name}
