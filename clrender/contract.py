"""The method contract: what a method plugs into the shell, as data.

A method is a :class:`MethodSpec`, a frozen dataclass its plug-in fills with what rendering,
training, baking and the CLI need (as nerfstudio's ``MethodSpecification`` or gsplat's
``Strategy``); what only the benchmarks need is its own optional :class:`BenchSpec`. A spec
checks itself when it is made, hook signatures included, so a plug-in that does not meet
the contract fails to import with a :class:`PluginError` saying what is wrong. The registry
that finds methods is :mod:`clrender.methods`.

Examples:
    >>> METHOD = MethodSpec(format="clrender-toy", presets=("tiny",), default_preset="tiny",
    ...                     renderer=Renderer, load_baked=load_baked, train=train,
    ...                     bake_run=bake_run, train_options={"radius": Option(float, 0.6,
    ...                     "sphere radius")}, bench=BenchSpec(model_spec, steps))
"""
from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol


class PluginError(TypeError):
    """A registered plug-in does not meet the contract (the message names it)."""


@dataclass(frozen=True)
class Option:
    """A declared option of a method (a render option of its Renderer, or a training /
    model or bake option), enough for a CLI flag, a bench row check or a viewer control.

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
        minimum: the smallest value allowed (numbers), or None.
    """

    type: type
    default: Any
    help: str
    choices: tuple | None = None
    flag: str | None = None
    nargs: str | None = None
    required: bool = False
    minimum: float | None = None

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
            if self.minimum is not None and v < self.minimum:
                raise ValueError(f"option {name!r} is {v!r}, expected >= {self.minimum}")


def check_options(given: Mapping, declared: Mapping[str, Option], what: str,
                  method: str) -> None:
    """Reject the options of ``given`` that ``declared`` lacks, then check each value.

    Args:
        given: {name: value}, e.g. a Renderer's keyword options or a bench row's table.
        declared: the method's {name: :class:`Option`} of that kind.
        what, method: for the message: "render options ['use_G'] do not apply to method
            'ndrf'; it takes ['hits']".
    Raises:
        ValueError: an unknown option, or the first invalid value (:meth:`Option.check`).
    """
    unknown = sorted(set(given) - set(declared))
    if unknown:
        raise ValueError(f"{what} {unknown} do not apply to method {method!r}; it takes "
                         f"{sorted(declared) or 'none'}")
    for name, value in given.items():
        declared[name].check(name, value)


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
        option: the training option that takes the teacher's baked file (in a bench row:
            a table of the teacher's model options, planned and cached like any model).
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
# returns the in-memory baked model of the training state (a model ``renderer`` takes).
StepHook = Callable[[int, Callable[[], Any]], None]
# The keywords (after data, out, preset) the shell passes to ``train``.
TRAIN_KEYWORDS = ("seed", "iterations", "torch_device", "progress", "on_step", "downscale")


@dataclass(frozen=True, eq=False)
class BenchSpec:
    """What the benchmark harness (``bench/``) needs of a method, beyond its MethodSpec.

    Attributes:
        model_spec: ``model_spec(preset, **model_options) -> dict``: everything but data,
            seed and teacher that determines a trained model (the model cache's key).
        steps: ``steps(preset) -> (iterations, log_every)`` of a run of ``preset``
            (:func:`preset_steps` reads a training module's ``TRAIN_PRESETS``).
        sources: the files and folders of its training code, whose normalised text keys
            the model cache (``bench/modelcache/fingerprint.py``).
        libraries: the distributions (beyond the shell's) whose versions can change its
            models (provenance of a cached model).
        teacher: which training option takes which method's model, or None.
        ablations: the folder of its paper tables (TOML), or None.
        curve_table: ``bench.train_curve``'s baseline row is this table's, or None.
        example_model: ``example_model(path) -> Path``: a random model of its default
            sizes baked to ``path`` (``bench.tools.device_check``), or None.
        paper_smoke: its :class:`PaperSmoke`, or None.
    """

    model_spec: Callable[..., dict]
    steps: Callable[[str], tuple[int, int]]
    sources: tuple = ()
    libraries: tuple[str, ...] = ()
    teacher: Teacher | None = None
    ablations: Path | None = None
    curve_table: str | None = None
    example_model: Callable[[Any], Path] | None = None
    paper_smoke: PaperSmoke | None = None

    def __post_init__(self):
        _raise_problems("BenchSpec", _bench_problems(self))

    def train_steps(self, preset: str, iterations: int | None = None) -> tuple[int, int]:
        """(iterations, log_every) of a run of ``preset``, ``iterations`` overriding."""
        n, log_every = self.steps(preset)
        return (n if iterations is None else int(iterations)), log_every


def preset_steps(module: str) -> Callable[[str], tuple[int, int]]:
    """A :attr:`BenchSpec.steps` reading ``module``'s ``TRAIN_PRESETS`` ({preset: a config
    with ``iterations`` and ``log_every``}), imported when first asked (training imports
    torch; rendering must not)."""
    def steps(preset: str) -> tuple[int, int]:
        tcfg = importlib.import_module(module).TRAIN_PRESETS[preset]
        return tcfg.iterations, tcfg.log_every

    return steps


