"""Render any method's baked model along a camera path into a video or a folder of PNGs.

Paths: see :mod:`clrender.paths` (``orbit``, ``spiral``, ``test``).

Examples:
    >>> render_path("model.npz", "orbit.mp4", frames=60)
    >>> render_path("model.npz", "frames/", path="test", data="data/lego", width=200, height=200)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from .atomic import atomic_write
from .paths import path_cameras
from .renderer import Renderer

VIDEO_SUFFIXES = (".mp4", ".gif")


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) float in [0, 1] -> uint8, rounded."""
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_png(path: Path, frame: np.ndarray) -> None:
    """Write a uint8 frame as a PNG, atomically."""
    import imageio.v3 as iio

    atomic_write(path, lambda tmp: iio.imwrite(tmp, frame))


def render_path(model, out, path: str = "orbit", frames: int = 60, width: int = 400,
                height: int = 400, data=None, device=None, background=None, fps: int = 30,
                downscale: int = 1, **render_options) -> Path:
    """Render ``frames`` views of a baked model along ``path`` into ``out``.

    Args:
        model: a baked model file (any method) or a loaded model.
        out: a ``.mp4`` / ``.gif`` file, or a folder that receives ``frame_0000.png``, ...
        path: ``orbit``, ``spiral`` or ``test`` (:mod:`clrender.paths`).
        data: dataset (path or name for :func:`clrender.data.load_dataset`) whose
            cameras define ``spiral`` and ``test``; ``downscale`` says which of its image
            folders to find them by (:func:`clrender.data.scan_dataset`).
        device: OpenCL device spec.
        background: RGB in [0, 1] behind the model (None: the method's default).
        fps: frame rate of a video.
        **render_options: the method's render options (NGP-RT: ``use_G``).
    Returns:
        the path written. Files are written to a temporary name and moved into place.
    """
    out = Path(out)
    if out.suffix.lower() == ".mp4" and (width % 2 or height % 2):
        raise ValueError(f"{out}: an .mp4 (H.264, yuv420p) needs an even width and height, "
                         f"got {width}x{height}")
    renderer = Renderer(model, device=device, **render_options)
    cameras = path_cameras(renderer.model.config.scene, path, frames, width, height, data,
                           downscale)
    frames_iter = (to_uint8(renderer.render(c, background=background)["rgb"])
                   for c in tqdm(cameras, desc=f"render {path}", unit="frame"))
    if out.suffix.lower() in VIDEO_SUFFIXES:
        _write_video(out, frames_iter, fps)
    else:
        out.mkdir(parents=True, exist_ok=True)
        for i, frame in enumerate(frames_iter):
            write_png(out / f"frame_{i:04d}.png", frame)
    return out


def _write_video(out: Path, frames, fps: int) -> None:
    import imageio.v2 as imageio
    import imageio.v3 as iio

    def write(tmp: Path) -> None:
        if out.suffix.lower() == ".mp4":  # streamed to ffmpeg frame by frame
            # macro_block_size=2: keep the frame size (ffmpeg would pad it to 16s).
            with imageio.get_writer(tmp, fps=fps, macro_block_size=2) as writer:
                for frame in frames:
                    writer.append_data(frame)
        else:  # Pillow's GIF writer: duration per frame in milliseconds
            iio.imwrite(tmp, np.stack(list(frames)), duration=1000.0 / fps, loop=0)

    atomic_write(out, write)
