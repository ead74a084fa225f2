"""Multi-view distillation: new views among the training cameras, rendered by the teacher.

The training camera centres are converted to spherical coordinates (r, theta, phi) about the
scene centre, with the polar axis along the scene's up vector (from the cameras' up and
right vectors, :func:`scene_up`); each distillation view
draws r, theta and phi uniformly within the ranges the training cameras span (phi within
the smallest arc that holds every camera's azimuth, so a ring of cameras crossing phi = pi
is not turned into the complementary arc) and looks at the centre. The teacher (a baked
NGP-RT model) renders them with the OpenCL renderer; the images are cached in the run
folder as ``distill.npz``.

Examples:
    >>> cams = distillation_cameras(train.cameras, 1000, seed=0)
    >>> images = render_teacher("teacher.npz", cams, train.background)   # (1000, H, W, 3)
    >>> cams, images = cached_distillation("run/", "teacher.npz", train.cameras, 1000, 0,
    ...                                    train.background)

References: NDRF (Wan et al., CVPR 2023) §3.3, Fig. 6; R2L (Wang et al., ECCV 2022).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..atomic import atomic_write
from ..camera import Camera, look_at

F32 = np.float32
TWO_PI = 2.0 * np.pi


def scene_up(cameras) -> np.ndarray:
    """(3,) float64 unit world up vector of a set of cameras.

    The cameras' mean up vector (the +y column of their c2w) leans towards the cameras when
    they look down at the scene from one side; cameras without roll all have their right
    vectors (+x columns) perpendicular to the world up, so when those right vectors span a
    plane (cameras at different azimuths) its normal is taken instead, oriented like the
    mean up vector.
    """
    c2w = np.stack([np.asarray(c.c2w, np.float64)[:3, :3] for c in cameras])
    up = c2w[:, :, 1].mean(axis=0)
    n = np.linalg.norm(up)
    if not n > 1e-6:
        raise ValueError("distillation: the training cameras' up vectors cancel out; "
                         "cannot choose a polar axis")
    right = c2w[:, :, 0]
    w, V = np.linalg.eigh(right.T @ right / len(right))
    if w[1] > 1e-3 and w[0] < 0.05 * w[1]:          # the right vectors span a plane
        normal = V[:, 0]
        return normal if normal @ up >= 0 else -normal
    return up / n


def spherical_frame(cameras, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(3, 3) float64 rows (e1, e2, up): the polar axis is :func:`scene_up`, e1 and e2
    complete a right-handed frame."""
    up = scene_up(cameras)
    seed_axis = np.eye(3)[int(np.argmin(np.abs(up)))]
    e1 = seed_axis - up * float(seed_axis @ up)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1), up])


def to_spherical(points: np.ndarray, frame: np.ndarray, centre=(0.0, 0.0, 0.0)):
    """(r, theta, phi), each (M,) float64, of world points (M, 3) about ``centre``:
    theta the polar angle from ``frame[2]`` in [0, pi], phi the azimuth in [0, 2 pi)."""
    p = (np.asarray(points, np.float64) - np.asarray(centre, np.float64)) @ frame.T
    r = np.linalg.norm(p, axis=1)
    theta = np.arccos(np.clip(p[:, 2] / np.maximum(r, 1e-12), -1.0, 1.0))
    phi = np.mod(np.arctan2(p[:, 1], p[:, 0]), TWO_PI)
    return r, theta, phi


def azimuth_arc(phi: np.ndarray) -> tuple[float, float]:
    """``(start, width)`` of the smallest arc (counter-clockwise from ``start``) holding
    every azimuth ``phi`` (radians): the circle minus its largest gap between cameras."""
    p = np.sort(np.mod(np.asarray(phi, np.float64), TWO_PI))
    gaps = np.diff(np.concatenate([p, [p[0] + TWO_PI]]))
    i = int(np.argmax(gaps))
    return float(p[(i + 1) % len(p)]), float(TWO_PI - gaps[i])


