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
from tqdm import tqdm

from ..camera import Camera
from .dataset import (F32, SCENE_KINDS, Dataset, area_downscale, check_downscale, composite,
                      downscaled_camera, read_image, stack_images)

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
    root, factor = Path(path), check_downscale(downscale)
    file = root / f"transforms_{split}.json"
    meta = read_json(file)
    kind, scale = scene_info(meta, file)
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise ValueError(f"{file}: missing or empty 'frames' list")
    bg = np.asarray(background, dtype=F32).reshape(3)
    images, alphas, cameras, files = [], [], [], []
    for i, frame in enumerate(tqdm(frames, desc=f"loading {split}", disable=None, leave=False)):
        if not isinstance(frame, dict) or "file_path" not in frame:
            raise ValueError(f"{file}: frame {i} has no 'file_path'")
        img_file = image_path(file.parent, frame["file_path"])
        rgba = read_image(img_file)
        c2w = pose(frame, i, file)
        c2w[:3, 3] *= scale
        camera = intrinsics({**meta, **frame}, rgba.shape[1], rgba.shape[0], c2w, i, file)
        rgb, alpha = composite(rgba, bg)
        images.append(area_downscale(rgb, factor))
        alphas.append(None if alpha is None else area_downscale(alpha, factor))
        cameras.append(downscaled_camera(camera, factor))
        files.append(img_file)
    has_alpha = [a is not None for a in alphas]
    if any(has_alpha) and not all(has_alpha):
        raise ValueError(f"{file}: some images have an alpha channel and some do not")
    alpha = stack_images(alphas, files) if all(has_alpha) else None
    return Dataset(stack_images(images, files), cameras, kind, bg, str(root), split, alpha)


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
    if ("w" in meta and meta["w"] != width) or ("h" in meta and meta["h"] != height):
        raise ValueError(f"{file}: frame {i} image is {width}x{height}, but w, h say "
                         f"{meta.get('w', width)}x{meta.get('h', height)}")
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
