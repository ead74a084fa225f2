"""What a loader sees of one split before reading pixels, and reading it into a Dataset.

Every loader first *scans* a split: its files, poses and intrinsics, and each image's size
from its header (no pixels decoded), checked there (rigid finite poses, one image size per
split, a non-empty split). :func:`read_views` then decodes the images, checks each against
its header, composites RGBA and shrinks by the factor still due. ``clrender data check``
prints a scan; training reads it.

Examples:
    >>> views = scan_dataset("data/fern", "train", downscale=8)   # clrender.data.load
    >>> views.cameras[0].width, views.scene, views.format
    (504, 'unbounded', 'llff')
    >>> ds = read_views(views)                                     # ds.images (N, H, W, 3)
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError
from tqdm import tqdm

from ..camera import Camera
from .dataset import (F32, Dataset, area_downscale, composite, downscaled_camera, read_image,
                      stack_images)

RIGID_TOLERANCE = 1e-3   # max |R^T R - I| entry of a pose's rotation (float32-printed poses)


@dataclass
class SplitViews:
    """One split as a loader scanned it: files and cameras, no pixels.

    Attributes:
        format: "blender", "transforms" (nerfstudio / instant-ngp), "llff" or "colmap".
        root: the dataset folder.
        split: "train", "val" or "test".
        scene: "bounded" or "unbounded".
        files: the image files, one per view.
        cameras: one :class:`Camera` per file at the file's own size (normalised space).
        resize: integer factor the images are still to be shrunk by after reading.
        source: the image folder or index file read (for messages and summaries).
    """

    format: str
    root: Path
    split: str
    scene: str
    files: list[Path]
    cameras: list[Camera]
    resize: int
    source: Path

    def final_cameras(self) -> list[Camera]:
        """The cameras of the images :func:`read_views` returns (after ``resize``)."""
        return [downscaled_camera(c, self.resize) for c in self.cameras]


def image_size(file: Path) -> tuple[int, int]:
    """(width, height) of an image from its header; errors name the file."""
    if not file.is_file():
        raise FileNotFoundError(f"{file}: image file not found")
    try:
        with Image.open(file) as im:
            return im.size
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise ValueError(f"{file}: not a readable image ({exc})") from exc


def check_pose(c2w: np.ndarray, where: str) -> np.ndarray:
    """(4, 4) float64 ``c2w`` if finite and rigid (orthonormal rotation, det +1, last row
    [0, 0, 0, 1]); else a ValueError starting with ``where``."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if not np.all(np.isfinite(c2w)):
        raise ValueError(f"{where}: pose has non-finite values (NaN or inf)")
    R = c2w[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > RIGID_TOLERANCE or np.linalg.det(R) < 0:
        raise ValueError(f"{where}: pose is not rigid (rotation off orthonormal by {err:.3g}, "
                         f"det {np.linalg.det(R):.3g}; expected a rotation and a translation)")
    if c2w.shape == (4, 4) and np.abs(c2w[3] - [0, 0, 0, 1]).max() > RIGID_TOLERANCE:
        raise ValueError(f"{where}: pose's last row is {c2w[3].tolist()}, expected [0, 0, 0, 1]")
    return c2w


def check_split(views: SplitViews) -> SplitViews:
    """``views`` if non-empty with one image size; errors name the source and the file."""
    if not views.files:
        raise ValueError(f"{views.source}: split {views.split!r} has no images")
    sizes = Counter((c.width, c.height) for c in views.cameras)
    (w, h), n = sizes.most_common(1)[0]
    for file, cam in zip(views.files, views.cameras):
        if (cam.width, cam.height) != (w, h):
            raise ValueError(f"{file}: image is {cam.width}x{cam.height}, but {n} of the "
                             f"{len(views.files)} images of split {views.split!r} are {w}x{h} "
                             "(one size per split)")
    return views


def read_views(views: SplitViews, background=(1.0, 1.0, 1.0)) -> Dataset:
    """Decode the images of ``views`` into a :class:`Dataset`.

    Args:
        background: RGB in [0, 1] that RGBA images are composited on.
    Returns:
        images (N, H / resize, W / resize, 3) float32, cameras scaled to match.
    """
    bg = np.asarray(background, dtype=F32).reshape(3)
    images, alphas = [], []
    for file, cam in tqdm(list(zip(views.files, views.cameras)), desc=f"loading {views.split}",
                          disable=None, leave=False):
        rgba = read_image(file)
        if rgba.shape[:2] != (cam.height, cam.width):
            raise ValueError(f"{file}: decoded image is {rgba.shape[1]}x{rgba.shape[0]}, its "
                             f"header says {cam.width}x{cam.height}")
        rgb, alpha = composite(rgba, bg)
        images.append(area_downscale(rgb, views.resize))
        alphas.append(None if alpha is None else area_downscale(alpha, views.resize))
    has_alpha = [a is not None for a in alphas]
    if any(has_alpha) and not all(has_alpha):
        raise ValueError(f"{views.source}: some images of split {views.split!r} have an alpha "
                         "channel and some do not")
    alpha = stack_images(alphas, views.files) if all(has_alpha) else None
    return Dataset(stack_images(images, views.files), views.final_cameras(), views.scene, bg,
                   str(views.root), views.split, alpha)
