"""The method contract and registry: what a method plugs into the shell, and where to find it.

The shell (``clrender.load`` / ``Renderer`` / ``render``, evaluation, video, the CLI and the
benchmark harness) reaches a method only through here. Methods are found through the
entry-point group ``clrender.methods`` (as nerfstudio finds its methods): the entry point's
name is the method's name, its value the plug-in module, e.g. in ``pyproject.toml``::

    [project.entry-points."clrender.methods"]
    ngprt = "clrender.ngprt.method"

so a method may live in another package. A plug-in is checked against :class:`Method` (its
``Renderer`` against :class:`MethodRenderer`), hook signatures included, when it is first
loaded; it declares the contract version it was written for (``CONTRACT``). The method
`clrender train` trains without ``--method`` is registered the same way, in the group
``clrender.default_method`` (one entry, its name the method's).

Examples:
    >>> from clrender import methods
    >>> methods.get("ngprt").PRESETS
    ('tiny', 'cpu', 'paper')
    >>> model = methods.load("model.npz")          # whatever method baked it
"""
from __future__ import annotations

import functools
import inspect
import json
import sys
import types
import typing
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, ClassVar, Mapping, Protocol

from . import bakedfile

GROUP = "clrender.methods"
DEFAULT_GROUP = "clrender.default_method"
# The version of the contract below; a plug-in declares the one it meets (``CONTRACT``).
CONTRACT = 1


class PluginError(TypeError):
    """A registered plug-in does not meet the contract (the message names it)."""


@dataclass(frozen=True)
class Option:
    """A declared option of a method (a render option of its Renderer, or a training /
    model option of its ``train``), enough for a CLI flag, a bench row check or a viewer
    control.

    Attributes:
        type: bool, int, float or str (of each value when ``nargs``).
        default: the value the method uses when the option is not given (None: the
            preset's).
        help: one line for ``--help`` and tooltips.
        choices: the allowed values, or None.
        flag: the command-line spelling; None: ``--name`` with ``_`` as ``-`` (a bool
            that defaults to True: ``--no-name``).
        nargs: "+" for a list of values.
        required: the CLI requires it.
    """

    type: type
    default: Any
    help: str
    choices: tuple | None = None
    flag: str | None = None
    nargs: str | None = None
    required: bool = False

    def cli_flag(self, name: str) -> str:
        if self.flag:
            return self.flag
        dashed = name.replace("_", "-")
        return f"--no-{dashed}" if self.type is bool and self.default is True else f"--{dashed}"

    def check(self, name: str, value) -> None:
        """Raise ValueError unless ``value`` is a valid value of this option."""
        values = value if self.nargs else [value]
        if self.nargs and not isinstance(value, (list, tuple)):
            raise ValueError(f"option {name!r} takes a list of {self.type.__name__}, got {value!r}")
        for v in values:
            ok = isinstance(v, self.type) and not (self.type is not bool and isinstance(v, bool))
            if self.type is float and isinstance(v, int) and not isinstance(v, bool):
                ok = True
            if not ok:
                raise ValueError(f"option {name!r} takes {self.type.__name__}, got {v!r}")
            if self.choices is not None and v not in self.choices:
                raise ValueError(f"option {name!r} is {v!r}, expected one of {self.choices}")


@dataclass(frozen=True)
class Stat:
    """A per-pixel statistic a Renderer reports, averaged over pixels into a table column.

    Attributes:
        key: the (H, W) array's key in ``render(..., stats=True)``'s result.
        fmt: the column's format (``"{:.1f}"``).
        help: what it counts.
    """

    key: str
    fmt: str = "{:.3g}"
    help: str = ""


@dataclass(frozen=True)
class Teacher:
    """A method trained from another method's baked model.

    Attributes:
        option: the ``TRAIN_OPTIONS`` name that takes the teacher's baked file (in a bench
            row: a table of the teacher's model options, planned and cached like any model).
        method: the teacher's method.
    """

    option: str
    method: str


@dataclass(frozen=True)
class PaperSmoke:
    """A method's steps of ``bench.speed.paper_smoke`` (its `paper` preset's smoke run).

    Attributes:
        options: the cuts it takes ({name: Option}, flags of the tool; also ``steps``, the
            training steps, which every method takes).
        run: ``run(data, work, cuts, phase, render) -> dict``: the steps' results by name;
            ``cuts`` {option: value}, ``phase(fn, *args)`` runs ``fn`` (module-level,
            returning a dict) in a child process and adds its seconds and peak memory,
            ``render(baked)`` renders one view of a baked file in a child.
    """

    options: Mapping[str, Option]
    run: Callable


