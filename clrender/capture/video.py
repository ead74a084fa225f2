"""Frames of a video for structure from motion: the video cut into ``max_frames`` equal
windows of consecutive frames, the sharpest frame of each kept (variance of the Laplacian
of its grey image, a standard focus measure: motion blur lowers it).

The video is decoded twice (scores, then the chosen frames), so memory holds one frame.

References: Pech-Pacheco et al. 2000, "Diatom autofocusing in brightfield microscopy: a
comparative study" (variance of the Laplacian).
"""
from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
from skimage.color import rgb2gray
from skimage.filters import laplace
from tqdm import tqdm

from .frames import check_count

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm")
JPEG_QUALITY = 95


def sharpness(rgb: np.ndarray) -> float:
    """Variance of the Laplacian of (H, W, 3) uint8 ``rgb`` as grey in [0, 1]."""
    return float(laplace(rgb2gray(rgb[..., :3])).var())


def window_picks(scores: np.ndarray, max_frames: int) -> list[int]:
    """Indices of the sharpest of each of ``min(max_frames, len(scores))`` equal windows
    of consecutive ``scores`` (N,) (ties: the earliest)."""
    windows = np.array_split(np.arange(len(scores)), min(max_frames, len(scores)))
    return [int(w[np.argmax(scores[w])]) for w in windows]


def _frames(file: Path):
    """Decoded (H, W, 3) uint8 frames of ``file``; errors name the file."""
    try:
        yield from iio.imiter(file, plugin="FFMPEG")
    except (OSError, RuntimeError, ValueError, StopIteration) as exc:
        raise ValueError(f"{file}: cannot decode the video ({exc})") from exc


def extract_frames(file: Path, dest: Path, max_frames: int) -> dict:
    """Write the sharpest frame of each window of ``file`` to ``dest`` as
    ``frame_{index:06d}.jpg``.

    Returns:
        {"source": "video", "given": frames decoded, "kept": [frame indices],
        "size": [W, H], "transparent": False}.
    """
    if max_frames < 1:
        raise ValueError(f"--frames must be at least 1, got {max_frames}")
    scores = [sharpness(f) for f in tqdm(_frames(file), desc="frames: scoring video",
                                         unit="frame", disable=None)]
    check_count(min(len(scores), max_frames), file)
    picks = set(window_picks(np.asarray(scores), max_frames))
    size = None
    for i, frame in enumerate(tqdm(_frames(file), total=len(scores), unit="frame",
                                   desc="frames: writing the sharpest", disable=None)):
        if i in picks:
            size = frame.shape[1::-1]
            iio.imwrite(dest / f"frame_{i:06d}.jpg", frame[..., :3], quality=JPEG_QUALITY)
    return {"source": "video", "given": len(scores), "kept": sorted(picks),
            "size": list(size), "transparent": False}
