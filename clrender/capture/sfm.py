"""Structure from motion with pycolmap (COLMAP's pipeline, on the CPU): SIFT features,
matching, incremental mapping with one shared camera, undistortion to PINHOLE.

Each stage is one function over COLMAP files (a database, a model folder); the pipeline
(:mod:`.pipeline`) decides which stages run and where their outputs go.

References: Schönberger & Frahm 2016, "Structure-from-Motion Revisited" (COLMAP).
"""
from __future__ import annotations

import itertools
import zlib  # noqa: F401  loaded before pycolmap: its own zlib symbols break PNG writing
from pathlib import Path

import numpy as np
import pycolmap
from tqdm import tqdm

CAMERA_MODEL = "SIMPLE_RADIAL"   # one focal length + one radial term, refined by mapping
EXTRACT_CHUNK = 8                # images per extraction call (the progress bar's step)
MATCH_BLOCK = 500                # image pairs per matching call (the progress bar's step)
LOG_LEVEL = 1                    # COLMAP's warnings and errors; the stages report progress
MIN_MODEL_SIZE = 3               # COLMAP drops smaller models; its 10 drops small captures
KEEP_GRID_PX = 1.0               # undistortion that moves the border less keeps the photo's grid

pycolmap.logging.minloglevel = max(pycolmap.logging.minloglevel, LOG_LEVEL)


def extract(db: Path, images: Path, threads: int) -> None:
    """SIFT features of every image of ``images`` into database ``db``, one shared camera
    (the first chunk creates it, the others reuse it: each call would make its own)."""
    names = sorted(p.name for p in images.iterdir())
    options = pycolmap.FeatureExtractionOptions(num_threads=threads)
    camera_id = -1
    with tqdm(total=len(names), desc="features", unit="image", disable=None) as bar:
        for i in range(0, len(names), EXTRACT_CHUNK):
            chunk = names[i:i + EXTRACT_CHUNK]
            reader = pycolmap.ImageReaderOptions(camera_model=CAMERA_MODEL,
                                                 existing_camera_id=camera_id)
            pycolmap.extract_features(db, images, image_names=chunk,
                                      camera_mode=pycolmap.CameraMode.SINGLE,
                                      reader_options=reader, extraction_options=options,
                                      device=pycolmap.Device.cpu)
            camera_id = _images(db)[0].camera_id
            bar.update(len(chunk))


def match(db: Path, sequential: bool, threads: int, overlap: int = 10) -> int:
    """Match and geometrically verify image pairs of ``db``: every pair (exhaustive), or
    each image with those :func:`sequential_steps` after it by name (sequential, video).
    Returns the number of pairs matched."""
    options = pycolmap.FeatureMatchingOptions(num_threads=threads)
    names = sorted(im.name for im in _images(db))
    if sequential:
        pairs = [(names[i], names[i + d]) for i in range(len(names))
                 for d in sequential_steps(overlap) if i + d < len(names)]
    else:
        pairs = list(itertools.combinations(names, 2))
    pairs_file = db.with_suffix(".pairs.txt")
    try:
        with tqdm(total=len(pairs), desc="matching", unit="pair", disable=None) as bar:
            for i in range(0, len(pairs), MATCH_BLOCK):
                block = pairs[i:i + MATCH_BLOCK]
                pairs_file.write_text("".join(f"{a} {b}\n" for a, b in block))
                pycolmap.match_image_pairs(
                    db, matching_options=options, device=pycolmap.Device.cpu,
                    pairing_options=pycolmap.ImportedPairingOptions(
                        match_list_path=pairs_file))
                bar.update(len(block))
    finally:
        pairs_file.unlink(missing_ok=True)
    return len(pairs)


def sequential_steps(overlap: int) -> list[int]:
    """Frame steps matched in sequential mode: 1..overlap, then 2^k beyond it up to
    2^overlap (COLMAP's quadratic overlap: far pairs tie the sequence against drift)."""
    return sorted(set(range(1, overlap + 1)) | {2 ** k for k in range(overlap + 1)})


def _images(db: Path):
    database = pycolmap.Database.open(db)
    try:
        return database.read_all_images()
    finally:
        database.close()


