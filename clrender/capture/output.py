"""The dataset folder a capture hands to ``clrender train``: what the COLMAP loader reads
(``sparse/0/`` and ``images/`` of the registered images only, ``images_N/``), the box of
an object capture (``clrender.json``) and the report (``capture.json``)."""
from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from ..data.dataset import area_downscale, read_image
from ..data.llff import image_files
from ..video import to_uint8
from . import sfm
from .box import scene_box, write_marker

JPEG_QUALITY = 95


def write_output(work: Path, out: Path, report: dict, times: dict, force: bool) -> dict:
    """Assemble ``out`` from ``work/undistorted`` in a temporary folder, then rename it
    into place (replacing an earlier ``out`` when ``force``). Returns the report."""
    start = time.perf_counter()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        os.chmod(tmp, 0o755)
        shutil.copytree(work / "undistorted" / "sparse", tmp / "sparse")
        shutil.copytree(work / "undistorted" / "images", tmp / "images",
                        copy_function=_link_or_copy)
        if report["downscale"]:
            write_downscaled(tmp / "images", tmp / f"images_{report['downscale']}",
                             report["downscale"])
        if report["scene"] == "bounded":
            points = sfm.read_model(tmp / "sparse" / "0").points3D
            centre, scale = scene_box(np.array([p.xyz for p in points.values()]))
            write_marker(tmp, centre, scale)
        times = {**times, "output": {"seconds": round(time.perf_counter() - start, 2),
                                     "skipped": False}}
        report = {**report, "stages": times,
                  "total_seconds": round(sum(t["seconds"] or 0 for t in times.values()), 2)}
        (tmp / "capture.json").write_text(json.dumps(report, indent=2) + "\n")
        _replace(tmp, out, force)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return report


def _link_or_copy(src, dst):
    """Hard link (the work folder keeps its copy at no cost), else copy."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _replace(tmp: Path, out: Path, force: bool) -> None:
    """Rename ``tmp`` to ``out``; with ``force`` an existing ``out`` is moved aside first."""
    if out.exists() and force:
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
        os.rename(out, old / out.name)
        os.rename(tmp, out)
        shutil.rmtree(old)
    else:
        if out.exists():
            out.rmdir()                 # empty (the pipeline refuses a non-empty one)
        os.rename(tmp, out)


def write_downscaled(src: Path, dest: Path, factor: int) -> None:
    """``dest/<name>``: each image of ``src`` shrunk ``factor`` times (box averaging, as
    the loaders shrink), in its own format."""
    dest.mkdir()
    for file in image_files(src):
        small = to_uint8(area_downscale(read_image(file), factor))
        if file.suffix.lower() in (".jpg", ".jpeg"):
            iio.imwrite(dest / file.name, small[..., :3], quality=JPEG_QUALITY)
        else:
            iio.imwrite(dest / file.name, small)


def format_report(report: dict) -> str:
    """A few lines for the terminal: registered of given, error, points, time per stage."""
    lines = [f"registered {report['registered']} of {report['given']} images "
             f"({report['models']} model{'s' if report['models'] != 1 else ''}, "
             f"{report['left_out']} left out), {report['points3D']} 3D points, mean "
             f"reprojection error {report['reprojection_error_px']:.3f} px",
             f"{report['matcher']} matching, {report.get('mapper', 'incremental')} mapping, "
             f"{report['threads']} threads, scene "
             f"{report['scene']}"]
    camera = report.get("camera")
    if camera:      # a focal length far from the photos' field of view flags a bad model
        lines.append(f"camera {camera['model']} {camera['width']}x{camera['height']}, "
                     f"parameters {', '.join(f'{p:.4g}' for p in camera['params'])}"
                     + (f" (from the focal prior {report['focal_prior']:.4g} px)"
                        if report.get("focal_prior") else ""))
    refuted = report.get("refuted") or {"rounds": [], "left_out": []}
    for i, check in enumerate(refuted["rounds"]):
        lines.append(f"mapping {i + 1}: {len(check['cameras'])} cameras see the object's "
                     f"points outside its silhouettes ({', '.join(check['cameras'])}); "
                     f"{check['pairs_removed']} image pairs that placed them removed")
    if refuted["left_out"]:
        lines.append(f"left out, still refuted: {', '.join(refuted['left_out'])}")
    for name, t in report["stages"].items():
        seconds = "-" if t["seconds"] is None else f"{t['seconds']:.1f} s"
        lines.append(f"  {name:13s} {seconds}{' (done before, skipped)' if t['skipped'] else ''}")
    return "\n".join(lines)
