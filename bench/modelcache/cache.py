"""Cached scenes and trained/baked models for the benchmark harness, safe for many writers.

Models are keyed by a hash of everything that determines them (the method's model and
training config, the code that trains it (bench/modelcache/fingerprint.py), data fingerprint, seed,
teacher), so tables that share a row configuration
share a model (table2's L=4 row is table3's Separate-Att (V) row and table4's L=4 rows; every
NDRF row of a scene shares its NGP-RT teacher).

Layout under the root: ``models/<key>/`` (``run/``, ``model.npz``, ``meta.json`` written
last and atomically: a model is cached once its ``meta.json`` exists), ``scenes/<name>/``,
and ``trainings.jsonl`` (one line per finished training: key, method, seed, host, pid).
Any number of processes (bench.run, Ray tasks' drivers) may share a root on one machine's
file system: a model or a built-in scene is made under its own lock (``filelock``, an
``flock`` the kernel releases when its holder dies, so a killed process's lock is never
stale), and whoever waited finds it made. File locks are not trusted across the nodes of a
network file system: there, one driver owns the cache (bench/modelcache/cluster.py).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from filelock import FileLock

from bench.modelcache import provenance
from bench.modelcache.fingerprint import code_fingerprint
from clrender import methods
from clrender.atomic import atomic_folder, remove_leftovers, write_atomic

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
        if _is_current(path, BUILTIN_SCENES[scene]):
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        with lock(path.parent / f"{path.name}.lock"):
            if not _is_current(path, BUILTIN_SCENES[scene]):     # made while we waited?
                _make_scene(BUILTIN_SCENES[scene], path)
        return path
    path = Path(scene)
    if not path.is_dir():
        raise ValueError(f"--scene {scene!r}: neither a built-in scene "
                         f"({', '.join(BUILTIN_SCENES)}) nor a dataset folder")
    return path


def lock(path: Path) -> FileLock:
    """The lock file ``path`` (held with ``with``; blocks until free)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return FileLock(str(path))


def _make_scene(kind: str, path: Path) -> None:
    """Generate a built-in scene into ``path`` (its lock held), atomically, after clearing
    the temporary folders of this scene's generators killed mid-way."""
    from clrender.data import make_scene

    for stale in path.parent.glob(f".{path.name}.*"):
        shutil.rmtree(stale, ignore_errors=True)
    shutil.rmtree(path, ignore_errors=True)
    atomic_folder(path, lambda tmp: make_scene(kind, tmp, seed=0))


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
    """A trained and baked model in the cache; ``trained_by``: what trained it (host,
    preset, seed, versions, git revision; {} for models cached before it was recorded)."""

    key: str
    baked: Path
    run_dir: Path
    train_minutes: float
    trained_by: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ModelPlan:
    """A model a table row needs, before it is trained: what :func:`train_into` trains.

    Attributes:
        key: the cache key (a hash of ``spec``); ``folder`` its cache folder.
        options: the method's training options, its teacher's option left out
            (``teacher`` is the teacher's own plan, or None).
        fingerprint: :func:`data_fingerprint` of ``data`` read at ``downscale``.
    """

    key: str
    spec: dict
    folder: Path
    data: Path
    fingerprint: str
    downscale: int
    preset: str
    method: str
    options: dict
    seed: int
    teacher: "ModelPlan | None"

    @property
    def cached(self) -> bool:
        return (self.folder / "meta.json").is_file()

    def lock(self) -> FileLock:
        return lock(self.folder / ".lock")


def _model_key(spec: dict) -> str:
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def plan_model(root: Path, data: Path, fingerprint: str, preset: str, method: str,
               options: dict, seed: int = 0, downscale: int = 1) -> ModelPlan:
    """The :class:`ModelPlan` of one table row's model (and of its teacher, nested).

    Args:
        method: the row's method; ``options`` its model options. The option its bench
            spec's ``teacher`` declares (a dict of model options of the teacher's method)
            names a teacher, planned (and cached) like any model and handed to the
            training as a baked file.
        fingerprint, downscale: :func:`data_fingerprint` of ``data`` read at ``downscale``.
    """
    presets, bench = methods.get(method).presets, methods.bench_of(method)
    if preset not in presets:
        raise ValueError(f"preset {preset!r}: method {method!r} has presets "
                         f"{', '.join(presets)}")
    options = dict(options)
    teacher = None
    if bench.teacher is not None and bench.teacher.option in options:
        teacher = plan_model(root, data, fingerprint, preset, bench.teacher.method,
                             options.pop(bench.teacher.option), seed=seed,
                             downscale=downscale)
    spec = {**bench.model_spec(preset, **options), "code": code_fingerprint(method),
            "data": fingerprint, "seed": seed}
    if teacher is not None:
        spec["teacher"] = teacher.key
    key = _model_key(spec)
    return ModelPlan(key, spec, Path(root) / "models" / key, Path(data), fingerprint, downscale,
                     preset, method, options, seed, teacher)


def ensure_model(root: Path, data: Path, fingerprint: str, preset: str, method: str,
                 options: dict, seed: int = 0, torch_device: str | None = None,
                 downscale: int = 1) -> ModelEntry:
    """Train (if missing) and bake (if missing) the model of one table row, in this
    process, its teacher first; arguments as :func:`plan_model`."""
    return ensure(plan_model(root, data, fingerprint, preset, method, options, seed=seed,
                             downscale=downscale), torch_device)


