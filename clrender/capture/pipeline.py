"""``clrender capture``: photos or a video in, a COLMAP dataset folder out.

Stages, each recorded in a work folder ``<out>.work/`` by a ``<stage>.json`` written last
(its outputs are renamed into place first), so an interrupted capture resumes at the first
stage without one; ``force`` starts over:

    frames        photos checked / video frames picked       -> frames/, masks/
    features      SIFT, one shared camera                    -> features.db
    matching      exhaustive (photos) or sequential (video)  -> matches.db
    mapping       incremental or global mapping (auto: incremental
                  for an object with silhouettes, else global),
                  largest model kept                         -> sparse/<k>/
                  object photos: cameras checked against the    (mapping.db: pairs
                  silhouettes, mapped again without the pairs    removed)
                  that placed a refuted one (:mod:`.silhouette`)
    undistortion  PINHOLE images of the registered frames    -> undistorted/
    output        <out>/: images/, images_N/, sparse/0/, capture.json, clrender.json

``<out>`` appears whole or not at all (built in a temporary folder, then renamed).
"""
from __future__ import annotations

import json
import os
import shutil
import sqlite3
import sys
import time
from contextlib import closing
from pathlib import Path

from ..atomic import atomic_folder, write_atomic
from . import sfm, silhouette
from .frames import MIN_FRAMES, copy_photos
from .output import write_output
from .video import VIDEO_SUFFIXES, extract_frames

STAGES = ("frames", "features", "matching", "mapping", "undistortion", "output")
EXHAUSTIVE_MAX = 300     # photos beyond this are matched sequentially (pairs grow as N^2)
REPORT = "capture.json"
MAX_REMAPS = 2           # mappings after the first, each without the pairs of refuted cameras
MAPPERS = ("auto", "incremental", "global")


def capture(src, out, max_frames: int = 200, matcher: str = "auto", bounded=None,
            downscale: int | None = None, force: bool = False, threads: int | None = None,
            seed: int = 0, mapper: str = "auto", focal: float | None = None) -> dict:
    """Run structure from motion on ``src`` and write a COLMAP dataset to ``out``.

    Args:
        src: a folder of photos (``.png``, ``.jpg``) or a video file.
        out: the dataset folder to write: a new or empty one, a finished capture (asked
            again with other options, redone from the first stage they change: a new
            ``downscale`` or ``bounded`` only the output, a new ``mapper`` or ``focal``
            from the mapping; with the same options kept, the report's ``reused`` True),
            or any folder with ``force``.
        max_frames: a video's frame budget (the sharpest of each window).
        matcher: "auto" (sequential for video or over EXHAUSTIVE_MAX photos), "exhaustive"
            or "sequential".
        bounded: True: an object capture scaled into [-1, 1]^3 (``clrender.json``); False:
            unbounded; None: bounded when every photo has transparent pixels.
        downscale: also write ``images_{downscale}/``.
        threads: CPU threads for every stage (default: all of the machine's).
        mapper: "incremental", "global" (:func:`.sfm.reconstruct`) or "auto"
            (:func:`choose_mapper`); a work folder mapped otherwise (another mapper or
            ``focal``) redoes mapping and the stages after it.
        focal: the frames' focal length in pixels, if known: the mapping's prior instead
            of the guess from the image size (:func:`.sfm.set_focal_prior`).
    Returns:
        the report written to ``out/capture.json``.
    """
    src, out = Path(src), Path(out)
    work = out.with_name(out.name + ".work")
    if mapper not in MAPPERS:
        raise ValueError(f"mapper {mapper!r}: expected one of {', '.join(MAPPERS)}")
    if focal is not None and not focal > 0:
        raise ValueError(f"focal length {focal!r}: expected a number of pixels > 0")
    if not src.exists():
        raise FileNotFoundError(f"{src}: no such folder or video")
    finished = not force and (out / REPORT).is_file()
    if force:
        shutil.rmtree(work, ignore_errors=True)
    elif out.exists() and any(out.iterdir()) and not finished:
        raise ValueError(f"{out}: exists and is not a finished capture (use --force to "
                         "replace it)")
    is_video = src.is_file()
    if is_video and src.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"{src}: not a folder of images nor a video "
                         f"({', '.join(VIDEO_SUFFIXES)})")
    settings = {"src": str(src.resolve()), "max_frames": max_frames if is_video else None,
                "matcher": matcher, "seed": seed}
    work.mkdir(parents=True, exist_ok=True)
    check_settings(work, settings)
    threads = threads or os.cpu_count() or 1
    run = _Run(work, threads)
    info = run.stage("frames", lambda: _frames(src, work, is_video, max_frames))
    sequential = matcher == "sequential" or (matcher == "auto" and (
        is_video or info["given"] > EXHAUSTIVE_MAX))
    run.stage("features", lambda: _database(work / "features.db", None,
                                            lambda db: sfm.extract(db, work / "frames",
                                                                   threads)))
    run.stage("matching", lambda: _database(
        work / "matches.db", work / "features.db",
        lambda db: {"pairs": sfm.match(db, sequential, threads),
                    "matcher": "sequential" if sequential else "exhaustive"}))
    masks = work / "masks" if info.get("transparent") else None
    mapper = choose_mapper(mapper, masks is not None)
    mapped_as = run.info("mapping") if (work / "mapping.json").is_file() else None
    if mapped_as is not None and (mapped_as.get("mapper", "incremental"),
                                  mapped_as.get("focal")) != (mapper, focal):
        for stage in ("mapping", "undistortion"):
            (work / f"{stage}.json").unlink(missing_ok=True)
        shutil.rmtree(work / "undistorted", ignore_errors=True)
    mapped = run.stage("mapping", lambda: _mapping(work, threads, seed, info["given"], masks,
                                                   mapper, focal))
    run.stage("undistortion", lambda: _undistortion(work, mapped["chosen"], threads))
    is_bounded = info["transparent"] if bounded is None else bool(bounded)
    report = {"given": info["given"], "source": info["source"], "threads": threads,
              **{k: mapped[k] for k in ("registered", "reprojection_error_px", "points3D",
                                        "models", "left_out")},
              "refuted": mapped.get("refuted"), "mapper": mapped.get("mapper", "incremental"),
              "focal_prior": mapped.get("focal"),
              "camera": mapped.get("camera"),
              "scene": "bounded" if is_bounded else "unbounded",
              "matcher": run.info("matching")["matcher"], "downscale": downscale}
    if finished:
        old = json.loads((out / REPORT).read_text())
        if _same_result(old, report):
            return {**old, "reused": True}
    run.stage("output", lambda: write_output(work, out, report, run.times, force or finished))
    return json.loads((out / REPORT).read_text())


