"""Pinhole cameras (NeRF/Blender convention) and ray generation (camera paths: paths.py).

Convention: ``c2w`` is a 4x4 camera-to-world matrix; the camera looks down its
-z axis with +y up and +x right; pixel centres sit at +0.5.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

F32 = np.float32
# The camera record's floats (Camera.packed(); its layout: kernels/camera.h).
CAM_FLOATS = 16
CAM_BYTES = CAM_FLOATS * 4


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes:
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels (image centre is ``width / 2``).
        width, height: image size in pixels.
        c2w: (4, 4) float64 camera-to-world matrix (NeRF/Blender convention).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    c2w: np.ndarray = field(repr=False)

    def __post_init__(self):
        c2w = np.asarray(self.c2w, dtype=np.float64)
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
            raise ValueError(f"Camera.c2w must be a finite (4, 4) matrix, got shape {c2w.shape}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Camera size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "c2w", c2w)

    @classmethod
    def from_fov(cls, fov_x_rad: float, width: int, height: int, c2w) -> "Camera":
        """A centred camera with horizontal field of view ``fov_x_rad`` (radians)."""
        f = 0.5 * width / np.tan(0.5 * fov_x_rad)
        return cls(f, f, width / 2.0, height / 2.0, int(width), int(height), c2w)

    @property
    def origin(self) -> np.ndarray:
        """(3,) float64 camera centre in world space."""
        return self.c2w[:3, 3].copy()

    def scaled_to(self, width: int, height: int) -> "Camera":
        """The same view with its intrinsics scaled to a ``width`` x ``height`` image."""
        sx, sy = width / self.width, height / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy,
                       width=int(width), height=int(height))

    def resized(self, factor: float) -> "Camera":
        """The same view with the image scaled by ``factor`` (0.5 halves width and height)."""
        return self.scaled_to(max(1, round(self.width * factor)),
                              max(1, round(self.height * factor)))

    def packed(self) -> np.ndarray:
        """(CAM_FLOATS,) float32 [fx, fy, cx, cy, R (row-major 3x3), origin (3)] for kernels
        (``kernels/camera.h``)."""
        out = np.zeros(CAM_FLOATS, dtype=F32)
        out[:4] = (self.fx, self.fy, self.cx, self.cy)
        out[4:13] = self.c2w[:3, :3].reshape(-1)
        out[13:16] = self.c2w[:3, 3]
        return out


def generate_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the pixel centres, in float32, bit-identical to ``kernels/camera.cl``.

    Returns:
        origins: (H, W, 3) float32 world-space ray origins.
        dirs: (H, W, 3) float32 unit world-space directions.
    """
    p = camera.packed()
    fx, fy, cx, cy = p[0], p[1], p[2], p[3]
    R = p[4:13].reshape(3, 3)
    x = np.arange(camera.width, dtype=F32)[None, :] + F32(0.5)
    y = np.arange(camera.height, dtype=F32)[:, None] + F32(0.5)
    a = np.broadcast_to((x - cx) / fx, (camera.height, camera.width))
    b = np.broadcast_to(-((y - cy) / fy), (camera.height, camera.width))
    # d = R @ (a, b, -1), written term by term in the kernel's order.
    d = [R[i, 0] * a + R[i, 1] * b - R[i, 2] for i in range(3)]
    norm = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    dirs = np.stack([di / norm for di in d], axis=-1).astype(F32)
    origins = np.broadcast_to(p[13:16], dirs.shape).astype(F32)
    return origins, dirs


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) camera-to-world matrix at ``eye`` looking at ``target`` (NeRF convention)."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-8:  # looking along `up`: pick any perpendicular
        right = np.cross([1.0, 0.0, 0.0] if abs(back[0]) < 0.9 else [0.0, 1.0, 0.0], back)
    right /= np.linalg.norm(right)
    cam_up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, cam_up, back, eye
    return c2w


def generate_rays_cl(camera: Camera, device=None) -> tuple[np.ndarray, np.ndarray]:
    """The same rays as :func:`generate_rays`, computed by ``kernels/camera.cl``."""
    import pyopencl as cl

    from .device import get_runtime

    rt = get_runtime(device)
    kernel = rt.program("camera.cl").kernel("generate_rays")
    n = camera.width * camera.height
    mf = cl.mem_flags
    cam = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=camera.packed())
    o_buf = cl.Buffer(rt.context, mf.WRITE_ONLY, 12 * n)
    d_buf = cl.Buffer(rt.context, mf.WRITE_ONLY, 12 * n)
    kernel(rt.queue, (camera.width, camera.height), None, cam, np.int32(camera.width),
           np.int32(camera.height), o_buf, d_buf)
    origins, dirs = np.empty((n, 3), F32), np.empty((n, 3), F32)
    cl.enqueue_copy(rt.queue, origins, o_buf)
    cl.enqueue_copy(rt.queue, dirs, d_buf)
    shape = (camera.height, camera.width, 3)
    return origins.reshape(shape), dirs.reshape(shape)
