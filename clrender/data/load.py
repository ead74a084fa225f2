"""Load a dataset folder of any supported format (detected from its files)."""
from __future__ import annotations

from pathlib import Path

from .blender import load_blender
from .dataset import Dataset
from .llff import load_llff


def load_dataset(path, split: str = "train", downscale: int = 1,
                 background=(1.0, 1.0, 1.0)) -> Dataset:
    """Load one split of a dataset folder, detecting its format.

    Args:
        path: a folder with ``transforms_{split}.json`` (Blender / NeRF-synthetic, also
            written by :func:`clrender.data.make_scene`) or ``poses_bounds.npy`` (LLFF /
            Mip-NeRF 360).
        split: "train", "val" or "test".
        downscale: integer factor the images are shrunk by (area averaging).
        background: RGB in [0, 1] behind transparent pixels.
    """
    root = Path(path)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: dataset folder not found")
    if any(root.glob("transforms_*.json")):
        return load_blender(root, split, downscale=downscale, background=background)
    if (root / "poses_bounds.npy").is_file():
        return load_llff(root, split, downscale=downscale, background=background)
    raise ValueError(f"{root}: unknown dataset format, expected transforms_{{train,val,test}}.json "
                     "(Blender) or poses_bounds.npy (LLFF / Mip-NeRF 360)")
