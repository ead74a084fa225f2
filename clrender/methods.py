"""The method registry: where the shell finds methods, and the calls it makes through them.

The shell (``clrender.load`` / ``Renderer`` / ``render``, evaluation, video, the CLI and the
benchmark harness) reaches a method only through here. Methods are found through the
entry-point group ``clrender.methods`` (as nerfstudio finds its methods): the entry point's
name is the method's name, its value the method's :class:`clrender.contract.MethodSpec`
(``package.module:METHOD``) or the plug-in module that holds it as ``METHOD``, e.g. in
``pyproject.toml``::

    [project.entry-points."clrender.methods"]
    ngprt = "clrender.ngprt.method"

so a method may live in another package. The method `clrender train` trains without
``--method`` is registered the same way, in the group ``clrender.default_method`` (one
entry, its name the method's).

Examples:
    >>> from clrender import methods
    >>> methods.get("ngprt").presets
    ('tiny', 'cpu', 'paper')
    >>> model = methods.load("model.npz")          # whatever method baked it
"""
from __future__ import annotations

import functools
import json
import sys
from importlib import metadata
from pathlib import Path

from . import bakedfile
from .contract import BenchSpec, MethodSpec, PluginError

GROUP = "clrender.methods"
DEFAULT_GROUP = "clrender.default_method"
SCENES = ("bounded", "unbounded")


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


def get(name: str) -> MethodSpec:
    """The :class:`MethodSpec` of method ``name`` (its entry point's object, or that
    module's ``METHOD``)."""
    eps = _entry_points()
    if name not in eps:
        raise ValueError(f"unknown method {name!r}; methods: {', '.join(sorted(eps))}")
    where = f"method {name!r} ({eps[name].value})"
    try:
        loaded = eps[name].load()
    except PluginError as e:
        raise PluginError(f"{where} does not meet the method contract "
                          f"(clrender.contract.MethodSpec): {e}") from e
    spec = getattr(loaded, "METHOD", loaded)
    if not isinstance(spec, MethodSpec):
        raise PluginError(f"{where} is a {type(loaded).__name__}, expected a "
                          f"clrender.contract.MethodSpec or a module whose METHOD is one")
    return spec


def bench_of(name: str) -> BenchSpec:
    """Method ``name``'s :class:`BenchSpec`; ValueError where it declares none."""
    bench = get(name).bench
    if bench is None:
        raise ValueError(f"method {name!r} declares no benchmark spec (MethodSpec.bench): "
                         f"the benchmarks cannot train or cache its models")
    return bench


def benched() -> dict[str, BenchSpec]:
    """{name: BenchSpec} of the registered methods that declare one."""
    return {n: get(n).bench for n in names() if get(n).bench is not None}


def for_format(fmt: str, where: str = "model") -> MethodSpec:
    """The spec of the method whose baked files have manifest format ``fmt``."""
    specs = {name: get(name) for name in names()}
    for spec in specs.values():
        if spec.format == fmt:
            return spec
    known = ", ".join(s.format for s in specs.values())
    raise bakedfile.BakedFormatError(f"{where}: format is {fmt!r}, expected one of {known}")


def name_of(spec: MethodSpec) -> str:
    """The registered name of a method's spec."""
    for name in names():
        if get(name) is spec:
            return name
    raise ValueError(f"{spec!r} is not a registered method")


def load(path):
    """Load and validate a baked file of any method (its manifest names the format), its
    ``.method`` stamped with the method's name."""
    spec = for_format(bakedfile.peek_format(path), str(path))
    return stamp(spec.load_baked(path), name_of(spec), str(path))


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


def of_model(model) -> MethodSpec:
    """The spec of a loaded model's method (``model.method``)."""
    return get(model.method)


def of_run(run_dir) -> MethodSpec:
    """The spec of a training run folder's method, ``config.json``'s ``method``."""
    conf = Path(run_dir) / "config.json"
    if not conf.is_file():
        raise FileNotFoundError(f"{conf}: not a training run (no config.json)")
    try:
        name = json.loads(conf.read_text()).get("method")
    except (json.JSONDecodeError, AttributeError) as e:
        raise ValueError(f"{conf}: not a JSON object ({e})") from e
    if name is None:
        raise ValueError(f"{conf}: no \"method\"; a run's config names the method that "
                         f"trained it: add \"method\": \"NAME\" to it, NAME one of "
                         f"{', '.join(names())}")
    return get(name)


def all_presets() -> list[str]:
    """Every preset name of every method, in first-seen order."""
    seen = []
    for name in names():
        seen += [p for p in get(name).presets if p not in seen]
    return seen
