"""The box an object capture is scaled into: bounded scenes live in [-1, 1]^3 (as the
Blender loader's), so the capture writes the centre and scale that map its sparse points
there, in ``clrender.json`` beside ``sparse/``; :mod:`clrender.data.colmap` applies it.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..atomic import write_atomic
from ..data.colmap import MARKER

PERCENTILE = 1.0           # per axis, the points below it and above 100 - it are outliers
MARGIN = 1.2               # the box's half side over the points' half extent


def scene_box(points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (3,), scale) of a cube holding (N, 3) ``points`` within ``1 / MARGIN``:
    ``(x - centre) * scale`` lies in [-1, 1]^3 for all but the outlying points."""
    if len(points) < 4:
        raise ValueError(f"{len(points)} sparse points: too few to find the object's box")
    lo, hi = np.percentile(points, [PERCENTILE, 100 - PERCENTILE], axis=0)
    half = float((hi - lo).max()) / 2 * MARGIN
    return (lo + hi) / 2, 1.0 / half


def write_marker(root: Path, centre: np.ndarray, scale: float) -> Path:
    """Write ``root/clrender.json``: a bounded scene, world x -> (x - centre) * scale."""
    data = {"scene": "bounded", "centre": [float(c) for c in centre], "scale": float(scale)}
    return write_atomic(root / MARKER, json.dumps(data, indent=2) + "\n")
