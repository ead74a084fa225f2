"""Optional dependencies (pyproject.toml's extras): a missing one named in one line.

Examples:
    >>> require("viser", "view", "`clrender view`")     # MissingExtra if viser is absent
"""
from __future__ import annotations

import importlib.util


class MissingExtra(ValueError):
    """A command needs an extra that is not installed (the message says which)."""


def require(module: str, extra: str, what: str) -> None:
    """Raise :class:`MissingExtra` unless ``module`` can be imported; ``extra`` is the
    pyproject extra that installs it, ``what`` the command or option that needs it."""
    if importlib.util.find_spec(module) is None:
        raise MissingExtra(f"{what} needs {module!r}, which is not installed: "
                           f"pip install 'clrender[{extra}]'")
