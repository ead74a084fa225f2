"""Camera paths: an orbit around the scene, an LLFF-style spiral, a dataset's test views.

Paths:
    ``orbit``: a circle around the origin looking at it; radius and elevation from the
        scene type (bounded: radius 3, 30 degrees up; unbounded: radius 1, 15 degrees up).
    ``spiral``: the LLFF-style spiral around the mean of a dataset's training cameras.
    ``test``: a dataset's test cameras, in order (at most ``frames``).

Examples:
    >>> cams = path_cameras("bounded", "orbit", frames=60, width=400, height=400)
    >>> poses = orbit_path(8, radius=3.0)          # (4, 4) camera-to-world matrices
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .camera import Camera, look_at

PATHS = ("orbit", "spiral", "test")
ORBIT = {"bounded": dict(radius=3.0, elevation_deg=30.0, fov_x=0.69),
         "unbounded": dict(radius=1.0, elevation_deg=15.0, fov_x=1.2)}


def orbit_path(n_frames: int, radius: float, elevation_deg: float = 30.0,
               target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> list[np.ndarray]:
    """``n_frames`` camera-to-world matrices on a circle around ``target`` (z up)."""
    el = np.deg2rad(elevation_deg)
    poses = []
    for az in np.linspace(0.0, 2 * np.pi, n_frames, endpoint=False):
        eye = np.asarray(target) + radius * np.array(
            [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        poses.append(look_at(eye, target, up))
    return poses


def spiral_path(c2ws: np.ndarray, n_frames: int, n_rots: float = 2.0,
                radius_scale: float = 1.0, focus_depth: float | None = None) -> list[np.ndarray]:
    """A forward-facing spiral around the mean of ``c2ws`` ((N, 4, 4) or (N, 3, 4)).

    The spiral radius is the 90th percentile of camera offsets from their mean along
    each axis of the mean pose, as in the LLFF render paths.
    """
    c2ws = np.asarray(c2ws, dtype=np.float64)[:, :3, :4]
    centre = c2ws[:, :, 3].mean(0)
    fwd = -c2ws[:, :, 2].mean(0)
    fwd /= np.linalg.norm(fwd)
    up = c2ws[:, :, 1].mean(0)
    mean_pose = look_at(centre, centre + fwd, up)
    offsets = (c2ws[:, :, 3] - centre) @ mean_pose[:3, :3]
    rads = np.percentile(np.abs(offsets), 90, axis=0) * radius_scale
    focus = focus_depth if focus_depth is not None else max(
        1.0, float(np.median(np.linalg.norm(c2ws[:, :, 3], axis=1))))
    target = centre + focus * fwd
    poses = []
    for theta in np.linspace(0.0, 2 * np.pi * n_rots, n_frames, endpoint=False):
        local = np.array([np.cos(theta), -np.sin(theta), -np.sin(0.5 * theta)]) * rads
        eye = centre + mean_pose[:3, :3] @ local
        poses.append(look_at(eye, target, up))
    return poses


def path_cameras(scene: str, path: str, frames: int, width: int, height: int,
                 data=None, downscale: int = 1) -> list[Camera]:
    """The cameras of a render path (see the module doc) at ``width`` x ``height``; a
    dataset folder ``data`` is scanned at ``downscale`` (image headers, no pixels)."""
    if path == "orbit":
        o = ORBIT[scene]
        return [Camera.from_fov(o["fov_x"], width, height, c2w)
                for c2w in orbit_path(frames, o["radius"], o["elevation_deg"])]
    if path not in PATHS:
        raise ValueError(f"unknown camera path {path!r}; expected one of {PATHS}")
    if data is None:
        raise ValueError(f"path={path!r} needs a dataset (data=...) for its cameras")
    from .data import scan_dataset

    ds = scan_dataset(data, "train" if path == "spiral" else "test", downscale)  # non-empty
    if path == "test":
        return [c.scaled_to(width, height) for c in ds.cameras[:frames]]
    base = ds.cameras[0].scaled_to(width, height)
    return [replace(base, c2w=c2w)
            for c2w in spiral_path(np.stack([c.c2w for c in ds.cameras]), frames)]
