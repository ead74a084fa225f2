"""Image quality metrics and timing summaries."""
from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity


def psnr(pred: np.ndarray, target: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of images in [0, 1]; ``inf`` when identical."""
    mse = float(np.mean((np.asarray(pred, np.float64) - np.asarray(target, np.float64)) ** 2))
    return float("inf") if mse == 0.0 else -10.0 * np.log10(mse)


def ssim(pred: np.ndarray, target: np.ndarray) -> float:
    """Structural similarity of (H, W, 3) images in [0, 1] (scikit-image, Gaussian 11x11
    window with sigma 1.5 as in the NeRF literature)."""
    return float(structural_similarity(
        np.asarray(pred, np.float64), np.asarray(target, np.float64), channel_axis=-1,
        data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False))


def summarize_ms(samples_ms) -> dict:
    """Median and spread of repeated timings: {median, p10, p90, min, n} in ms."""
    a = np.asarray(list(samples_ms), dtype=np.float64)
    if a.size == 0:
        raise ValueError("summarize_ms: no timing samples")
    return {"median": float(np.median(a)), "p10": float(np.percentile(a, 10)),
            "p90": float(np.percentile(a, 90)), "min": float(a.min()), "n": int(a.size)}
