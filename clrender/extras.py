"""Optional dependencies (pyproject.toml's extras): a job whose extra is missing says so in
one line.

The core (numpy, scipy, pyopencl, imageio, pillow, tqdm) loads and renders baked files;
each other job names the extra that installs what it imports.

Examples:
    >>> require("view", "`clrender view`")        # MissingExtra if viser is absent
    >>> extra_of("torch")
    'train'
"""
from __future__ import annotations

import importlib.util

# Each extra's packages as imported (module names), in the order they are checked; an
# extra that includes another (train includes eval) lists its packages too.
EXTRAS = {
    "video": ("imageio_ffmpeg",),
    "eval": ("skimage",),
    "train": ("torch", "skimage", "trimesh", "embreex", "fast_simplification"),
    "capture": ("pycolmap", "skimage", "imageio_ffmpeg"),
    "bench": ("torch", "skimage", "trimesh", "embreex", "fast_simplification", "matplotlib",
              "filelock"),
    "view": ("viser",),
    "cluster": ("ray",),
}
# The extra that brings a module (the first extra listing it: the smallest job).
_BY_MODULE = {}
for _extra, _modules in EXTRAS.items():
    for _module in _modules:
        _BY_MODULE.setdefault(_module, _extra)


class MissingExtra(ValueError):
    """A command needs an extra that is not installed (the message says which)."""


def message(module: str, extra: str, what: str) -> str:
    """The one line that says ``what`` needs ``module`` from ``extra``."""
    return (f"{what} needs {module!r}, which is not installed: "
            f"pip install 'clrender[{extra}]'")


def require(extra: str, what: str, modules: tuple[str, ...] | None = None) -> None:
    """Raise :class:`MissingExtra` unless every module of ``extra`` (or ``modules`` of it)
    can be imported; ``what`` is the command or option that needs them."""
    for module in EXTRAS[extra] if modules is None else modules:
        if importlib.util.find_spec(module) is None:
            raise MissingExtra(message(module, extra, what))


def extra_of(module: str) -> str | None:
    """The extra that installs top-level module ``module``, None for any other module."""
    return _BY_MODULE.get(module.partition(".")[0])


def missing(exc: ModuleNotFoundError, what: str) -> MissingExtra | None:
    """``exc`` (an import that failed) as a :class:`MissingExtra` naming its extra, None
    where the module belongs to no extra (a broken install, not a missing job)."""
    extra = extra_of(exc.name or "")
    return None if extra is None else MissingExtra(message(exc.name, extra, what))
