"""Datasets: Blender / NeRF-synthetic, nerfstudio / instant-ngp ``transforms.json``, LLFF /
Mip-NeRF 360 and COLMAP loaders, and built-in scenes.

Examples:
    >>> from clrender.data import load_dataset, make_scene, scan_dataset
    >>> folder = make_scene("bounded", "/tmp/scene", n_train=20, n_test=4, width=64, height=64)
    >>> ds = load_dataset(folder, split="train")   # ds.images: (20, 64, 64, 3) float32
    >>> scan_dataset(folder, "test").cameras[0]    # cameras without reading pixels
"""
from .blender import load_blender
from .dataset import Dataset
from .load import detect_format, load_dataset, scan_dataset
from .llff import load_llff
from .views import SplitViews, read_views

__all__ = ["Dataset", "SplitViews", "detect_format", "load_dataset", "load_blender",
           "load_llff", "make_scene", "read_views", "scan_dataset"]


def make_scene(*args, **kwargs):
    """:func:`clrender.data.scene.make_scene` (imported when called: ray casting the
    built-in scenes needs the ``train`` extra's trimesh and embreex)."""
    from .scene import make_scene as make

    return make(*args, **kwargs)