class MethodRenderer(Protocol):
    """A method's renderer: built once per model, rendering many views."""

    RENDER_OPTIONS: ClassVar[Mapping[str, Option]]   # keyword arguments of the constructor
    SCALAR_STATS: ClassVar[Mapping[str, Stat]]       # {table column: statistic}
    TIME_NOTE: ClassVar[str]                         # what ``ms`` covers, for table notes
    runtime: Any                                     # clrender.device.Runtime (``.name``)

    def __init__(self, model, device=None, **options) -> None: ...

    def render(self, camera, background=None, stats: bool = False) -> dict:
        """dict: ``rgb`` (H, W, 3) float32 in [0, 1], ``ms`` (the frame's time, ms),
        ``ms_<stage>`` per stage; with ``stats`` every :attr:`SCALAR_STATS` key and any
        other per-pixel statistic, (H, W) arrays."""


# on_step(step, bake): called after every training step (0-based, as log.jsonl); ``bake()``
# returns the in-memory baked model of the training state (a model ``Renderer`` takes).
StepHook = Callable[[int, Callable[[], Any]], None]


class Method(Protocol):
    """A method's plug-in module (see :func:`check` for what is verified; :data:`OPTIONAL`
    lists what a plug-in may leave out)."""

    CONTRACT: int                    # the version of this contract it meets (CONTRACT)
    FORMAT: str                      # the baked manifest's ``format``
    PRESETS: tuple[str, ...]         # preset names (CLI and bench choices)
    DEFAULT_PRESET: str              # `clrender train`'s preset when none is given
    TRAIN_OPTIONS: Mapping[str, Option]   # keyword options of ``train`` (CLI flags)
    TEACHER: Teacher | None          # which option takes which method's model, or None
    ABLATIONS: Path | None           # folder of the method's table TOMLs (bench), or None
    CURVE_TABLE: str | None          # train-curve: the baseline row of this table, or None
    Renderer: type[MethodRenderer]

    def load_baked(self, path) -> Any:
        """A validated model with ``.config.scene`` ("bounded" or "unbounded"); the shell
        stamps ``.method`` (the entry-point name) on it (:func:`load`)."""

    def train(self, data, out, preset: str, *, seed: int = 0, iterations: int | None = None,
              torch_device=None, progress: bool = True, on_step: StepHook | None = None,
              downscale: int = 1, **options) -> Path:
        """Train into (or resume) the run folder ``out`` on ``data`` read at ``downscale``
        (recorded in the run's config.json); ``options``: TRAIN_OPTIONS."""

    def train_steps(self, preset: str, iterations: int | None = None) -> tuple[int, int]:
        """(iterations, log_every) of a run of ``preset``."""

    def bake_run(self, run_dir, out_path, **options) -> Path:
        """Bake a run folder into a model file; returns its path. ``options``: its
        ``BAKE_OPTIONS`` (given only where it declares them)."""

    def check_model_options(self, options: dict) -> None:
        """Raise ValueError unless ``options`` are model options of a bench row."""

    def model_spec(self, preset: str, **options) -> dict:
        """Everything but data, seed and teacher that determines a trained model."""

    def add_commands(self, subparsers) -> None:
        """Add the method's own ``clrender`` sub-commands (may add none)."""


# Declarations a plug-in may leave out, with the value the shell then assumes:
# LEGACY_RUNS, run folders whose config.json lacks "method" are its; LIBRARIES, the
# distributions (beyond the shell's) whose versions can change its models (bench
# provenance); SOURCES, the files and folders of its training code, whose normalised text
# keys the model cache (bench/modelcache/cache.py); example_model(folder), a random model of its
# default sizes baked into ``folder``, returning the file (bench.tools.device_check, fuzzing);
# PAPER_SMOKE, its :class:`PaperSmoke`; BAKE_OPTIONS, keyword options of ``bake_run``
# ({name: Option}, CLI flags of `clrender bake`; a bench row's ``bake``).
OPTIONAL = {"LEGACY_RUNS": False, "LIBRARIES": (), "SOURCES": (), "example_model": None,
            "PAPER_SMOKE": None, "BAKE_OPTIONS": {}}
# The keywords (after the named positional arguments) the shell passes to each hook.
TRAIN_KEYWORDS = ("seed", "iterations", "torch_device", "progress", "on_step", "downscale")
SCENES = ("bounded", "unbounded")


def declared(plugin, name: str):
    """``plugin``'s declaration ``name`` of :data:`OPTIONAL`, or its default."""
    return getattr(plugin, name, OPTIONAL[name])


