"""Baked model files, for every method: a versioned ``.npz`` of plain arrays plus a JSON
manifest (``format``, ``version``, method fields, the array list).

Files are read with ``allow_pickle=False``; every problem raises :class:`BakedFormatError`
naming the file. A method's own module checks its config and arrays
(:func:`check_arrays` does the generic part) and decides what its format means.

Examples:
    >>> save("model.npz", {"format": "clrender-ndrf", "version": 1, "config": {...}}, arrays)
    >>> manifest, arrays = read("model.npz")
    >>> peek_format("model.npz")
    'clrender-ndrf'
"""
from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .atomic import atomic_write

F32, U8, I32 = np.dtype(np.float32), np.dtype(np.uint8), np.dtype(np.int32)
_READ_ERRORS = (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError, KeyError)


class BakedFormatError(ValueError):
    """An invalid baked file or model; the message names the file and the problem."""


def fail(where: str, problem: str):
    """Raise :class:`BakedFormatError` as ``"{where}: {problem}"``."""
    raise BakedFormatError(f"{where}: {problem}")


def check_arrays(arrays: dict, expected: dict, where: str, what: str = "") -> None:
    """Names, shapes, dtypes and finite floats of ``arrays`` against ``expected``.

    Args:
        arrays: ``{name: np.ndarray}``.
        expected: ``{name: (shape, dtype)}``; every name must be present, no other.
        what: appended to the missing/unexpected messages (e.g. the variant).
    """
    if not isinstance(arrays, dict):
        fail(where, f"arrays is a {type(arrays).__name__}, expected a dict")
    missing, extra = sorted(set(expected) - set(arrays)), sorted(set(arrays) - set(expected))
    if missing:
        fail(where, f"missing arrays {missing}{what}")
    if extra:
        fail(where, f"unexpected arrays {extra}{what}")
    for name, (shape, dtype) in expected.items():
        a = arrays[name]
        if not isinstance(a, np.ndarray):
            fail(where, f"{name} is a {type(a).__name__}, expected a numpy array")
        if a.dtype != dtype:
            fail(where, f"{name} has dtype {a.dtype}, expected {dtype}")
        if a.shape != tuple(shape):
            fail(where, f"{name} has shape {a.shape}, expected {tuple(shape)}")
        if dtype.kind == "f" and not np.all(np.isfinite(a)):
            bad = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
            fail(where, f"{name} has {bad} non-finite values (NaN or inf)")


def _savez(path: Path, payload: dict) -> None:
    with open(path, "wb") as f:     # a file object: numpy adds no ".npz" to the name
        np.savez_compressed(f, **payload)


def save(path, manifest: dict, arrays: dict) -> Path:
    """Write ``arrays`` and ``manifest`` (plus the array list) atomically to ``path``.

    The caller validates first; ``manifest`` must hold ``format`` and ``version``.
    Returns:
        the path written.
    """
    manifest = {**manifest, "arrays": {n: {"shape": list(a.shape), "dtype": str(a.dtype)}
                                       for n, a in sorted(arrays.items())}}
    payload = {n: np.ascontiguousarray(a) for n, a in arrays.items()}
    payload["manifest"] = np.array(json.dumps(manifest))
    return atomic_write(path, lambda tmp: _savez(tmp, payload))


def _open(path, where: str):
    try:
        npz = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise
    except _READ_ERRORS as e:
        raise BakedFormatError(f"{where}: not a readable .npz archive "
                               f"(truncated or corrupt?): {e}") from e
    if not isinstance(npz, np.lib.npyio.NpzFile):
        fail(where, "not an .npz archive (a single .npy array)")
    return npz


def _manifest(npz, where: str) -> dict:
    if "manifest" not in npz.files:
        fail(where, "no 'manifest' entry: not a clrender baked model")
    try:
        raw = npz["manifest"]
    except _READ_ERRORS as e:
        raise BakedFormatError(f"{where}: cannot read the manifest (truncated or corrupt?): "
                               f"{e}") from e
    if raw.dtype.kind != "U" or raw.shape != ():
        fail(where, f"manifest must be a 0-d unicode array, found {raw.dtype} {raw.shape}")
    try:
        manifest = json.loads(str(raw))
    except json.JSONDecodeError as e:
        fail(where, f"manifest is not valid JSON ({e})")
    if not isinstance(manifest, dict):
        fail(where, "manifest is not a JSON object")
    if not isinstance(manifest.get("format"), str):
        fail(where, "manifest names no format")
    return manifest


def peek_manifest(path) -> dict:
    """A baked file's manifest (reads the manifest only)."""
    where = str(path)
    with _open(path, where) as npz:
        return _manifest(npz, where)


def peek_format(path) -> str:
    """The ``format`` named by a baked file's manifest (reads the manifest only)."""
    return peek_manifest(path)["format"]


def trained_downscale(path) -> int:
    """The dataset downscale a baked file's model was trained at (``trained_on`` in its
    manifest, written by the bake of a run), 1 when it says none."""
    record = peek_manifest(path).get("trained_on")
    value = record.get("downscale", 1) if isinstance(record, dict) else 1
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        fail(str(path), f"trained_on.downscale is {value!r}, expected an integer >= 1")
    return value


def read(path, format: str, version, keys=()) -> tuple[dict, dict]:
    """Read a baked file of ``format`` / ``version``.

    Args:
        version: the version this reader knows, or a tuple of the versions it reads.
        keys: manifest keys the format requires besides format, version and arrays.
    Returns:
        ``(manifest, arrays)``: the manifest dict and ``{name: np.ndarray}``, the arrays
        checked against the manifest's list (names, shapes, dtypes).
    """
    where = str(path)
    with _open(path, where) as npz:
        manifest = _manifest(npz, where)
        if manifest["format"] != format:
            fail(where, f"format is {manifest['format']!r}, expected {format!r}")
        known = (version,) if isinstance(version, int) else tuple(version)
        if manifest.get("version") not in known:
            fail(where, f"unknown version {manifest.get('version')!r}; this reader knows "
                        f"version {' and '.join(map(str, known))}")
        for key in ("arrays",) + tuple(keys):
            if key not in manifest:
                fail(where, f"manifest has no {key!r}")
        try:
            arrays = {n: npz[n] for n in npz.files if n != "manifest"}
        except _READ_ERRORS as e:
            raise BakedFormatError(f"{where}: cannot read the archive's arrays "
                                   f"(truncated or corrupt?): {e}") from e
    listed = manifest["arrays"]
    if not isinstance(listed, dict) or set(listed) != set(arrays):
        names = sorted(listed) if isinstance(listed, dict) else listed
        fail(where, f"manifest lists arrays {names}, the archive holds {sorted(arrays)}")
    for name, a in arrays.items():
        meta = listed[name]
        if not isinstance(meta, dict) or list(meta.get("shape", [])) != list(a.shape) \
                or meta.get("dtype") != str(a.dtype):
            fail(where, f"{name} is {a.dtype} {a.shape} but the manifest says {meta}")
    return manifest, arrays
