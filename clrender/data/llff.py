"""LLFF / Mip-NeRF 360 loader (``poses_bounds.npy`` + ``images[_factor]/``).

``poses_bounds.npy`` is (N, 17) float: a (3, 5) matrix per image, row-major, whose columns
are the camera axes [down, right, back], the position and [H, W, focal] (the hwf column), then
the near and far bounds. Poses are converted to NeRF's [right, up, back], recentred on an
average pose and scaled so the camera positions' largest norm is 1, as Mip-NeRF 360 / MERF do;
the scene is treated as "unbounded". Every 8th image (``i % 8 == 0``) is the test split.

References: LLFF (Mildenhall et al. 2019) poses_bounds format; Mip-NeRF 360 (Barron et al.
2022) and MERF (Reiser et al. 2023) normalisation and test split.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import Camera
from .dataset import Dataset, check_downscale
from .views import SplitViews, check_pose, check_split, image_size, read_views

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
TEST_EVERY = 8
# Mean of the cameras' unit back axes above this: a forward-facing capture (LLFF's average
# pose); below: cameras look inward from around the scene (360°), centred on their focus point.
FORWARD_FACING_MIN = 0.9


def load_llff(path, split: str = "train", downscale: int = 1,
              background=(1.0, 1.0, 1.0)) -> Dataset:
    """Load one split of an LLFF / Mip-NeRF 360 folder.

    Args:
        path: folder with ``poses_bounds.npy`` and ``images/`` (and optionally
            ``images_{downscale}/``, used as is when present).
        split: "train" (``i % 8 != 0``), "test" or "val" (both ``i % 8 == 0``).
        downscale: integer factor; reads ``images_{downscale}/`` or shrinks ``images/``.
        background: RGB in [0, 1] for images with an alpha channel.
    Returns:
        a :class:`Dataset` with scene "unbounded" and cameras in normalised space.
    """
    return read_views(scan_llff(path, split, downscale), background)


def scan_llff(path, split: str = "train", downscale: int = 1) -> SplitViews:
    """The files and cameras of one split of an LLFF folder (image headers only)."""
    root, factor = Path(path), check_downscale(downscale)
    file = root / "poses_bounds.npy"
    poses = read_poses(file)
    folder, resize = image_folder(root, factor)
    files = image_files(folder)
    if len(files) != len(poses):
        raise ValueError(f"{folder}: found {len(files)} images, but {file} has "
                         f"{len(poses)} poses")
    c2w = llff_to_nerf(poses)
    for i in range(len(poses)):
        check_pose(c2w[i], f"{file}: pose {i} ({files[i].name})")
    c2w = normalise(c2w)
    chosen = split_indices(len(poses), split)
    cameras = []
    for i in chosen:
        w, h = image_size(files[i])
        H, W, f = poses[i, :, 4]  # hwf of the original images: scale to this file's size
        cameras.append(Camera(f * w / W, f * h / H, w / 2.0, h / 2.0, w, h, c2w[i]))
    return check_split(SplitViews("llff", root, split, "unbounded", [files[i] for i in chosen],
                                  cameras, resize, folder))


def image_files(folder: Path) -> list[Path]:
    """The images of ``folder`` by name (``.png``, ``.jpg``, ``.jpeg``, any case; other
    files, e.g. ``.DS_Store`` or notes, are not images and are left out)."""
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
                  and not p.name.startswith("."))


def read_poses(file: Path) -> np.ndarray:
    """(N, 3, 5) float64 LLFF poses from ``poses_bounds.npy``; errors name the file."""
    if not file.is_file():
        raise FileNotFoundError(f"{file}: poses file not found")
    try:
        arr = np.load(file, allow_pickle=False)
    except ValueError as exc:
        raise ValueError(f"{file}: not a plain numeric .npy array ({exc})") from exc
    if arr.ndim != 2 or arr.shape[1] != 17 or arr.shape[0] == 0:
        raise ValueError(f"{file}: poses_bounds has shape {arr.shape}, expected (N, 17)")
    if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{file}: poses_bounds must hold finite numbers (dtype {arr.dtype})")
    poses = arr[:, :15].astype(np.float64).reshape(-1, 3, 5)
    if np.any(poses[:, :, 4] <= 0):
        raise ValueError(f"{file}: the hwf column (height, width, focal) must be positive")
    return poses


def image_folder(root: Path, factor: int) -> tuple[Path, int]:
    """(folder to read, factor still to shrink by): ``images_{factor}`` if present."""
    if factor > 1 and (root / f"images_{factor}").is_dir():
        return root / f"images_{factor}", 1
    folder = root / "images"
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: image folder not found"
                                + (f" (nor {root / f'images_{factor}'})" if factor > 1 else ""))
    return folder, factor


def split_indices(n: int, split: str) -> list[int]:
    """Indices of ``split`` among ``n`` images: every 8th is test (and val)."""
    if split == "train":
        return [i for i in range(n) if i % TEST_EVERY != 0]
    if split in ("test", "val"):
        return [i for i in range(n) if i % TEST_EVERY == 0]
    raise ValueError(f"split must be 'train', 'val' or 'test', got {split!r}")


def llff_to_nerf(poses: np.ndarray) -> np.ndarray:
    """(N, 4, 4) NeRF c2w [right, up, back] from (N, 3, 5) LLFF poses [down, right, back]."""
    c2w = np.tile(np.eye(4), (len(poses), 1, 1))
    c2w[:, :3, 0] = poses[:, :, 1]
    c2w[:, :3, 1] = -poses[:, :, 0]
    c2w[:, :3, 2] = poses[:, :, 2]
    c2w[:, :3, 3] = poses[:, :, 3]
    return c2w


def normalise(c2w: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses expressed in the average pose's frame, scaled to max camera norm 1."""
    out = np.linalg.inv(average_pose(c2w)) @ c2w
    radius = np.linalg.norm(out[:, :3, 3], axis=-1).max()
    if radius > 0:
        out[:, :3, 3] /= radius
    return out


def average_pose(c2w: np.ndarray) -> np.ndarray:
    """(4, 4) frame to recentre on.

    Forward-facing captures: LLFF's average pose (mean position, mean back axis, mean up).
    360° captures: origin at the point nearest to all optical axes, +z along the mean camera
    up, +x along the first camera's right axis made horizontal.
    """
    back, up = c2w[:, :3, 2].mean(0), c2w[:, :3, 1].mean(0)
    if np.linalg.norm(back) > FORWARD_FACING_MIN:
        z, centre, x_hint = back, c2w[:, :3, 3].mean(0), np.cross(up, back)
    else:
        z, centre, x_hint = up, focus_point(c2w), c2w[0, :3, 0]
    z = z / np.linalg.norm(z)
    x = x_hint - z * (x_hint @ z)
    x /= np.linalg.norm(x)
    frame = np.eye(4)
    frame[:3, 0], frame[:3, 1], frame[:3, 2], frame[:3, 3] = x, np.cross(z, x), z, centre
    return frame


def focus_point(c2w: np.ndarray) -> np.ndarray:
    """(3,) least-squares point nearest to the optical axes of (N, 4, 4) cameras."""
    d = c2w[:, :3, 2] / np.linalg.norm(c2w[:, :3, 2], axis=-1, keepdims=True)
    m = np.eye(3) - d[:, :, None] * d[:, None, :]
    return np.linalg.solve(m.sum(0), (m @ c2w[:, :3, 3, None]).sum(0))[:, 0]