def set_focal_prior(db: Path, focal: float | None = None) -> None:
    """Mark the focal length of every camera of ``db`` as a prior: ``focal`` (pixels of
    the frames), else the one extraction set (COLMAP's guess from the image size, 1.2 times
    its larger side, when the photos carry no EXIF focal length).

    Without a prior, the mapper estimates the focal length anew with each image it
    registers (P4Pf, from that image's matches alone) and a weak registration can drag the
    shared camera to a wrong model; with one, registration is calibrated (P3P) and the
    focal length is refined by bundle adjustment over all images only."""
    database = pycolmap.Database.open(db)
    try:
        for camera in database.read_all_cameras():
            if focal is not None:
                camera.focal_length = float(focal)
            camera.has_prior_focal_length = True
            database.update_camera(camera)
    finally:
        database.close()


def reconstruct(db: Path, images: Path, out: Path, threads: int, seed: int = 0,
                mapper: str = "incremental") -> dict:
    """Mapping of ``db`` into ``out/<k>/`` (one folder per model found), incremental
    (COLMAP's: one image registered at a time) or global (GLOMAP's: rotation averaging,
    then global positioning, then bundle adjustment). Returns {k: Reconstruction}."""
    pycolmap.set_random_seed(seed)
    if mapper == "global":
        options = pycolmap.GlobalPipelineOptions(num_threads=threads, random_seed=seed,
                                                 min_model_size=MIN_MODEL_SIZE)
        options.mapper.global_positioning.use_gpu = False      # the CPU wheel: no CUDA
        options.mapper.bundle_adjustment.ceres.use_gpu = False
        with tqdm(total=1, desc="mapping (global)", unit="model", disable=None) as bar:
            found = pycolmap.global_mapping(db, images, out, options)
            bar.update()
        return found
    if mapper != "incremental":
        raise ValueError(f"mapper {mapper!r}: expected 'incremental' or 'global'")
    options = pycolmap.IncrementalPipelineOptions(num_threads=threads, random_seed=seed,
                                                  min_model_size=MIN_MODEL_SIZE)
    n = len(_images(db))
    with tqdm(total=n, desc="mapping", unit="image", disable=None) as bar:
        return pycolmap.incremental_mapping(db, images, out, options,
                                            next_image_callback=lambda: bar.update())


def model_summary(rec) -> dict:
    """{"registered", "points3D", "reprojection_error_px", "camera": {"model", "params"}}
    of a Reconstruction (its first camera: the shared one)."""
    camera = next(iter(rec.cameras.values()), None)
    return {"registered": rec.num_reg_images(), "points3D": rec.num_points3D(),
            "reprojection_error_px": float(rec.compute_mean_reprojection_error()),
            "camera": None if camera is None else {
                "model": camera.model.name, "width": camera.width, "height": camera.height,
                "params": [float(p) for p in camera.params]}}


def undistort(model: Path, images: Path, out: Path, threads: int) -> None:
    """Undistort the registered images of ``model`` to PINHOLE into ``out``:
    ``out/images/`` and the model in ``out/sparse/``.

    COLMAP's undistorter crops the image to its valid region and puts the principal point
    at the new centre, which for a lens with little distortion leaves the image a pixel
    smaller, its grid shifted by half a pixel from the photo's: every pixel becomes the
    mean of four (bilinear interpolation), a blur that costs a model trained on them its
    detail. A camera whose distortion moves no pixel of the image's border by more than
    KEEP_GRID_PX keeps the photo's size and principal point (scale 1: near the identity;
    barrel distortion, the usual one, samples nothing outside the photo then, pincushion
    at most a sliver that thin at the corners)."""
    options = pycolmap.UndistortCameraOptions()
    cameras = read_model(model).cameras.values()
    if max(border_displacement(c) for c in cameras) <= KEEP_GRID_PX:
        options.min_scale = options.max_scale = 1.0
    with tqdm(total=1, desc="undistortion", unit="model", disable=None) as bar:
        pycolmap.undistort_images(out, model, images, undistort_options=options,
                                  num_threads=threads)
        bar.update()


def border_displacement(camera) -> float:
    """The largest distance in pixels between a point of the image's border (corners and
    edge midpoints) and where a pinhole camera of the same focal length and principal
    point sees it: how far undistortion moves the border."""
    w, h = camera.width, camera.height
    pixels = np.array([[u, v] for u in (0, w / 2, w) for v in (0, h / 2, h)], float)
    rays = np.asarray(camera.cam_from_img(pixels))
    fx, fy = camera.focal_length_x, camera.focal_length_y
    cx, cy = camera.principal_point_x, camera.principal_point_y
    pinhole = np.stack([fx * rays[:, 0] + cx, fy * rays[:, 1] + cy], axis=1)
    return float(np.linalg.norm(pinhole - pixels, axis=1).max())


def read_model(folder: Path):
    """The Reconstruction in ``folder``."""
    return pycolmap.Reconstruction(str(folder))