def ensure(plan: ModelPlan, torch_device: str | None = None) -> ModelEntry:
    """The cached model of ``plan``, trained here (in its cache folder, under its lock,
    resuming a checkpoint a killed run left) when no process has cached it yet."""
    teacher = ensure(plan.teacher, torch_device) if plan.teacher is not None else None
    with plan.lock():
        if not plan.cached:
            remove_leftovers(plan.folder)
            remove_leftovers(plan.folder / "run")
            record = train_into(plan, plan.folder, teacher and teacher.baked, torch_device)
            commit(plan, {}, record)
        elif not (plan.folder / "model.npz").is_file():
            methods.get(plan.method).bake_run(plan.folder / "run", plan.folder / "model.npz")
    return entry(plan)


def train_into(plan: ModelPlan, folder: Path, teacher_baked: Path | None,
               torch_device: str | None = None, progress: bool = True,
               revision: str | None = None) -> dict:
    """Train ``plan`` into ``folder/run`` and bake ``folder/model.npz``; returns the
    record :func:`commit` stores (``spec``, ``train_minutes``: a resumed run's earlier
    processes included, :func:`earlier_seconds`; ``trained_by``;
    ``revision``: see :func:`bench.modelcache.provenance.trained_by`)."""
    import torch

    from clrender.runs import pick_device

    plugin, options = methods.get(plan.method), dict(plan.options)
    if plan.teacher is not None:
        options[plugin.bench.teacher.option] = str(teacher_baked)
    resumed = (folder / "run" / "checkpoint.pt").is_file()
    start = time.perf_counter()
    plugin.train(str(plan.data), folder / "run", plan.preset, seed=plan.seed,
                 torch_device=torch_device, progress=progress, downscale=plan.downscale,
                 **options)
    seconds = time.perf_counter() - start + (earlier_seconds(folder / "run") if resumed else 0.0)
    plugin.bake_run(folder / "run", folder / "model.npz")
    who = provenance.trained_by(str(pick_device(torch_device)), torch.get_num_threads(),
                                revision)
    return {"spec": plan.spec, "train_minutes": seconds / 60.0,
            "trained_by": {**who, "method": plan.method, "preset": plan.preset,
                           "seed": plan.seed, "resumed_checkpoint": resumed}}


def earlier_seconds(run_dir: Path) -> float:
    """Training seconds of the earlier processes of a resumed run, from its ``log.jsonl``.

    Each process of the run logs ``seconds`` from its own start (the clock falls back where
    one resumed) and its last checkpoint's steps were trained again by the next; each
    earlier process counts up to its last line before the step its successor started
    from. With one process, 0."""
    from clrender.runs import read_log

    segments: list[list[dict]] = [[]]
    for line in read_log(run_dir):
        if segments[-1] and line["seconds"] < segments[-1][-1]["seconds"]:
            segments.append([])
        segments[-1].append(line)
    return sum(max((line["seconds"] for line in segment if line["step"] < after[0]["step"]),
                   default=0.0)
               for segment, after in zip(segments, segments[1:]))


def commit(plan: ModelPlan, files: dict[str, bytes], record: dict) -> None:
    """Store ``files`` ({path relative to the model folder: bytes}, each written
    atomically) then ``meta.json`` (the model is cached from then on) and a line of
    ``trainings.jsonl``. The caller holds ``plan``'s lock."""
    for rel, data in sorted(files.items()):
        write_atomic(plan.folder / rel, data)
    write_atomic(plan.folder / "meta.json", json.dumps(record, indent=2))
    line = {"key": plan.key, "method": plan.method, "seed": plan.seed,
            "host": record["trained_by"]["host"], "pid": record["trained_by"]["pid"],
            "train_minutes": record["train_minutes"]}
    root = plan.folder.parent.parent
    with lock(root / "trainings.jsonl.lock"), open(root / "trainings.jsonl", "a") as log:
        log.write(json.dumps(line) + "\n")


def ensure_baked(entry: ModelEntry, method: str, options: dict) -> ModelEntry:
    """``entry`` with its run baked with ``options`` (the method's ``bake_options``) into
    ``model-<name=value,...>.npz`` beside its ``model.npz`` (once, under the model's lock);
    ``entry`` itself where every option has its default (what ``model.npz`` holds)."""
    declared = methods.get(method).bake_options
    options = {k: v for k, v in options.items() if v != declared[k].default}
    if not options:
        return entry
    name = ",".join(f"{k}={options[k]}" for k in sorted(options))
    baked = entry.baked.with_name(f"model-{name}.npz")
    with lock(entry.baked.parent / ".lock"):
        if not baked.is_file():
            methods.get(method).bake_run(entry.run_dir, baked, **options)
    return replace(entry, baked=baked)


def entry(plan: ModelPlan) -> ModelEntry:
    """The cached :class:`ModelEntry` of ``plan`` (its ``meta.json`` must exist)."""
    meta = json.loads((plan.folder / "meta.json").read_text())
    return ModelEntry(plan.key, plan.folder / "model.npz", plan.folder / "run",
                      float(meta["train_minutes"]), meta.get("trained_by", {}))