def _runtime_types(hint) -> tuple:
    """The classes ``isinstance`` checks for an annotation (``str | None``: str, NoneType;
    ``Mapping[str, Option]``: Mapping; ``ClassVar[X]``: X's)."""
    origin = typing.get_origin(hint)
    if origin is typing.ClassVar:
        return _runtime_types(typing.get_args(hint)[0])
    if origin in (typing.Union, types.UnionType):
        return tuple(t for a in typing.get_args(hint) for t in _runtime_types(a))
    return (origin or hint,)


def _declared(protocol) -> dict[str, tuple]:
    """{attribute: runtime classes} a Protocol declares (``Any`` ones left out)."""
    hints = typing.get_type_hints(protocol)
    return {name: _runtime_types(h) for name, h in hints.items() if h is not Any}


def _hooks(protocol) -> list[str]:
    return [n for n, v in vars(protocol).items() if callable(v) and not n.startswith("_")]


ATTRIBUTES, HOOKS = _declared(Method), _hooks(Method)
RENDERER_ATTRIBUTES = _declared(MethodRenderer)


def check(plugin) -> list[str]:
    """What ``plugin`` lacks of :class:`Method` (empty: it conforms)."""
    problems = [f"{a} is missing" if not hasattr(plugin, a) else
                f"{a} should be {' or '.join(c.__name__ for c in t)}, is "
                f"{type(getattr(plugin, a)).__name__}"
                for a, t in ATTRIBUTES.items() if not isinstance(getattr(plugin, a, None), t)
                or not hasattr(plugin, a)]
    problems += [f"{h} is not callable" for h in HOOKS if not callable(getattr(plugin, h, None))]
    if problems:
        return problems
    if plugin.CONTRACT != CONTRACT:
        problems.append(f"CONTRACT is {plugin.CONTRACT!r}; this clrender's method contract is "
                        f"version {CONTRACT}")
    if plugin.DEFAULT_PRESET not in plugin.PRESETS:
        problems.append(f"DEFAULT_PRESET {plugin.DEFAULT_PRESET!r} not in PRESETS")
    problems += [f"TRAIN_OPTIONS[{k!r}] is not an Option" for k, v in plugin.TRAIN_OPTIONS.items()
                 if not isinstance(v, Option)]
    if plugin.TEACHER is not None and plugin.TEACHER.option not in plugin.TRAIN_OPTIONS:
        problems.append(f"TEACHER.option {plugin.TEACHER.option!r} is not in TRAIN_OPTIONS")
    if declared(plugin, "example_model") is not None and not callable(plugin.example_model):
        problems.append("example_model should be callable")
    if not isinstance(declared(plugin, "PAPER_SMOKE"), (PaperSmoke, type(None))):
        problems.append("PAPER_SMOKE should be a PaperSmoke")
    problems += _signature_problems("train", plugin.train, ("data", "out", "preset"),
                                    (*TRAIN_KEYWORDS, *plugin.TRAIN_OPTIONS))
    problems += _signature_problems("bake_run", plugin.bake_run, ("run_dir", "out_path"), ())
    r = plugin.Renderer
    problems += [f"Renderer.{a} should be {' or '.join(c.__name__ for c in t)}"
                 for a, t in RENDERER_ATTRIBUTES.items() if not isinstance(getattr(r, a, None), t)]
    if problems:
        return problems
    problems += [f"Renderer.RENDER_OPTIONS[{k!r}] is not an Option"
                 for k, v in r.RENDER_OPTIONS.items() if not isinstance(v, Option)]
    problems += [f"Renderer.SCALAR_STATS[{k!r}] is not a Stat"
                 for k, v in r.SCALAR_STATS.items() if not isinstance(v, Stat)]
    problems += _signature_problems("Renderer", r, ("model",),
                                    ("device", *r.RENDER_OPTIONS))
    if not callable(getattr(r, "render", None)):
        problems.append("Renderer.render is not callable")
    else:
        problems += _signature_problems("Renderer.render", r.render, ("self", "camera"),
                                        ("background", "stats"))
    return problems


def _signature_problems(name: str, fn, positional: tuple[str, ...],
                        keywords: tuple[str, ...]) -> list[str]:
    """Why ``fn`` cannot be called as the shell calls it: ``positional`` arguments by
    position, then ``keywords`` all by keyword (empty: it can)."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return []                       # a builtin without a signature: not checkable
    try:
        sig.bind(*positional, **{k: None for k in keywords})
    except TypeError as e:
        call = ", ".join([*positional, *(f"{k}=" for k in keywords)])
        return [f"{name}{sig} cannot be called as {name}({call}): {e}"]
    return []


def _entry_points() -> dict[str, metadata.EntryPoint]:
    return _entry_points_on(tuple(sys.path))


@functools.lru_cache(maxsize=8)
def _entry_points_on(path: tuple) -> dict[str, metadata.EntryPoint]:
    """The group's entry points installed on ``path`` (sys.path; scanned once per path)."""
    found: dict[str, metadata.EntryPoint] = {}
    for ep in metadata.entry_points(group=GROUP):
        if ep.name in found and found[ep.name].value != ep.value:
            raise RuntimeError(f"method {ep.name!r} is registered twice in entry-point group "
                               f"{GROUP!r}: {found[ep.name].value} and {ep.value}")
        found[ep.name] = ep
    if not found:
        raise RuntimeError(f"no method registered in entry-point group {GROUP!r}: is clrender "
                           "installed (pip install -e .)?")
    return found


