"""COLMAP loader: ``sparse/0/{cameras,images,points3D}.{bin,txt}`` + ``images/``.

The model is read with ``pycolmap`` (COLMAP's own reader, binary or text). Also accepted:
the model directly in ``sparse/`` (the layout of COLMAP's ``image_undistorter`` output).
Poses (world-to-camera, OpenCV axes: x right, y down, z forward) become NeRF
camera-to-world matrices ([right, up, back]); then, as the LLFF loader (whose functions
these are): recentred and scaled (:func:`clrender.data.llff.normalise`), scene
"unbounded", images sorted by name and every 8th (``i % 8 == 0``) held out for test / val.

Cameras: ``PINHOLE`` and ``SIMPLE_PINHOLE`` are used as they are (COLMAP's pixel centres sit
at +0.5, as ours). Any other model (``SIMPLE_RADIAL``, ``OPENCV``, fisheye ...) has lens
distortion and is refused, naming the camera, its model and parameters: undistort first
(``colmap image_undistorter`` or ``pycolmap.undistort_images`` write PINHOLE cameras).
Every file in the image folder must be a registered image (and the other way round).

A ``clrender.json`` beside ``sparse/`` (written by ``clrender capture --bounded``), with
``{"scene": "bounded", "centre": [x, y, z], "scale": s}`` in the model's world units, makes
the scene bounded: camera positions ``(c - centre) * s`` instead of the LLFF normalisation.

``downscale`` N reads ``images_N/`` (Mip-NeRF 360 ships them) where present, else shrinks
``images/``; intrinsics are scaled to the images read.

References: COLMAP output format (colmap.github.io/format.html); Mip-NeRF 360 (Barron et
al. 2022) test split.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..camera import Camera
from .dataset import check_downscale
from .llff import image_files, image_folder, normalise, split_indices
from .views import SplitViews, check_pose, check_split, image_size

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")
MODEL_FILES = ("cameras", "images", "points3D")
MARKER = "clrender.json"
OPENCV_TO_NERF = np.diag([1.0, -1.0, -1.0, 1.0])  # flip the y and z camera axes


def find_model(root: Path) -> Path | None:
    """The folder holding the COLMAP model: ``sparse/0`` or ``sparse``, else None."""
    for folder in (root / "sparse" / "0", root / "sparse"):
        if any((folder / f"cameras{ext}").is_file() for ext in (".bin", ".txt")):
            return folder
    return None


def read_model(folder: Path):
    """(cameras {id: Camera}, images [(name, camera_id, (4, 4) cam_from_world)]) of a COLMAP
    model folder, sorted by name; errors name the folder."""
    from ..extras import require

    require("capture", f"{folder}: reading a COLMAP model", modules=("pycolmap",))
    import pycolmap

    missing = [n for n in MODEL_FILES
               if not any((folder / f"{n}{ext}").is_file() for ext in (".bin", ".txt"))]
    if missing:
        raise FileNotFoundError(f"{folder}: COLMAP model incomplete, no "
                                f"{', '.join(m + '.bin/.txt' for m in missing)}")
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except (ValueError, RuntimeError) as exc:
        raise ValueError(f"{folder}: cannot read the COLMAP model ({exc})") from exc
    images = []
    for im in rec.images.values():
        if not im.has_pose:
            continue
        w2c = np.eye(4)
        w2c[:3, :4] = im.cam_from_world().matrix()
        images.append((im.name, im.camera_id, w2c))
    if not images:
        raise ValueError(f"{folder}: the COLMAP model has no registered images")
    return rec.cameras, sorted(images, key=lambda item: item[0])


def pinhole(camera, camera_id: int, folder: Path) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of a pinhole COLMAP camera; a distorted model is refused."""
    model, params = camera.model.name, [float(p) for p in camera.params]
    if model == "SIMPLE_PINHOLE":
        return params[0], params[0], params[1], params[2]
    if model == "PINHOLE":
        return tuple(params)
    raise ValueError(f"{folder}: camera {camera_id} is {model} with parameters "
                     f"{camera.params_info} = {params}: a lens-distortion model, which "
                     f"clrender does not treat as a pinhole; undistort the images first "
                     f"(colmap image_undistorter, or pycolmap.undistort_images) and load its "
                     f"output ({' / '.join(PINHOLE_MODELS)} cameras)")


