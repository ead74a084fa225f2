"""``clrender data check``: what the loader sees of a dataset folder, from image headers.

Examples:
    >>> summary = check_dataset("data/fern", downscale=8)
    >>> summary["splits"]["train"]["views"], summary["scene"]
    (17, 'unbounded')
    >>> print(format_summary(summary))
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .load import detect_format, scan_dataset

SPLITS = ("train", "val", "test")


def check_dataset(path, downscale: int = 1) -> dict:
    """Scan every split of ``path`` (:func:`scan_dataset`: no pixels decoded).

    Returns:
        ``{"format", "path", "scene", "splits": {split: {"views", "width", "height",
        "source", "resize", "fx", "fy", "cx", "cy", "intrinsics_vary"} or None where a
        Blender folder has no such split}, "camera_distance":
        {"min", "max"}}``; distances are from the scene centre (the origin of normalised
        space) to the camera centres of every split, in normalised units (bounded scenes
        fill [-1, 1]^3; unbounded ones have their cameras within 1).
    """
    fmt = detect_format(path)
    splits, origins, scene = {}, [], None
    for split in SPLITS:
        if fmt == "blender" and split != "train" \
                and not (Path(path) / f"transforms_{split}.json").is_file():
            splits[split] = None  # a Blender folder may lack val (or test) views
            continue
        views = scan_dataset(path, split, downscale)
        cams = views.final_cameras()
        k = np.array([[c.fx, c.fy, c.cx, c.cy] for c in cams])
        splits[split] = {"views": len(cams), "width": cams[0].width, "height": cams[0].height,
                         "source": str(views.source), "resize": views.resize,
                         **dict(zip(("fx", "fy", "cx", "cy"), map(float, k[0]))),
                         "intrinsics_vary": bool(np.ptp(k, axis=0).max() > 1e-6)}
        origins += [c.origin for c in cams]
        scene = views.scene
    dist = np.linalg.norm(np.stack(origins), axis=1)
    return {"format": fmt, "path": str(path), "scene": scene, "splits": splits,
            "camera_distance": {"min": float(dist.min()), "max": float(dist.max())}}


def format_summary(summary: dict) -> str:
    """The human-readable lines ``clrender data check`` prints."""
    lines = [f"{summary['path']}: {summary['format']}, {summary['scene']}"]
    for split, s in summary["splits"].items():
        if s is None:
            lines.append(f"  {split:5s} none")
            continue
        shrink = f", shrunk {s['resize']}x" if s["resize"] > 1 else ""
        vary = " (first view; they vary)" if s["intrinsics_vary"] else ""
        lines.append(f"  {split:5s} {s['views']:4d} views  {s['width']}x{s['height']}  "
                     f"fx {s['fx']:.2f} fy {s['fy']:.2f} cx {s['cx']:.2f} cy {s['cy']:.2f}"
                     f"{vary}  from {s['source']}{shrink}")
    d = summary["camera_distance"]
    lines.append(f"  cameras {d['min']:.3f} to {d['max']:.3f} from the scene centre "
                 f"(normalised units)")
    return "\n".join(lines)
