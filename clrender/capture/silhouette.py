"""Object captures: each camera checked against the object's silhouette, and the image pairs
that placed a refuted camera removed before mapping again.

Photos of an object on a transparent background give each image its silhouette (the alpha
channel, kept by the frames stage as ``masks/<stem>.png``). A camera registered where it
stood sees the model's sparse points inside that silhouette, but for a few outliers. An
object with repeated structure (parts that look alike from opposite sides, such as a
vehicle's two tracks) can be registered turned about it: matches between views from
opposite sides, geometrically consistent, outvote the few with its true neighbours. From
there the object's points fall on the background of the camera's image, since an outline
seen from the opposite side is its mirror image.

Such a camera is refuted. The verified pairs between it and the cameras that pass whose
inliers fit the model's relative pose of the two are the matches that placed it there
(its true neighbours' matches cannot fit a turned pose); they are removed from a copy of
the database, and mapping starts over on it.

Examples:
    >>> bad = refuted(rec, work / "masks")                  # {name: share outside}
    >>> removed = prune_pairs(work / "mapping.db", rec, bad)

References: Heinly et al. 2014, "Correcting for Duplicate Scene Structure in Sparse 3D
Reconstruction" (ECCV), on the repeated-structure failure; measured on lego in
docs/guides/capture.md.
"""
from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np

from .sfm import pycolmap

OUTSIDE_MAX = 0.10   # share of the points in view a camera may see on the background
PAIR_FIT_PX = 4.0    # median epipolar error (pixels) of a pair that fits a pose: the
                     # mapper's own bound on a point's reprojection error


def outside_share(rec, masks: Path) -> dict[str, float]:
    """{image name: share of the model's points in front of the camera and within its
    image that project onto the background (alpha 0) of ``masks/<stem>.png``}."""
    xyz = np.array([p.xyz for p in rec.points3D.values()]).reshape(-1, 3)
    shares = {}
    for image_id in rec.reg_image_ids():
        image = rec.images[image_id]
        camera = rec.cameras[image.camera_id]
        mask = iio.imread(masks / f"{Path(image.name).stem}.png") > 0
        pose = image.cam_from_world().matrix()
        in_cam = xyz @ pose[:, :3].T + pose[:, 3]
        uv = np.asarray(camera.img_from_cam(in_cam[in_cam[:, 2] > 0])).reshape(-1, 2)
        seen = ((uv >= 0) & (uv < [camera.width, camera.height])).all(axis=1)
        u, v = uv[seen].astype(int).T
        shares[image.name] = float((~mask[v, u]).mean()) if seen.any() else 1.0
    return shares


def refuted(rec, masks: Path, outside_max: float = OUTSIDE_MAX) -> dict[str, float]:
    """{name: share} of the registered images that see more than ``outside_max`` of the
    points in view on the background."""
    return {n: s for n, s in outside_share(rec, masks).items() if s > outside_max}


def epipolar_error_px(camera, cam1_from_world: np.ndarray, cam2_from_world: np.ndarray,
                      xy1: np.ndarray, xy2: np.ndarray) -> np.ndarray:
    """(N,) Sampson error in pixels of the matches ``xy1`` <-> ``xy2`` ((N, 2) pixels, as
    detected) under the relative pose of two (3, 4) world-to-camera poses of ``camera``."""
    R = cam2_from_world[:, :3] @ cam1_from_world[:, :3].T
    t = cam2_from_world[:, 3] - R @ cam1_from_world[:, 3]
    t = t / np.linalg.norm(t)
    E = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ R
    x1, x2 = (np.c_[np.asarray(camera.cam_from_img(xy)).reshape(-1, 2), np.ones(len(xy))]
              for xy in (xy1, xy2))
    Ex1, Etx2 = x1 @ E.T, x2 @ E
    residual = np.sum(x2 * Ex1, axis=1)
    scale = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return np.sqrt(residual ** 2 / scale) * camera.mean_focal_length()


def prune_pairs(db: Path, rec, names, fit_px: float = PAIR_FIT_PX) -> list[list[str]]:
    """Delete from database ``db`` the verified pairs between a camera of ``names`` and a
    registered camera not in ``names`` whose inliers fit the model's relative pose
    (median :func:`epipolar_error_px` under ``fit_px``). Returns the pairs, by name."""
    ids = {im.name: i for i, im in rec.images.items()}
    bad = {ids[n] for n in names}
    registered = set(rec.reg_image_ids())
    database = pycolmap.Database.open(db)
    removed = []
    try:
        pair_ids, geometries = database.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries):
            i, j = pycolmap.pair_id_to_image_pair(pair_id)
            matches = geometry.inlier_matches
            if not ({i, j} <= registered and (i in bad) != (j in bad) and len(matches)):
                continue
            im1, im2 = rec.images[i], rec.images[j]
            error = epipolar_error_px(
                rec.cameras[im1.camera_id], im1.cam_from_world().matrix(),
                im2.cam_from_world().matrix(), database.read_keypoints(i)[matches[:, 0], :2],
                database.read_keypoints(j)[matches[:, 1], :2])
            if np.median(error) < fit_px:
                database.delete_two_view_geometry(i, j)
                removed.append(sorted((im1.name, im2.name)))
    finally:
        database.close()
    return removed
