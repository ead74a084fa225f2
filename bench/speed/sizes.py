"""Frames of the kernel benchmarks (``bench.speed.ngprt_kernels``, ``bench.speed.ndrf_kernels``): a
trained model's test split, a "WIDTHxHEIGHT" argument parsed, and a test camera resized
to it."""
from __future__ import annotations

from dataclasses import replace


def trained_test_set(model_path, data, downscale: int | None = None):
    """The test split of dataset ``data`` at ``downscale``, by default the one the baked
    model at ``model_path`` was trained at (its manifest; ``clrender eval`` does the same)."""
    from clrender.bakedfile import trained_downscale
    from clrender.data import load_dataset

    if downscale is None:
        downscale = trained_downscale(model_path)
    return load_dataset(data, split="test", downscale=downscale)


def at_size(camera, width: int, height: int):
    """A test camera at ``width`` x ``height``: :meth:`Camera.scaled_to` (intrinsics
    scaled per axis), then ``fx`` reset to keep the test camera's pixel aspect ``fx / fy``:
    the vertical field of view is kept and the horizontal one follows the new aspect (a
    square test camera at 1920x1080 sees 16:9 of the scene, unstretched)."""
    c = camera.scaled_to(width, height)
    return replace(c, fx=c.fy * camera.fx / camera.fy)


def parse_size(text: str) -> tuple[int, int]:
    """``"WIDTHxHEIGHT"`` (``x`` or ``X``) as ``(width, height)``, both positive; a
    ValueError that names the text otherwise."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"frame size {text!r}: expected WIDTHxHEIGHT, e.g. 1920x1080") from None
    if w <= 0 or h <= 0:
        raise ValueError(f"frame size {text!r}: width and height must be positive")
    return w, h
