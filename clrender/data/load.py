"""Load a dataset folder of any supported format (detected from its files).

Formats, in the order they are detected:
    ``transforms_{train,val,test}.json``   Blender / NeRF-synthetic (:mod:`.blender`)
    ``transforms.json``                     nerfstudio / instant-ngp (:mod:`.transforms`)
    ``poses_bounds.npy``                    LLFF / Mip-NeRF 360 (:mod:`.llff`)
    ``sparse/0/`` or ``sparse/``            COLMAP (:mod:`.colmap`)
"""
from __future__ import annotations

from pathlib import Path

from .blender import scan_blender
from .colmap import find_model, scan_colmap
from .dataset import Dataset
from .llff import scan_llff
from .transforms import FILE as TRANSFORMS, scan_transforms
from .views import SplitViews, read_views

SCANNERS = {"blender": scan_blender, "transforms": scan_transforms, "llff": scan_llff,
            "colmap": scan_colmap}


def detect_format(path) -> str:
    """The format of a dataset folder: "blender", "transforms", "llff" or "colmap"."""
    root = Path(path)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: dataset folder not found")
    if any(root.glob("transforms_*.json")):
        return "blender"
    if (root / TRANSFORMS).is_file():
        return "transforms"
    if (root / "poses_bounds.npy").is_file():
        return "llff"
    if find_model(root) is not None:
        return "colmap"
    raise ValueError(f"{root}: unknown dataset format, expected transforms_{{train,val,test}}.json "
                     "(Blender), transforms.json (nerfstudio / instant-ngp), poses_bounds.npy "
                     "(LLFF / Mip-NeRF 360) or sparse/0/cameras.bin|txt (COLMAP)")


def scan_dataset(path, split: str = "train", downscale: int = 1) -> SplitViews:
    """One split's files and cameras, checked, without decoding pixels (:mod:`.views`)."""
    return SCANNERS[detect_format(path)](path, split, downscale)


def load_dataset(path, split: str = "train", downscale: int = 1,
                 background=(1.0, 1.0, 1.0)) -> Dataset:
    """Load one split of a dataset folder, detecting its format.

    Args:
        path: a dataset folder of a format above (Blender also as written by
            :func:`clrender.data.make_scene`).
        split: "train", "val" or "test".
        downscale: integer factor the images are shrunk by (area averaging), or the
            ``images_{downscale}/`` folder read where the format has one.
        background: RGB in [0, 1] behind transparent pixels.
    """
    return read_views(scan_dataset(path, split, downscale), background)
