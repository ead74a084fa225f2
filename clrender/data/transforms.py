"""nerfstudio / instant-ngp loader: one ``transforms.json`` for every split.

The file holds ``frames`` (``file_path``, ``transform_matrix``: camera-to-world in the
NeRF / OpenGL convention) and intrinsics, global or per frame: ``fl_x fl_y cx cy w h`` or
``camera_angle_x`` (the keys the Blender loader reads too, whose code this shares).

Splits: nerfstudio's ``train_filenames`` / ``val_filenames`` / ``test_filenames`` lists
when present (``test`` falls back to ``val`` and the other way round, as nerfstudio
evaluates on its val list); otherwise every 8th frame (``i % 8 == 0``) is test and val, as
the LLFF loader.

Bounded or unbounded: a ``"clrender"`` key decides when present (as in the Blender loader);
else instant-ngp's ``aabb_scale``: 1 says the scene lies in instant-ngp's unit cube, i.e.
within ~1.5 of the origin of the file's coordinates (instant-ngp scales them by 0.33), so it
is bounded and scaled by 2/3 as NeRF-synthetic; any other value, or none (nerfstudio's real
captures), is unbounded, recentred and scaled as LLFF / COLMAP
(:func:`clrender.data.llff.normalise`).

Only undistorted pinhole images are read: ``camera_model`` ``OPENCV`` or ``PINHOLE`` with
every distortion coefficient zero; any other model (fisheye, equirectangular) or a non-zero
``k1 k2 k3 k4 p1 p2`` is refused, naming the frame and the values.

``downscale`` N reads nerfstudio's ``images_N/`` (same names as ``images/``) where every
frame is there and ``w``, ``h`` are given; else it shrinks the images it finds.

References: nerfstudio data conventions (docs.nerf.studio); instant-ngp ``transforms.json``
(nerf_loader.cu: ``aabb_scale``, ``scale`` 0.33).
"""
from __future__ import annotations

from pathlib import Path

from .blender import (NERF_SYNTHETIC_SCALE, frame_poses, frame_views, image_path, read_json,
                      scene_info)
from .dataset import check_downscale
from .llff import normalise, split_indices
from .views import SplitViews, check_split

FILE = "transforms.json"
PINHOLE_MODELS = ("OPENCV", "PINHOLE")
DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
SPLIT_LISTS = {"train": ("train_filenames",), "test": ("test_filenames", "val_filenames"),
               "val": ("val_filenames", "test_filenames")}


def scan_transforms(path, split: str = "train", downscale: int = 1) -> SplitViews:
    """The files and cameras of one split of ``path/transforms.json`` (image headers only)."""
    root, factor = Path(path), check_downscale(downscale)
    file = root / FILE
    meta = read_json(file)
    frames = meta.get("frames")
    poses = frame_poses(frames, file)
    for i, frame in enumerate(frames):
        check_pinhole({**meta, **frame}, f"{file}: frame {i} ({frame['file_path']})")
    kind = scene_kind(meta, file)
    if kind == "bounded":
        poses[:, :3, 3] *= scene_info(meta, file)[1] if "clrender" in meta \
            else NERF_SYNTHETIC_SCALE
    else:
        poses = normalise(poses)
    indices = split_frames(meta, frames, split, file)
    locate, resize = image_locator(root, meta, [frames[i] for i in indices], factor)
    files, cameras = frame_views(meta, frames, poses, file, indices, locate,
                                 prescaled=factor // resize)
    return check_split(SplitViews("transforms", root, split, kind, files, cameras, resize, file))


def scene_kind(meta: dict, file: Path) -> str:
    """"bounded" or "unbounded" (module doc): the clrender key, else ``aabb_scale``."""
    if "clrender" in meta:
        return scene_info(meta, file)[0]
    return "bounded" if meta.get("aabb_scale") == 1 else "unbounded"


def check_pinhole(meta: dict, where: str) -> None:
    """ValueError unless ``meta`` (a frame's keys over the file's) is an undistorted pinhole."""
    model = meta.get("camera_model", "OPENCV")
    if model not in PINHOLE_MODELS:
        raise ValueError(f"{where}: camera_model {model!r} is not supported; clrender reads "
                         f"pinhole images ({' or '.join(PINHOLE_MODELS)} with zero distortion)"
                         " - undistort them first")
    coeffs = {k: meta[k] for k in DISTORTION if k in meta}
    if any(not isinstance(v, (int, float)) or v != 0 for v in coeffs.values()):
        raise ValueError(f"{where}: distortion {coeffs} is not zero; clrender reads undistorted"
                         " pinhole images only - undistort them first (e.g. nerfstudio's "
                         "ns-process-data or COLMAP's image_undistorter)")


def split_frames(meta: dict, frames: list, split: str, file: Path) -> list[int]:
    """Indices of ``split``'s frames: nerfstudio's split lists, else every 8th is held out."""
    lists = [k for k in ("train_filenames", "val_filenames", "test_filenames") if k in meta]
    if not lists:
        return split_indices(len(frames), split)
    if split not in SPLIT_LISTS:
        raise ValueError(f"split must be 'train', 'val' or 'test', got {split!r}")
    key = next((k for k in SPLIT_LISTS[split] if k in meta), None)
    if key is None:
        raise ValueError(f"{file}: has {', '.join(lists)} but no list for split {split!r}")
    names = meta[key]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise ValueError(f"{file}: {key} must be a list of file paths")
    index = {Path(f["file_path"]).as_posix().removeprefix("./"): i for i, f in enumerate(frames)}
    unknown = [n for n in names if Path(n).as_posix().removeprefix("./") not in index]
    if unknown:
        raise ValueError(f"{file}: {key} names {len(unknown)} file(s) no frame has, e.g. "
                         f"{unknown[0]!r} ({len(names)} listed, {len(frames)} frames)")
    if not names:
        raise ValueError(f"{file}: {key} is empty, split {split!r} has no images")
    return [index[Path(n).as_posix().removeprefix("./")] for n in names]


def image_locator(root: Path, meta: dict, frames: list, factor: int):
    """(``file_path -> Path``, factor still to shrink by): ``images_N/`` for ``images/``
    where every frame of the split is there and ``w``, ``h`` are known."""
    plain = (lambda file_path: image_path(root, file_path)), factor
    if factor == 1:
        return plain

    def small(file_path: str) -> Path:
        rel = Path(file_path.removeprefix("./")).relative_to("images")
        return image_path(root / f"images_{factor}", str(rel))

    for frame in frames:
        rel = Path(frame["file_path"].removeprefix("./"))
        m = {**meta, **frame}
        if rel.parts[:1] != ("images",) or "w" not in m or "h" not in m \
                or not small(frame["file_path"]).is_file():
            return plain
    return small, 1
