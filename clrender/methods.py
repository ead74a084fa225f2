"""The method contract and registry: what a method plugs into the shell, and where to find it.

The shell (``clrender.load`` / ``Renderer`` / ``render``, evaluation, video, the CLI and the
benchmark harness) reaches a method only through here. Methods are found through the
entry-point group ``clrender.methods`` (as nerfstudio finds its methods): the entry point's
name is the method's name, its value the plug-in module, e.g. in ``pyproject.toml``::

    [project.entry-points."clrender.methods"]
    ngprt = "clrender.ngprt.method"

so a method may live in another package. A plug-in is checked against :class:`Method` (its
``Renderer`` against :class:`MethodRenderer`) when it is first loaded.

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
# The method `clrender train` trains when --method is not given.
DEFAULT = "ngprt"


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
    """A method's plug-in module (see :func:`check` for what is verified)."""

    FORMAT: str                      # the baked manifest's ``format``
    PRESETS: tuple[str, ...]         # preset names (CLI and bench choices)
    DEFAULT_PRESET: str              # `clrender train`'s preset when none is given
    TRAIN_OPTIONS: Mapping[str, Option]   # keyword options of ``train`` (CLI flags)
    TEACHER: str | None              # the method of the model option ``teacher``, or None
    ABLATIONS: Path | None           # folder of the method's table TOMLs (bench), or None
    CURVE_TABLE: str | None          # train-curve: the baseline row of this table, or None
    LEGACY_RUNS: bool                # run folders whose config.json lacks "method" are its
    Renderer: type[MethodRenderer]

    def load_baked(self, path) -> Any:
        """A validated model with ``.method`` (the entry-point name) and ``.config.scene``."""

    def train(self, data, out, preset: str, *, seed: int = 0, iterations: int | None = None,
              torch_device=None, progress: bool = True, on_step: StepHook | None = None,
              downscale: int = 1, **options) -> Path:
        """Train into (or resume) the run folder ``out`` on ``data`` read at ``downscale``
        (recorded in the run's config.json); ``options``: TRAIN_OPTIONS."""

    def train_steps(self, preset: str, iterations: int | None = None) -> tuple[int, int]:
        """(iterations, log_every) of a run of ``preset``."""

    def bake_run(self, run_dir, out_path) -> Path:
        """Bake a run folder into a model file; returns its path."""

    def check_model_options(self, options: dict) -> None:
        """Raise ValueError unless ``options`` are model options of a bench row."""

    def model_spec(self, preset: str, **options) -> dict:
        """Everything but data, seed and teacher that determines a trained model."""

    def add_commands(self, subparsers) -> None:
        """Add the method's own ``clrender`` sub-commands (may add none)."""


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
    if plugin.DEFAULT_PRESET not in plugin.PRESETS:
        problems.append(f"DEFAULT_PRESET {plugin.DEFAULT_PRESET!r} not in PRESETS")
    problems += [f"TRAIN_OPTIONS[{k!r}] is not an Option" for k, v in plugin.TRAIN_OPTIONS.items()
                 if not isinstance(v, Option)]
    r = plugin.Renderer
    problems += [f"Renderer.{a} should be {' or '.join(c.__name__ for c in t)}"
                 for a, t in RENDERER_ATTRIBUTES.items() if not isinstance(getattr(r, a, None), t)]
    if problems:
        return problems
    problems += [f"Renderer.RENDER_OPTIONS[{k!r}] is not an Option"
                 for k, v in r.RENDER_OPTIONS.items() if not isinstance(v, Option)]
    problems += [f"Renderer.SCALAR_STATS[{k!r}] is not a Stat"
                 for k, v in r.SCALAR_STATS.items() if not isinstance(v, Stat)]
    params = inspect.signature(r).parameters
    problems += [f"Renderer() takes no render option {k!r}" for k in r.RENDER_OPTIONS
                 if k not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values())]
    if not callable(getattr(r, "render", None)):
        problems.append("Renderer.render is not callable")
    return problems


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
            raise TypeError(f"method {name!r} ({eps[name].value}) does not meet the method "
                            f"contract (clrender.methods.Method): {'; '.join(problems)}")
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
    """Load and validate a baked file of any method (its manifest names the format)."""
    return for_format(bakedfile.peek_format(path), str(path)).load_baked(path)


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
        legacy = [n for n in names() if get(n).LEGACY_RUNS]
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