def _same_result(old: dict, new: dict) -> bool:
    """Whether a finished capture's report ``old`` holds what ``new`` (a report before its
    output stage) asks for: the same fields but the stages' times and the threads."""
    ignored = {"stages", "total_seconds", "threads"}
    return ({k: v for k, v in old.items() if k not in ignored}
            == json.loads(json.dumps({k: v for k, v in new.items() if k not in ignored})))


def choose_mapper(mapper: str, silhouettes: bool) -> str:
    """The mapper to run: ``mapper``, or for "auto" incremental when the capture has
    silhouettes (an object on a transparent background), global otherwise.

    Measured (docs/results-capture.md): incremental mapping drifts round an orbit (bonsai, 100
    photos: rotations 1.6 degrees off at the median, out of the 1-degree bound) where
    global mapping does not (0.40 at the median, 0.63 at most); on an object with
    repeated structure both turn a few cameras (lego: 6 incremental, 10 global), which
    only the silhouette check finds, and after it only the incremental mapping ended
    within the bounds (all 100 cameras; global left one turned by 12 degrees). Without
    silhouettes nothing catches a turned camera, so the mapper without drift is the
    better bet."""
    if mapper != "auto":
        return mapper
    return "incremental" if silhouettes else "global"


class _Run:
    """The stages of one capture: skip those done, time the others."""

    def __init__(self, work: Path, threads: int):
        self.work, self.threads = work, threads
        self.times = {}

    def info(self, name: str) -> dict:
        return json.loads((self.work / f"{name}.json").read_text())

    def stage(self, name: str, fn) -> dict:
        """``fn()``'s info dict, or the stored one of a stage done before."""
        if (self.work / f"{name}.json").is_file():
            info = self.info(name)
            self.times[name] = {"seconds": info.get("_seconds"), "skipped": True}
            return info
        start = time.perf_counter()
        info = fn() or {}
        info["_seconds"] = round(time.perf_counter() - start, 2)
        self.times[name] = {"seconds": info["_seconds"], "skipped": False}
        if name != "output":
            write_atomic(self.work / f"{name}.json", json.dumps(info, indent=2))
        return info


def check_settings(work: Path, settings: dict) -> None:
    """Record ``settings`` in a new work folder; one made with others is refused."""
    file = work / "settings.json"
    if file.is_file():
        old = json.loads(file.read_text())
        if old != settings:
            changed = ", ".join(f"{k} {old.get(k)!r} -> {v!r}" for k, v in settings.items()
                                if old.get(k) != v)
            raise ValueError(f"{work}: a capture with other settings was made here "
                             f"({changed}); use --force to start over")
    else:
        write_atomic(file, json.dumps(settings, indent=2))


def _frames(src: Path, work: Path, is_video: bool, max_frames: int) -> dict:
    """``frames/``; for photos also ``masks/``, the alpha of those with transparent pixels
    (the silhouettes :mod:`.silhouette` checks an object capture's cameras against)."""
    result = {}
    for folder in ("frames", "masks"):          # left by an interrupted stage
        shutil.rmtree(work / folder, ignore_errors=True)

    def write(tmp: Path) -> None:
        if is_video:
            result.update(extract_frames(src, tmp, max_frames))
        else:
            atomic_folder(work / "masks",
                          lambda masks: result.update(copy_photos(src, tmp, masks)))

    atomic_folder(work / "frames", write)
    return result


