"""A capture's poses against published ones, and the same dataset on the published poses.

``python -m clrender.capture.accuracy DATA REFERENCE --truth TRUE_DATA`` compares the
registered images of capture ``DATA`` with the images of the same names (by stem) in
``REFERENCE`` (any dataset clrender loads: Blender, LLFF, ...): rotation and position
errors after a similarity alignment of the camera centres (:func:`.align.pose_errors`).
With ``--truth`` it also writes ``TRUE_DATA``, a COLMAP dataset of the same frames the
capture saw (``DATA.work/frames``) on the reference's poses and pinhole intrinsics,
carried into the capture's world frame so that ``clrender.json`` (an object capture's box)
and the loader's normalisation treat both alike: train both, compare their test views.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from ..atomic import atomic_folder
from ..data.colmap import MARKER, OPENCV_TO_NERF, read_model
from ..data.load import scan_dataset
from ..data.views import image_size
from .align import pose_errors
from .output import write_downscaled
from .sfm import pycolmap

SPLITS = ("train", "val", "test")
# A camera turned further than this from the truth is not inaccurate but misregistered (a
# mirror or flip on a symmetric object): listed, and the others realigned without it.
MISREGISTERED_DEG = 10.0


def reference_cameras(reference: Path) -> dict:
    """{image stem: Camera} over every split of a dataset (its normalised space)."""
    cameras = {}
    for split in SPLITS:
        try:
            views = scan_dataset(reference, split)
        except FileNotFoundError:
            continue
        cameras.update({f.stem: c for f, c in zip(views.files, views.cameras)})
    return cameras


def recovered(data: Path) -> np.ndarray:
    """(N, 4, 4) NeRF c2w of ``data/sparse/0``'s images by name, as written."""
    _, images = read_model(data / "sparse" / "0")
    return np.stack([np.linalg.inv(w2c) @ OPENCV_TO_NERF for _, _, w2c in images])


def error_summary(errors: dict) -> dict:
    """Mean and max rotation (degrees) and position (fraction of the extent) errors."""
    rot, pos = errors["rotation_deg"], errors["position"] / errors["extent"]
    return {"rotation_deg_mean": float(rot.mean()), "rotation_deg_max": float(rot.max()),
            "position_of_extent_mean": float(pos.mean()),
            "position_of_extent_max": float(pos.max())}


def compare(data: Path, reference: Path) -> tuple[list[str], dict, list]:
    """(registered names, :func:`pose_errors` of them, their reference cameras)."""
    _, images = read_model(data / "sparse" / "0")
    truth = reference_cameras(reference)
    missing = [n for n, _, _ in images if Path(n).stem not in truth]
    if missing:
        raise ValueError(f"{reference}: no image named like {missing[0]} of {data}")
    names = [n for n, _, _ in images]
    cams = [truth[Path(n).stem] for n in names]
    return names, pose_errors(recovered(data), np.stack([c.c2w for c in cams])), cams


def write_truth(data: Path, out: Path, names: list[str], cams: list, sim3) -> None:
    """``out``: COLMAP dataset of ``data``'s input frames ``names`` on the reference
    cameras ``cams``, moved into the capture's frame by the inverse of ``sim3``."""
    s, R, t = sim3
    report = json.loads((data / "capture.json").read_text())
    frames = data.with_name(data.name + ".work") / "frames"

    def write(tmp: Path) -> None:
        rec = pycolmap.Reconstruction()
        for i, (name, cam) in enumerate(zip(names, cams), start=1):
            cam = cam.scaled_to(*image_size(frames / name))   # the frames the capture saw
            rec.add_camera_with_trivial_rig(pycolmap.Camera(
                model="PINHOLE", width=cam.width, height=cam.height, camera_id=i,
                params=[cam.fx, cam.fy, cam.cx, cam.cy]))
            c2w = cam.c2w.copy()
            c2w[:3, :3] = R.T @ c2w[:3, :3]
            c2w[:3, 3] = R.T @ (c2w[:3, 3] - t) / s
            w2c = np.linalg.inv(c2w @ OPENCV_TO_NERF)
            rec.add_image_with_trivial_frame(
                pycolmap.Image(name=name, camera_id=i, image_id=i),
                pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3]))
        (tmp / "sparse" / "0").mkdir(parents=True)
        rec.write_binary(str(tmp / "sparse" / "0"))
        (tmp / "images").mkdir()
        for name in names:
            shutil.copyfile(frames / name, tmp / "images" / name)
        if report["downscale"]:
            write_downscaled(tmp / "images", tmp / f"images_{report['downscale']}",
                             report["downscale"])
        if (data / MARKER).is_file():
            shutil.copyfile(data / MARKER, tmp / MARKER)

    atomic_folder(out, write)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m clrender.capture.accuracy",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("data", type=Path, help="a `clrender capture` output folder")
    p.add_argument("reference", type=Path, help="the same images with published poses")
    p.add_argument("--truth", type=Path, default=None,
                   help="write the capture's frames on the reference poses here")
    args = p.parse_args(argv)
    names, errors, cams = compare(args.data, args.reference)
    summary = {"registered": len(names),
               "reference_images": len(reference_cameras(args.reference)),
               "all": error_summary(errors)}
    wrong = errors["rotation_deg"] > MISREGISTERED_DEG
    if wrong.any():             # the others' alignment, not pulled by the wrong ones
        summary["misregistered"] = [n for n, w in zip(names, wrong) if w]
        errors = pose_errors(recovered(args.data)[~wrong],
                             np.stack([c.c2w for c, w in zip(cams, wrong) if not w]))
        summary["others"] = error_summary(errors)
    print(json.dumps(summary, indent=2))
    if args.truth:
        write_truth(args.data, args.truth, names, cams, errors["sim3"])
        print(f"wrote {args.truth}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
