"""Cached scenes and trained/baked models for the benchmark harness.

Models are keyed by a hash of everything that determines them (the method's model and
training config, data fingerprint, seed, teacher), so tables that share a row configuration
share a model (table2's L=4 row is table3's Separate-Att (V) row and table4's L=4 rows; every
NDRF row of a scene shares its NGP-RT teacher).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from clrender import methods
from clrender.atomic import write_atomic

BUILTIN_SCENES = {"builtin-bounded": "bounded", "builtin-unbounded": "unbounded"}


def cache_root() -> Path:
    """``$CLRENDER_CACHE``, else ``$XDG_CACHE_HOME/clrender``, else ``~/.cache/clrender``."""
    if os.environ.get("CLRENDER_CACHE"):
        return Path(os.environ["CLRENDER_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "clrender"


def resolve_scene(scene: str, root: Path) -> Path:
    """A dataset folder for ``scene``: a built-in name (generated once, again when the
    generator changed) or a path."""
    if scene in BUILTIN_SCENES:
        path = root / "scenes" / f"{scene}-seed0"
        if not _is_current(path, BUILTIN_SCENES[scene]):
            from clrender.data import make_scene

            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=".tmp-scene-"))
            make_scene(BUILTIN_SCENES[scene], tmp, seed=0)
            shutil.rmtree(path, ignore_errors=True)
            os.replace(tmp, path)
        return path
    path = Path(scene)
    if not path.is_dir():
        raise ValueError(f"--scene {scene!r}: neither a built-in scene "
                         f"({', '.join(BUILTIN_SCENES)}) nor a dataset folder")
    return path


def _is_current(path: Path, kind: str) -> bool:
    """Whether ``path`` holds the built-in ``kind`` scene as today's generator makes it."""
    from clrender.data.scene import scene_key

    try:
        meta = json.loads((path / "transforms_train.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("clrender") == scene_key(kind, 0)


def data_fingerprint(path: Path, downscale: int = 1) -> str:
    """sha256 over the relative names and bytes of every file of a dataset folder, and
    the ``downscale`` it is read at (when not 1, so earlier fingerprints stay valid)."""
    h = hashlib.sha256()
    if downscale != 1:
        h.update(f"downscale={downscale}".encode())
    for f in sorted(p for p in Path(path).rglob("*") if p.is_file()):
        h.update(str(f.relative_to(path)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


@dataclass(frozen=True)
class ModelEntry:
    """A trained and baked model in the cache."""

    key: str
    baked: Path
    run_dir: Path
    train_minutes: float


def _model_key(spec: dict) -> str:
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def ensure_model(root: Path, data: Path, fingerprint: str, preset: str, method: str,
                 options: dict, seed: int = 0, torch_device: str | None = None,
                 downscale: int = 1) -> ModelEntry:
    """Train (if missing) and bake (if missing) the model of one table row.

    Args:
        method: the row's method; ``options`` its model options. An option ``teacher``
            (a dict of model options of the method's ``TEACHER`` method) names a teacher
            that is ensured first (cached like any model) and handed to the method's
            training as a baked file.
        fingerprint, downscale: :func:`data_fingerprint` of ``data`` read at ``downscale``.
    """
    plugin = methods.get(method)
    if preset not in plugin.PRESETS:
        raise ValueError(f"preset {preset!r}: method {method!r} has presets "
                         f"{', '.join(plugin.PRESETS)}")
    options = dict(options)
    teacher = None
    if "teacher" in options:
        if plugin.TEACHER is None:
            raise ValueError(f"method {method!r} takes no teacher")
        teacher = ensure_model(root, data, fingerprint, preset, plugin.TEACHER,
                               options.pop("teacher"), seed=seed, torch_device=torch_device,
                               downscale=downscale)
    spec = {**plugin.model_spec(preset, **options), "data": fingerprint, "seed": seed}
    if teacher is not None:
        spec["teacher"] = teacher.key
    key = _model_key(spec)
    folder = root / "models" / key
    meta_path, baked = folder / "meta.json", folder / "model.npz"
    if not meta_path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        if teacher is not None:
            options["teacher"] = str(teacher.baked)
        plugin.train(str(data), folder / "run", preset, seed=seed, torch_device=torch_device,
                     downscale=downscale, **options)
        minutes = (time.perf_counter() - start) / 60.0
        plugin.bake_run(folder / "run", baked)
        write_atomic(meta_path, json.dumps({"spec": spec, "train_minutes": minutes}, indent=2))
    elif not baked.is_file():
        plugin.bake_run(folder / "run", baked)
    meta = json.loads(meta_path.read_text())
    return ModelEntry(key, baked, folder / "run", float(meta["train_minutes"]))