def names() -> list[str]:
    """The registered methods' names, sorted."""
    return sorted(_entry_points())


_checked: dict[str, ModuleType] = {}


def get(name: str) -> ModuleType:
    """The plug-in module of method ``name``, checked against :class:`Method` once."""
    eps = _entry_points()
    if name not in eps:
        raise ValueError(f"unknown method {name!r}; methods: {', '.join(sorted(eps))}")
    plugin = eps[name].load()
    if _checked.get(name) is not plugin:
        problems = check(plugin)
        if problems:
            raise PluginError(f"method {name!r} ({eps[name].value}) does not meet the method "
                              f"contract (clrender.methods.Method, version {CONTRACT}): "
                              f"{'; '.join(problems)}")
        _checked[name] = plugin
    return plugin


def for_format(fmt: str, where: str = "model") -> ModuleType:
    """The plug-in module of the method whose baked files have manifest format ``fmt``."""
    plugins = {name: get(name) for name in names()}
    for plugin in plugins.values():
        if plugin.FORMAT == fmt:
            return plugin
    known = ", ".join(p.FORMAT for p in plugins.values())
    raise bakedfile.BakedFormatError(f"{where}: format is {fmt!r}, expected one of {known}")


def name_of(plugin) -> str:
    """The registered name of a plug-in module."""
    for name in names():
        if get(name) is plugin:
            return name
    raise ValueError(f"{plugin!r} is not a registered method")


def load(path):
    """Load and validate a baked file of any method (its manifest names the format), its
    ``.method`` stamped with the method's name."""
    plugin = for_format(bakedfile.peek_format(path), str(path))
    return stamp(plugin.load_baked(path), name_of(plugin), str(path))


def stamp(model, name: str, where: str = "model"):
    """``model`` with ``.method = name`` (set on frozen dataclasses too), after checking
    the contract's ``model.config.scene``; returns ``model``."""
    scene = getattr(getattr(model, "config", None), "scene", None)
    if scene not in SCENES:
        raise bakedfile.BakedFormatError(f"{where}: a {name} model's config.scene is "
                                         f"{scene!r}, expected one of {SCENES}")
    object.__setattr__(model, "method", name)
    return model


def default() -> str:
    """The method `clrender train` trains without ``--method``: the one entry of group
    :data:`DEFAULT_GROUP` (its name), else the only registered method."""
    chosen = sorted({ep.name for ep in metadata.entry_points(group=DEFAULT_GROUP)})
    known = names()
    if not chosen and len(known) == 1:
        return known[0]
    if len(chosen) != 1 or chosen[0] not in known:
        raise RuntimeError(f"entry-point group {DEFAULT_GROUP!r} should name one registered "
                           f"method ({', '.join(known)}), names {chosen or 'none'}")
    return chosen[0]


def of_model(model) -> ModuleType:
    """The plug-in module of a loaded model (``model.method``)."""
    return get(model.method)


def of_run(run_dir) -> ModuleType:
    """The plug-in module of a training run folder: ``config.json``'s ``method``; a folder
    written before runs named their method belongs to the method with ``LEGACY_RUNS``."""
    conf = Path(run_dir) / "config.json"
    if not conf.is_file():
        raise FileNotFoundError(f"{conf}: not a training run (no config.json)")
    try:
        config = json.loads(conf.read_text())
        name = config.get("method")
    except (json.JSONDecodeError, AttributeError) as e:
        raise ValueError(f"{conf}: not a JSON object ({e})") from e
    if name is None:
        legacy = [n for n in names() if declared(get(n), "LEGACY_RUNS")]
        if len(legacy) != 1:
            raise ValueError(f"{conf}: no \"method\" and {len(legacy)} methods claim such runs")
        name = legacy[0]
    return get(name)


def all_presets() -> list[str]:
    """Every preset name of every method, in first-seen order."""
    seen = []
    for name in names():
        seen += [p for p in get(name).PRESETS if p not in seen]
    return seen