def distillation_cameras(train_cameras, n: int, seed: int = 0,
                         centre=(0.0, 0.0, 0.0)) -> list[Camera]:
    """``n`` cameras drawn uniformly in the (r, theta, phi) ranges of ``train_cameras``.

    Args:
        train_cameras: the training :class:`Camera` list (NeRF convention).
        n: number of views (paper: 1000).
        seed: seed of the generator.
        centre: scene centre in world units (the origin for bounded scenes).
    Returns:
        cameras with the intrinsics of ``train_cameras[0]``, each at
        ``centre + r (sin theta cos phi e1 + sin theta sin phi e2 + cos theta up)`` looking
        at ``centre`` with ``up`` from :func:`scene_up`.
    """
    cams = list(train_cameras)
    if not cams or n < 0:
        raise ValueError(f"distillation_cameras: need training cameras and n >= 0, got "
                         f"{len(cams)} cameras, n={n}")
    frame = spherical_frame(cams, centre)
    r, theta, phi = to_spherical(np.stack([c.origin for c in cams]), frame, centre)
    phi0, width = azimuth_arc(phi)
    rng = np.random.default_rng(seed)
    rs = rng.uniform(r.min(), r.max(), n)
    ts = rng.uniform(theta.min(), theta.max(), n)
    ps = phi0 + rng.uniform(0.0, width, n)
    local = np.stack([np.sin(ts) * np.cos(ps), np.sin(ts) * np.sin(ps), np.cos(ts)], -1)
    eyes = np.asarray(centre, np.float64) + rs[:, None] * (local @ frame)
    c0 = cams[0]
    return [Camera(c0.fx, c0.fy, c0.cx, c0.cy, c0.width, c0.height,
                   look_at(e, centre, frame[2])) for e in eyes]


def render_teacher(teacher, cameras, background, device=None,
                   progress: bool = True) -> np.ndarray:
    """Render ``cameras`` with the teacher's OpenCL renderer.

    Args:
        teacher: a baked model (any method) or its path.
        background: RGB in [0, 1] behind the model.
        device: OpenCL device spec.
    Returns:
        (n, H, W, 3) float32 in [0, 1].
    """
    from ..renderer import Renderer

    cameras = list(cameras)
    if not cameras:
        return np.zeros((0, 0, 0, 3), F32)
    renderer = Renderer(teacher, device=device)
    c0 = cameras[0]
    out = np.empty((len(cameras), c0.height, c0.width, 3), F32)
    for i, cam in enumerate(tqdm(cameras, desc="teacher", unit="view", disable=not progress)):
        out[i] = np.clip(renderer.render(cam, background=background)["rgb"], 0.0, 1.0)
    return out


def save_distill(path, cameras, images: np.ndarray, spec: dict) -> Path:
    """Write poses, intrinsics, images and the JSON ``spec`` they were made from, atomically.

    Images are stored as float16 (error below 2.5e-4 in [0, 1], finer than 8-bit data).
    """
    arrays = {"c2w": np.stack([c.c2w for c in cameras]).astype(np.float64),
              "intrinsics": np.array([[c.fx, c.fy, c.cx, c.cy, c.width, c.height]
                                      for c in cameras], np.float64),
              "images": np.asarray(images, np.float16),
              "spec": np.array(json.dumps(spec, sort_keys=True))}
    return atomic_write(Path(path), lambda tmp: np.savez(tmp, **arrays))


def load_distill(path) -> tuple[list[Camera], np.ndarray, dict]:
    """``(cameras, images (n, H, W, 3) float16, spec)`` of :func:`save_distill`."""
    with np.load(path, allow_pickle=False) as z:
        c2w, intr, images = z["c2w"], z["intrinsics"], z["images"]
        spec = json.loads(str(z["spec"]))
    if len(c2w) != len(intr) or len(c2w) != len(images):
        raise ValueError(f"{path}: {len(c2w)} poses, {len(intr)} intrinsics and "
                         f"{len(images)} images, expected equal counts")
    cams = [Camera(float(i[0]), float(i[1]), float(i[2]), float(i[3]), int(i[4]), int(i[5]), m)
            for m, i in zip(c2w, intr)]
    return cams, images, spec


def cached_distillation(run_dir, teacher, train_cameras, n: int, seed: int, background,
                        teacher_key: str = "", device=None, progress: bool = True):
    """The distillation views of a run: ``RUN/distill.npz`` when it was made from the same
    (n, seed, teacher_key, training poses), else rendered and written there.

    Returns:
        cameras (list of n :class:`Camera`), images (n, H, W, 3) float16 in [0, 1].
    """
    cams = list(train_cameras)
    spec = {"n": int(n), "seed": int(seed), "teacher": str(teacher_key),
            "background": [float(b) for b in np.asarray(background).reshape(3)],
            "train_c2w": np.round(np.stack([c.c2w for c in cams]), 6).tolist()}
    spec = json.loads(json.dumps(spec, sort_keys=True))
    path = Path(run_dir) / "distill.npz"
    if path.is_file():
        try:
            cached_cams, images, cached_spec = load_distill(path)
            if cached_spec == spec:
                return cached_cams, images
        except (ValueError, KeyError, OSError):
            pass                                    # unreadable or stale: render again
    views = distillation_cameras(cams, n, seed)
    images = render_teacher(teacher, views, background, device=device, progress=progress)
    save_distill(path, views, images, spec)
    return views, images.astype(np.float16)