def _database(db: Path, start: Path | None, fill) -> dict:
    """``fill(tmp)`` on a copy of ``start`` (or a new database), then renamed to ``db``."""
    tmp = db.with_name(f".{db.name}.tmp")
    leftovers = [tmp.with_name(tmp.name + s) for s in ("", "-wal", "-shm")]  # SQLite's
    for f in leftovers:
        f.unlink(missing_ok=True)
    if start is not None:
        shutil.copyfile(start, tmp)
    try:
        info = fill(tmp)
        with closing(sqlite3.connect(tmp)) as con:     # the WAL into the file, then move it
            con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        os.replace(tmp, db)
    finally:
        for f in leftovers:
            f.unlink(missing_ok=True)
    return info or {}


def _mapping(work: Path, threads: int, seed: int, given: int, masks: Path | None,
             mapper: str, focal: float | None = None) -> dict:
    """Map ``mapping.db`` (``matches.db`` with the shared camera's focal length taken for
    a prior: :func:`.sfm.set_focal_prior`) into ``sparse/``; the largest model is chosen.
    With ``masks`` (an object capture), its cameras are checked against the silhouettes:
    while some are refuted, the pairs that placed them are removed from ``mapping.db`` and
    mapping starts over, at most MAX_REMAPS times; cameras still refuted then are
    deregistered (left out rather than wrong)."""
    db, rounds, dropped = work / "mapping.db", [], []
    _database(db, work / "matches.db", lambda tmp: sfm.set_focal_prior(tmp, focal))
    while True:
        found, chosen = _map(work, db, threads, seed, given, mapper)
        bad = silhouette.refuted(found[chosen], masks) if masks else {}
        if not bad:
            break
        removed = (silhouette.prune_pairs(db, found[chosen], bad)
                   if len(rounds) < MAX_REMAPS else [])
        rounds.append({"cameras": {n: round(v, 3) for n, v in sorted(bad.items())},
                       "pairs_removed": len(removed)})
        if not removed:
            dropped = sorted(bad)
            _deregister(found[chosen], bad, work / "sparse" / str(chosen))
            break
    models = {k: sfm.model_summary(r) for k, r in found.items()     # COLMAP discards
              if r.num_reg_images() >= sfm.MIN_MODEL_SIZE}           # smaller ones
    left_out = given - models[chosen]["registered"]
    if len(models) > 1:
        print(f"clrender capture: warning: {len(models)} disconnected models; kept the "
              f"largest ({models[chosen]['registered']} of {given} images), {left_out} images "
              "left out", file=sys.stderr)
    if dropped:
        print(f"clrender capture: warning: {len(dropped)} cameras see the object's points "
              f"outside its silhouettes after {len(rounds) - 1} new mappings, left out: "
              f"{', '.join(dropped)}", file=sys.stderr)
    return {**models[chosen], "chosen": str(chosen), "models": len(models),
            "left_out": left_out, "refuted": {"rounds": rounds, "left_out": dropped},
            "mapper": mapper, "focal": focal}


def _map(work: Path, db: Path, threads: int, seed: int, given: int,
         mapper: str) -> tuple[dict, int]:
    """({k: Reconstruction} mapped from ``db`` into ``sparse/<k>/``, the largest's k)."""
    found = {}

    def write(tmp: Path) -> None:
        found.update(sfm.reconstruct(db, work / "frames", tmp, threads, seed, mapper))

    if (work / "sparse").exists():
        shutil.rmtree(work / "sparse")
    atomic_folder(work / "sparse", write)
    best = max((r.num_reg_images() for r in found.values()), default=0)
    if best < MIN_FRAMES:
        shutil.rmtree(work / "sparse")
        raise ValueError(f"{work / 'frames'}: structure from motion registered "
                         f"{'none' if best == 0 else f'only {best}'} of the {given} images "
                         f"(at least {MIN_FRAMES} needed; too few matching features: little "
                         "texture, little overlap between views, or unrelated photos)")
    return found, max(found, key=lambda k: found[k].num_reg_images())


def _deregister(rec, names, folder: Path) -> None:
    """Deregister the images ``names`` of ``rec`` and write it over ``folder``."""
    for image in list(rec.images.values()):
        if image.name in names:
            rec.deregister_frame(image.frame_id)
    rec.write(str(folder))


def _undistortion(work: Path, chosen: str, threads: int) -> dict:
    def write(tmp: Path) -> None:
        sfm.undistort(work / "sparse" / chosen, work / "frames", tmp, threads)
        model = tmp / "sparse" / "0"
        model.mkdir()
        for f in (tmp / "sparse").iterdir():
            if f.is_file():
                f.rename(model / f.name)

    atomic_folder(work / "undistorted", write)
    return {}