def scan_colmap(path, split: str = "train", downscale: int = 1) -> SplitViews:
    """The files and cameras of one split of a COLMAP folder (image headers only)."""
    root, factor = Path(path), check_downscale(downscale)
    model = find_model(root)
    if model is None:
        raise FileNotFoundError(f"{root / 'sparse' / '0'}: COLMAP model not found")
    cameras, images = read_model(model)
    folder, resize = image_folder(root, factor)
    check_registered(folder, [name for name, _, _ in images], model)
    c2w = []
    for name, _, w2c in images:
        check_pose(w2c, f"{model}: image {name!r}")
        c2w.append(np.linalg.inv(w2c) @ OPENCV_TO_NERF)
    scene, c2w = scene_frame(root, np.stack(c2w))
    files, views, shrunk = [], [], factor // resize   # images_N/ read: shrunk N times
    for i in split_indices(len(images), split):
        name, camera_id = images[i][:2]
        file = folder / name
        w, h = image_size(file)
        cam = cameras[camera_id]
        fx, fy, cx, cy = pinhole(cam, camera_id, model)
        if abs(w - cam.width / shrunk) >= 1 or abs(h - cam.height / shrunk) >= 1:
            raise ValueError(f"{file}: image is {w}x{h}, but COLMAP camera {camera_id} is "
                             f"{cam.width}x{cam.height}" + (f" (/ {shrunk} expected in "
                                                           f"{folder.name})" if shrunk > 1 else ""))
        full = Camera(fx, fy, cx, cy, cam.width, cam.height, c2w[i])
        views.append(full.scaled_to(w, h))
        files.append(file)
    return check_split(SplitViews("colmap", root, split, scene, files, views, resize,
                                  folder))


def scene_frame(root: Path, c2w: np.ndarray) -> tuple[str, np.ndarray]:
    """(scene kind, (N, 4, 4) normalised c2w): ``root/clrender.json``'s box if present
    (bounded), else :func:`normalise` (unbounded)."""
    file = root / MARKER
    if not file.is_file():
        return "unbounded", normalise(c2w)
    try:
        box = json.loads(file.read_text())
        centre = np.asarray(box["centre"], dtype=np.float64)
        scale = float(box["scale"])
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{file}: expected {{\"scene\": \"bounded\", \"centre\": [x, y, z], "
                         f"\"scale\": s}} ({exc!r})") from exc
    if box.get("scene") != "bounded" or centre.shape != (3,) or not np.all(np.isfinite(centre)) \
            or not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"{file}: expected scene \"bounded\", a finite centre [x, y, z] and a "
                         f"positive scale, found {box}")
    out = c2w.copy()
    out[:, :3, 3] = (out[:, :3, 3] - centre) * scale
    return "bounded", out


def check_registered(folder: Path, names: list[str], model: Path) -> None:
    """Every image file of ``folder`` a registered image of ``model``, and vice versa."""
    found = {p.name for p in image_files(folder)}
    top = {n for n in names if "/" not in n}
    missing, unposed = sorted(top - found), sorted(found - set(names))
    if missing:
        raise FileNotFoundError(f"{folder / missing[0]}: image file not found ({len(missing)} "
                                f"of the {len(names)} images {model} registers are missing)")
    if unposed:
        raise ValueError(f"{folder}: {len(found)} images, but {model} has poses for "
                         f"{len(names)}; without a pose: {', '.join(unposed[:5])}"
                         f"{' ...' if len(unposed) > 5 else ''} (move them out, or register "
                         "them in COLMAP)")
