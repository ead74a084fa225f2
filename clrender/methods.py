"""The method registry: a method's name and baked format -> the module that plugs it in.

The shell (``clrender.load``/``Renderer``/``render``, evaluation, video, the CLI and the
benchmark harness) reaches a method only through here. A method's plug-in module provides:

    FORMAT                      the baked manifest's ``format``
    PRESETS                     preset names (the CLI choices derive from them)
    load_baked(path)            -> a validated model with ``.method`` and ``.config.scene``
    Renderer(model, device=None, **options)
        .render(camera, background=None, stats=False) -> dict: ``rgb`` (H, W, 3) float32,
            ``ms`` (the frame's time, ms), ``ms_<stage>`` per stage; with stats=True also
            the method's per-pixel statistics
        SCALAR_STATS            {table column: per-pixel stat averaged over pixels}
        RENDER_OPTIONS          {option: type} accepted by the constructor
    add_train_arguments(parser), train_from_args(args) -> run folder
    bake_run(run_dir, out_path) -> path
    model_spec(preset, **options) -> dict, train_for_bench(data, out, preset, seed,
        torch_device, teacher, downscale, **options) -> run folder   (the benchmark's
        model cache)

Examples:
    >>> from clrender import methods
    >>> methods.get("ngprt").PRESETS
    ('tiny', 'cpu', 'paper')
    >>> model = methods.load("model.npz")          # whatever method baked it
"""
from __future__ import annotations

import importlib
import json
from pathlib import Path
from types import ModuleType

from . import bakedfile

# name -> (baked format, plug-in module). The only place the shell names a method.
METHODS = {
    "ngprt": ("clrender-ngprt", "clrender.ngprt.method"),
    "ndrf": ("clrender-ndrf", "clrender.ndrf.method"),
}
DEFAULT = "ngprt"


def names() -> list[str]:
    return list(METHODS)


def get(name: str) -> ModuleType:
    """The plug-in module of method ``name``."""
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; methods: {', '.join(METHODS)}")
    return importlib.import_module(METHODS[name][1])


def for_format(fmt: str, where: str = "model") -> ModuleType:
    """The plug-in module of the method whose baked files have manifest format ``fmt``."""
    for name, (f, _) in METHODS.items():
        if f == fmt:
            return get(name)
    known = ", ".join(f for f, _ in METHODS.values())
    raise bakedfile.BakedFormatError(f"{where}: format is {fmt!r}, expected one of {known}")


def load(path):
    """Load and validate a baked file of any method (its manifest names the format)."""
    return for_format(bakedfile.peek_format(path), str(path)).load_baked(path)


def of_model(model) -> ModuleType:
    """The plug-in module of a loaded model (``model.method``)."""
    return get(model.method)


def of_run(run_dir) -> ModuleType:
    """The plug-in module of a training run folder (``config.json``'s ``method``)."""
    conf = Path(run_dir) / "config.json"
    if not conf.is_file():
        raise FileNotFoundError(f"{conf}: not a training run (no config.json)")
    try:
        name = json.loads(conf.read_text()).get("method", DEFAULT)
    except (json.JSONDecodeError, AttributeError) as e:
        raise ValueError(f"{conf}: not a JSON object ({e})") from e
    return get(name)


def all_presets() -> list[str]:
    """Every preset name of every method, in first-seen order."""
    seen = []
    for name in METHODS:
        seen += [p for p in get(name).PRESETS if p not in seen]
    return seen
