"""The exported folder: static page files, binary assets and their JSON manifest, written
to a temporary folder beside the target and renamed into place.

Layout of ``DIR``: ``index.html`` and the page's scripts and shaders (copied from
``clrender/export/web/``), ``model.json`` (the manifest), ``*.bin`` (little-endian arrays,
already laid out as the textures the page uploads).

Manifest (``format`` "clrender-web", ``version`` 1): ``method``, ``config`` (the baked
model's), method fields, ``assets`` {name: {"file", "dtype", "shape"}}, ``cameras`` (list
of {"name", "fx", "fy", "cx", "cy", "width", "height", "c2w" (4x4 row-major)}), ``bytes``.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from ..atomic import atomic_folder
from .limits import TEX_WIDTH, ExportError, texture_rows

FORMAT = "clrender-web"
VERSION = 1
WEB = Path(__file__).resolve().parent / "web"
STATIC = (".html", ".js", ".glsl", ".vert", ".frag", ".css")     # the page: every such file of web/
DTYPES = {np.dtype(np.float32): "float32", np.dtype(np.int32): "int32",
          np.dtype(np.uint8): "uint8", np.dtype(np.uint16): "uint16"}


def as_texture(where: str, values: np.ndarray, channels: int, what: str) -> np.ndarray:
    """``values`` (N, C) laid out as a TEX_WIDTH-wide texture of ``channels`` components:
    row-major (rows, TEX_WIDTH, channels), item i at texels [i * t, (i + 1) * t) with
    t = ceil(C / channels), zero-padded."""
    values = np.asarray(values)
    n, c = values.shape
    per = -(-c // channels)
    rows = texture_rows(where, n * per, what)
    out = np.zeros((rows, TEX_WIDTH, channels), values.dtype)
    flat = np.zeros((n, per * channels), values.dtype)
    flat[:, :c] = values
    out.reshape(-1)[:flat.size] = flat.reshape(-1)
    return out


def camera_record(cam, name: str) -> dict:
    """A :class:`clrender.camera.Camera` as the page's JSON camera."""
    return {"name": name, "fx": float(cam.fx), "fy": float(cam.fy), "cx": float(cam.cx),
            "cy": float(cam.cy), "width": int(cam.width), "height": int(cam.height),
            "c2w": np.asarray(cam.c2w, np.float64).tolist()}


def dataset_cameras(data, downscale: int, split: str = "test") -> list[dict]:
    """The ``split`` cameras of a dataset folder (headers only, no pixels), as records."""
    from ..data.load import scan_dataset

    views = scan_dataset(data, split, downscale)
    return [camera_record(c, Path(f).stem) for c, f in zip(views.final_cameras(), views.files)]


def write_export(out, manifest: dict, assets: dict[str, np.ndarray]) -> Path:
    """Write the page, ``assets`` ({name: array}) and the manifest to folder ``out``.

    ``out`` must not exist or be empty; nothing appears there unless all is written.
    Returns ``out``.
    """
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ExportError(f"{out}: exists and is not an empty folder (export writes a new one)")
    entries, total = {}, 0
    for name, a in assets.items():
        if a.dtype not in DTYPES:
            raise TypeError(f"asset {name}: dtype {a.dtype} has no page type")
        entries[name] = {"file": f"{name}.bin", "dtype": DTYPES[a.dtype], "shape": list(a.shape)}
        total += a.nbytes
    manifest = {"format": FORMAT, "version": VERSION, **manifest, "assets": entries,
                "bytes": total}

    def write(tmp: Path) -> None:
        for f in sorted(WEB.iterdir()):
            if f.suffix in STATIC:
                shutil.copyfile(f, tmp / f.name)
        for name, a in assets.items():
            np.ascontiguousarray(a).astype(a.dtype.newbyteorder("<")).tofile(tmp / f"{name}.bin")
        (tmp / "model.json").write_text(json.dumps(manifest, indent=1))

    if out.exists():
        out.rmdir()
    return atomic_folder(out, write)
