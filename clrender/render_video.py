"""Render a baked NGP-RT model along a camera path into a video or a folder of PNGs.

Paths:
    ``orbit``: a circle around the origin looking at it; radius and elevation from the
        scene type (bounded: radius 3, 30 degrees up; unbounded: radius 1, 15 degrees up).
    ``spiral``: the LLFF-style spiral around the mean of a dataset's training cameras.
    ``test``: a dataset's test cameras, in order (at most ``frames``).

Examples:
    >>> render_path("model.npz", "orbit.mp4", frames=60)
    >>> render_path("model.npz", "frames/", path="test", data="data/lego", width=200, height=200)
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from .atomic import atomic_write
from .camera import Camera, orbit_path, spiral_path

VIDEO_SUFFIXES = (".mp4", ".gif")
ORBIT = {"bounded": dict(radius=3.0, elevation_deg=30.0, fov_x=0.69),
         "unbounded": dict(radius=1.0, elevation_deg=15.0, fov_x=1.2)}


def _fit(camera: Camera, width: int, height: int) -> Camera:
    """``camera`` with its intrinsics scaled to a ``width`` x ``height`` image."""
    sx, sy = width / camera.width, height / camera.height
    return replace(camera, fx=camera.fx * sx, fy=camera.fy * sy, cx=camera.cx * sx,
                   cy=camera.cy * sy, width=int(width), height=int(height))


def path_cameras(scene: str, path: str, frames: int, width: int, height: int,
                 data=None) -> list[Camera]:
    """The cameras of a render path (see the module doc) at ``width`` x ``height``."""
    if path == "orbit":
        o = ORBIT[scene]
        return [Camera.from_fov(o["fov_x"], width, height, c2w)
                for c2w in orbit_path(frames, o["radius"], o["elevation_deg"])]
    if path not in ("spiral", "test"):
        raise ValueError(f"unknown camera path {path!r}; expected 'orbit', 'spiral' or 'test'")
    if data is None:
        raise ValueError(f"path={path!r} needs a dataset (data=...) for its cameras")
    from .data import load_dataset

    ds = load_dataset(data, "train" if path == "spiral" else "test")
    if not ds.cameras:
        raise ValueError(f"{data}: the dataset has no cameras for path={path!r}")
    if path == "test":
        return [_fit(c, width, height) for c in ds.cameras[:frames]]
    base = _fit(ds.cameras[0], width, height)
    return [replace(base, c2w=c2w)
            for c2w in spiral_path(np.stack([c.c2w for c in ds.cameras]), frames)]


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _write_png(path: Path, frame: np.ndarray) -> None:
    import imageio.v3 as iio

    atomic_write(path, lambda tmp: iio.imwrite(tmp, frame))


def render_path(model_path, out, path: str = "orbit", frames: int = 60, width: int = 400,
                height: int = 400, data=None, device=None, background=(1.0, 1.0, 1.0),
                fps: int = 30, use_G: bool = True) -> Path:
    """Render ``frames`` views of a baked model along ``path`` into ``out``.

    Args:
        model_path: a baked model file (or an already loaded BakedModel).
        out: a ``.mp4`` / ``.gif`` file, or a folder that receives ``frame_0000.png``, ...
        path: ``orbit``, ``spiral`` or ``test`` (see the module doc).
        data: dataset (path or name for :func:`clrender.data.load_dataset`) whose
            cameras define ``spiral`` and ``test``.
        device, use_G: as for :class:`clrender.ngprt.render_cl.Renderer`.
        background: RGB in [0, 1] behind the model.
        fps: frame rate of a video.
    Returns:
        the path written. Files are written to a temporary name and moved into place.
    """
    from .ngprt.render_cl import Renderer

    if hasattr(model_path, "config"):
        model = model_path
    else:
        from .ngprt.baked import load_baked

        model = load_baked(model_path)
    out = Path(out)
    if out.suffix.lower() == ".mp4" and (width % 2 or height % 2):
        raise ValueError(f"{out}: an .mp4 (H.264, yuv420p) needs an even width and height, "
                         f"got {width}x{height}")
    cameras = path_cameras(model.config.scene, path, frames, width, height, data)
    renderer = Renderer(model, device=device, use_G=use_G)
    frames_iter = (_to_uint8(renderer.render(c, background=background)["rgb"])
                   for c in tqdm(cameras, desc=f"render {path}", unit="frame"))
    if out.suffix.lower() in VIDEO_SUFFIXES:
        _write_video(out, frames_iter, fps)
    else:
        out.mkdir(parents=True, exist_ok=True)
        for i, frame in enumerate(frames_iter):
            _write_png(out / f"frame_{i:04d}.png", frame)
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
