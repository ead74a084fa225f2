"""Blender / NeRF-synthetic loader (``transforms_{split}.json``, instant-ngp keys accepted).

A top-level ``"clrender": {"scene": "bounded" | "unbounded", "scale": s}`` key (written by
:func:`clrender.data.make_scene`) says how to normalise; without it the folder is taken for a
NeRF-synthetic scene: bounded, objects within radius 1.5, so scale 2/3 maps them into
[-1, 1]^3. The scale multiplies the camera translations.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..camera import Camera
from .dataset import SCENE_KINDS, Dataset, check_downscale
from .views import SplitViews, check_pose, check_split, image_size, read_views

NERF_SYNTHETIC_SCALE = 2.0 / 3.0


def load_blender(path, split: str = "train", downscale: int = 1,
                 background=(1.0, 1.0, 1.0)) -> Dataset:
    """Load ``path/transforms_{split}.json`` and its images.

    Args:
        path: dataset folder.
        split: "train", "val" or "test".
        downscale: integer shrink factor (box averaging; intrinsics scaled to match).
        background: RGB in [0, 1] that RGBA images are composited on.
    Returns:
        a :class:`Dataset` with images (N, H/downscale, W/downscale, 3) float32.
    """
    return read_views(scan_blender(path, split, downscale), background)


def scan_blender(path, split: str = "train", downscale: int = 1) -> SplitViews:
    """The files and cameras of ``path/transforms_{split}.json`` (image headers only)."""
    root, factor = Path(path), check_downscale(downscale)
    file = root / f"transforms_{split}.json"
    meta = read_json(file)
    kind, scale = scene_info(meta, file)
    frames = meta.get("frames")
    poses = frame_poses(frames, file)
    poses[:, :3, 3] *= scale
    files, cameras = frame_views(meta, frames, poses, file)
    return check_split(SplitViews("blender", root, split, kind, files, cameras, factor, file))


def frame_poses(frames, file: Path) -> np.ndarray:
    """(N, 4, 4) float64 checked camera-to-world matrices of a transforms file's ``frames``."""
    if not isinstance(frames, list) or not frames:
        raise ValueError(f"{file}: missing or empty 'frames' list")
    poses = []
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict) or "file_path" not in frame:
            raise ValueError(f"{file}: frame {i} has no 'file_path'")
        poses.append(check_pose(pose(frame, i, file), f"{file}: frame {i} "
                                                      f"({frame['file_path']})"))
    return np.stack(poses)


def frame_views(meta: dict, frames: list, poses: np.ndarray, file: Path, indices=None,
                locate=None, prescaled: int = 1) -> tuple[list[Path], list[Camera]]:
    """(image files, cameras at their header sizes) of a transforms file's frames.

    Args:
        meta: the file's top-level object (global intrinsics; a frame's keys override them).
        frames, poses: every frame and its (4, 4) camera-to-world (:func:`frame_poses`,
            already normalised).
        indices: the frames to take (default all).
        locate: ``file_path -> Path`` of a frame's image; default :func:`image_path`
            beside ``file``.
        prescaled: the images were shrunk by this factor from the ``w`` x ``h`` the
            intrinsics describe (an ``images_N/`` folder).
    """
    locate = locate or (lambda file_path: image_path(file.parent, file_path))
    files, cameras = [], []
    for i in range(len(frames)) if indices is None else indices:
        img_file = locate(frames[i]["file_path"])
        width, height = image_size(img_file)
        m = {**meta, **frames[i]}
        full = declared_size(m, width, height, prescaled, img_file, file)
        cameras.append(intrinsics(m, *full, poses[i], i, file).scaled_to(width, height))
        files.append(img_file)
    return files, cameras


def declared_size(meta: dict, width: int, height: int, factor: int, img_file: Path,
                  file: Path) -> tuple[int, int]:
    """(w, h) the intrinsics of a frame describe, its ``width`` x ``height`` image shrunk
    ``factor`` times from them; an image of another size is refused."""
    w, h = meta.get("w", width * factor), meta.get("h", height * factor)
    if abs(width - w / factor) >= 1 or abs(height - h / factor) >= 1:
        shrunk = f" shrunk {factor} times" if factor > 1 else ""
        raise ValueError(f"{img_file}: image is {width}x{height}, but w, h of {file.name} "
                         f"say {w}x{h}{shrunk}")
    return int(w), int(h)


def read_json(file: Path) -> dict:
    """The JSON object in ``file``; errors name the file."""
    if not file.is_file():
        raise FileNotFoundError(f"{file}: transforms file not found")
    try:
        meta = json.loads(file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{file}: malformed JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise ValueError(f"{file}: expected a JSON object at the top level")
    return meta


def scene_info(meta: dict, file: Path) -> tuple[str, float]:
    """(scene kind, scale into normalised space) from the optional ``"clrender"`` key."""
    info = meta.get("clrender")
    if info is None:
        return "bounded", NERF_SYNTHETIC_SCALE
    kind, scale = info.get("scene", "bounded"), info.get("scale", 1.0)
    if kind not in SCENE_KINDS:
        raise ValueError(f"{file}: clrender.scene is {kind!r}, expected one of {SCENE_KINDS}")
    if not isinstance(scale, (int, float)) or not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"{file}: clrender.scale is {scale!r}, expected a positive number")
    return kind, float(scale)


def image_path(folder: Path, file_path: str) -> Path:
    """The image of a frame: ``file_path`` relative to the JSON, ``.png`` added if absent."""
    p = folder / file_path
    return p if p.suffix else p.with_name(p.name + ".png")


def pose(frame: dict, i: int, file: Path) -> np.ndarray:
    """(4, 4) float64 camera-to-world of frame ``i``."""
    if "transform_matrix" not in frame:
        raise ValueError(f"{file}: frame {i} has no 'transform_matrix'")
    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{file}: frame {i} transform_matrix is not numeric ({exc})") from exc
    if c2w.shape != (4, 4):
        raise ValueError(f"{file}: frame {i} transform_matrix has shape {c2w.shape}, "
                         "expected (4, 4)")
    if not np.all(np.isfinite(c2w)):
        raise ValueError(f"{file}: frame {i} transform_matrix has non-finite values")
    return c2w.copy()


def intrinsics(meta: dict, width: int, height: int, c2w: np.ndarray, i: int,
               file: Path) -> Camera:
    """Camera of frame ``i`` from camera_angle_x/y or instant-ngp's fl_x, fl_y, cx, cy, w, h."""
    if "fl_x" in meta:
        fx = float(meta["fl_x"])
    elif "camera_angle_x" in meta:
        fx = 0.5 * width / np.tan(0.5 * float(meta["camera_angle_x"]))
    else:
        raise ValueError(f"{file}: frame {i} has no focal length, expected 'camera_angle_x' "
                         "or 'fl_x'")
    if "fl_y" in meta:
        fy = float(meta["fl_y"])
    elif "camera_angle_y" in meta:
        fy = 0.5 * height / np.tan(0.5 * float(meta["camera_angle_y"]))
    else:
        fy = fx
    cx, cy = float(meta.get("cx", width / 2.0)), float(meta.get("cy", height / 2.0))
    if not all(np.isfinite(v) and v > 0 for v in (fx, fy)):
        raise ValueError(f"{file}: frame {i} focal lengths {fx}, {fy} are not positive")
    return Camera(fx, fy, cx, cy, width, height, c2w)
