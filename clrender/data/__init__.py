"""Datasets: Blender / NeRF-synthetic and LLFF / Mip-NeRF 360 loaders, and built-in scenes.

Examples:
    >>> from clrender.data import load_dataset, make_scene
    >>> folder = make_scene("bounded", "/tmp/scene", n_train=20, n_test=4, width=64, height=64)
    >>> ds = load_dataset(folder, split="train")   # ds.images: (20, 64, 64, 3) float32
"""
from .blender import load_blender
from .dataset import Dataset
from .load import load_dataset
from .llff import load_llff
from .scene import make_scene

__all__ = ["Dataset", "load_dataset", "load_blender", "load_llff", "make_scene"]
