"""PSNR, SSIM and timing summaries."""
import numpy as np
import pytest

from clrender import metrics


def test_psnr_known_value():
    a = np.zeros((8, 8, 3))
    assert metrics.psnr(a, a + 0.1) == pytest.approx(20.0)
    assert metrics.psnr(a, a) == float("inf")


def test_ssim_identical_and_noisy():
    rng = np.random.default_rng(0)
    img = rng.uniform(size=(32, 32, 3))
    assert metrics.ssim(img, img) == pytest.approx(1.0)
    noise = rng.normal(size=img.shape)
    scores = [metrics.ssim(img, np.clip(img + sigma * noise, 0, 1)) for sigma in (0.05, 0.2, 0.5)]
    assert scores[0] > scores[1] > scores[2]


def test_summarize_ms():
    s = metrics.summarize_ms([3.0, 1.0, 2.0])
    assert s["median"] == 2.0 and s["min"] == 1.0 and s["n"] == 3
    with pytest.raises(ValueError):
        metrics.summarize_ms([])
