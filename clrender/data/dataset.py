"""The in-memory dataset every loader returns and the loaders' shared image helpers."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from ..camera import Camera

F32 = np.float32
SCENE_KINDS = ("bounded", "unbounded")


@dataclass
class Dataset:
    """Posed images of one split, in normalised scene space.

    Attributes:
        images: (N, H, W, 3) float32 in [0, 1], RGBA already composited on ``background``.
        cameras: one :class:`Camera` per image (NeRF/Blender convention, normalised space).
        scene: "bounded" (content inside [-1, 1]^3) or "unbounded" (360°, MERF contraction).
        background: (3,) float32 RGB in [0, 1].
        path: the dataset folder.
        split: "train", "val" or "test".
        alpha: (N, H, W) float32 coverage in [0, 1] when the images had an alpha channel,
            else None.
    """

    images: np.ndarray
    cameras: list[Camera]
    scene: str
    background: np.ndarray
    path: str
    split: str
    alpha: np.ndarray | None = None


def check_downscale(downscale) -> int:
    """``downscale`` as a positive int, or a ValueError."""
    if int(downscale) != downscale or downscale < 1:
        raise ValueError(f"downscale must be a positive integer, got {downscale!r}")
    return int(downscale)


def read_image(file: Path) -> np.ndarray:
    """(H, W, 3 or 4) float32 in [0, 1] from an 8- or 16-bit image file (grey expanded to RGB)."""
    if not file.is_file():
        raise FileNotFoundError(f"{file}: image file not found")
    try:
        img = iio.imread(file)
    except Exception as exc:  # imageio raises many types for unreadable files
        raise ValueError(f"{file}: cannot read image ({exc})") from exc
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{file}: unsupported pixel type {img.dtype}, expected uint8 or uint16")
    img = img.astype(F32) / F32(np.iinfo(img.dtype).max)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[-1] not in (1, 2, 3, 4):
        raise ValueError(f"{file}: image has shape {img.shape}, expected (H, W[, 1-4])")
    if img.shape[-1] in (1, 2):  # grey [+ alpha]
        img = np.concatenate([np.repeat(img[..., :1], 3, -1), img[..., 1:]], -1)
    return img


def composite(img: np.ndarray, background: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Composite (H, W, 3|4) float32 on (3,) ``background``: (H, W, 3) rgb, (H, W) alpha or None."""
    if img.shape[-1] == 3:
        return img, None
    alpha = img[..., 3]
    return img[..., :3] * alpha[..., None] + background * (1.0 - alpha[..., None]), alpha


def area_downscale(img: np.ndarray, factor: int) -> np.ndarray:
    """Shrink (H, W, ...) by an integer ``factor`` with box averaging (edges cropped)."""
    if factor == 1:
        return img
    h, w = img.shape[0] // factor, img.shape[1] // factor
    if h == 0 or w == 0:
        raise ValueError(f"image of size {img.shape[1]}x{img.shape[0]} is smaller than "
                         f"downscale {factor}")
    blocks = img[:h * factor, :w * factor].reshape(h, factor, w, factor, *img.shape[2:])
    return blocks.mean(axis=(1, 3), dtype=np.float64).astype(F32)


def downscaled_camera(camera: Camera, factor: int) -> Camera:
    """The camera of :func:`area_downscale` (crop to a multiple of ``factor``, then resize)."""
    if factor == 1:
        return camera
    w, h = camera.width // factor * factor, camera.height // factor * factor
    cropped = Camera(camera.fx, camera.fy, camera.cx, camera.cy, w, h, camera.c2w)
    return cropped.resized(1.0 / factor)


def stack_images(images: list[np.ndarray], files: list[Path]) -> np.ndarray:
    """Stack equally sized images; a size mismatch names the first file that differs."""
    for img, file in zip(images, files):
        if img.shape != images[0].shape:
            raise ValueError(f"{file}: image has shape {img.shape}, expected {images[0].shape} "
                             f"like {files[0].name}")
    return np.stack(images).astype(F32)