@dataclass(frozen=True, eq=False)
class MethodSpec:
    """A method, as its plug-in declares it (``METHOD = MethodSpec(...)``); checked when
    made (a :class:`PluginError` lists what is wrong).

    Attributes:
        format: the baked manifest's ``format``.
        presets: preset names (CLI and bench choices); ``default_preset`` among them is
            `clrender train`'s when none is given.
        renderer: its :class:`MethodRenderer` class.
        load_baked: ``load_baked(path)``: a validated model with ``.config.scene``
            ("bounded" or "unbounded"); the shell stamps ``.method`` on it (:func:`load`).
        train: ``train(data, out, preset, *, seed=0, iterations=None, torch_device=None,
            progress=True, on_step=None, downscale=1, **train_options) -> Path``: train
            into (or resume) the run folder ``out`` on ``data`` read at ``downscale``
            (recorded in the run's config.json, with ``"method"``); ``on_step`` a
            :data:`StepHook`.
        bake_run: ``bake_run(run_dir, out_path, **bake_options) -> Path``: a run folder
            baked into a model file.
        train_options, bake_options: {name: :class:`Option`} of ``train`` / ``bake_run``
            (CLI flags; a bench row's ``model`` / ``bake``).
        add_commands: ``add_commands(subparsers)`` adds its own ``clrender`` commands, or
            None.
        bench: its :class:`BenchSpec`, or None (no benchmark tables or cache).
    """

    format: str
    presets: tuple[str, ...]
    default_preset: str
    renderer: type
    load_baked: Callable[[Any], Any]
    train: Callable[..., Path]
    bake_run: Callable[..., Path]
    train_options: Mapping[str, Option] = field(default_factory=dict)
    bake_options: Mapping[str, Option] = field(default_factory=dict)
    add_commands: Callable | None = None
    bench: BenchSpec | None = None

    def __post_init__(self):
        _raise_problems("MethodSpec", _spec_problems(self))


def _raise_problems(what: str, problems: list[str]) -> None:
    if problems:
        raise PluginError(f"{what}: {'; '.join(problems)}")


def _type_problems(obj, types: dict[str, tuple]) -> list[str]:
    return [f"{name} should be {' or '.join(t.__name__ for t in ts)}, is "
            f"{type(getattr(obj, name)).__name__}"
            for name, ts in types.items() if not isinstance(getattr(obj, name), ts)]


def _not_callable(obj, names: tuple[str, ...], optional: bool = False) -> list[str]:
    return [f"{n} is not callable" for n in names
            if not callable(getattr(obj, n)) and not (optional and getattr(obj, n) is None)]


def _options_problems(where: str, options: Mapping, kind: type = Option) -> list[str]:
    return [f"{where}[{k!r}] is not {kind.__name__}" for k, v in options.items()
            if not isinstance(v, kind)]


def _spec_problems(spec: MethodSpec) -> list[str]:
    problems = _type_problems(spec, {"format": (str,), "presets": (tuple,),
                                     "default_preset": (str,), "renderer": (type,),
                                     "train_options": (Mapping,), "bake_options": (Mapping,),
                                     "bench": (BenchSpec, type(None))})
    problems += _not_callable(spec, ("load_baked", "train", "bake_run"))
    problems += _not_callable(spec, ("add_commands",), optional=True)
    if problems:
        return problems
    if spec.default_preset not in spec.presets:
        problems.append(f"default_preset {spec.default_preset!r} not in presets")
    problems += _options_problems("train_options", spec.train_options)
    problems += _options_problems("bake_options", spec.bake_options)
    teacher = spec.bench and spec.bench.teacher
    if teacher and teacher.option not in spec.train_options:
        problems.append(f"bench.teacher.option {teacher.option!r} is not in train_options")
    problems += _signature_problems("train", spec.train, ("data", "out", "preset"),
                                    (*TRAIN_KEYWORDS, *spec.train_options))
    problems += _signature_problems("bake_run", spec.bake_run, ("run_dir", "out_path"),
                                    tuple(spec.bake_options))
    return problems + _renderer_problems(spec.renderer)


def _renderer_problems(r: type) -> list[str]:
    problems = [f"renderer.{a} should be {t.__name__}" for a, t in (
        ("RENDER_OPTIONS", Mapping), ("SCALAR_STATS", Mapping), ("TIME_NOTE", str))
        if not isinstance(getattr(r, a, None), t)]
    if problems:
        return problems
    problems += _options_problems("renderer.RENDER_OPTIONS", r.RENDER_OPTIONS)
    problems += _options_problems("renderer.SCALAR_STATS", r.SCALAR_STATS, Stat)
    problems += _signature_problems("renderer", r, ("model",), ("device", *r.RENDER_OPTIONS))
    if not callable(getattr(r, "render", None)):
        return problems + ["renderer.render is not callable"]
    return problems + _signature_problems("renderer.render", r.render, ("self", "camera"),
                                          ("background", "stats"))


def _bench_problems(bench: BenchSpec) -> list[str]:
    problems = _type_problems(bench, {"sources": (tuple,), "libraries": (tuple,),
                                      "teacher": (Teacher, type(None)),
                                      "ablations": (Path, type(None)),
                                      "curve_table": (str, type(None)),
                                      "paper_smoke": (PaperSmoke, type(None))})
    problems += _not_callable(bench, ("model_spec", "steps"))
    return problems + _not_callable(bench, ("example_model",), optional=True)


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


