"""The command that made a table's run, as a reader types it: ``bench.run``'s arguments
with their paths as :func:`bench.options.shown_path` records them (``argv`` in the run's
JSON), and for a public scene (``public_scene``) the lines that assemble its folder
(:func:`bench.tools.public_scenes.commands`).

Examples:
    >>> recorded(["table2", "--scene", str(Path.cwd() / "data/bonsai"), "--downscale", "2"])
    ['table2', '--scene', 'data/bonsai', '--downscale', '2']
    >>> lines({"argv": ["ndrf-table3", "--scene", "data/lego"], "public_scene": "lego"})[-1]
    'python -m bench.run ndrf-table3 --scene data/lego'
"""
from __future__ import annotations

import shlex

from bench.options import shown_path

PATHS = ("--scene", "--cache", "--out")
WHERE = ("--cache", "--out")        # where files go, not what is measured: not shown
DIRTY = "+dirty"                    # the end of a revision with uncommitted changes


def recorded(argv: list[str]) -> list[str]:
    """``argv`` with the folder of each of :data:`PATHS` (``--scene X`` or ``--scene=X``)
    by :func:`bench.options.shown_path`; a built-in scene's name unchanged."""
    from bench.modelcache.cache import BUILTIN_SCENES

    def shown(value: str) -> str:
        return value if value in BUILTIN_SCENES else shown_path(value)

    out, follows = [], False
    for arg in argv:
        name, eq, value = arg.partition("=")
        if follows:
            out.append(shown(arg))
        elif eq and name in PATHS:
            out.append(f"{name}={shown(value)}")
        else:
            out.append(arg)
        follows = not follows and arg in PATHS
    return out


def _shown_argv(argv: list[str]) -> list[str]:
    out, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in WHERE:
            skip = True
        elif arg.partition("=")[0] not in WHERE:
            out.append(arg)
    return out


def lines(data: dict) -> list[str]:
    """The shell lines that make the run ``data`` (a table's JSON): the public scene's
    assembly, then ``python -m bench.run ...`` without :data:`WHERE`'s options; a
    ValueError where the JSON records no ``argv``."""
    if not isinstance(data.get("argv"), list):
        raise ValueError("no argv: the command that made the run is not recorded")
    argv = _shown_argv(data["argv"])
    scene = next((a.partition("=")[2] or argv[i + 1] for i, a in enumerate(argv)
                  if a.partition("=")[0] == "--scene"), None)
    public = []
    if data.get("public_scene"):
        from bench.tools.public_scenes import commands

        public = commands(data["public_scene"], scene)
    return public + [("python -m bench.run " + shlex.join(argv)).rstrip()]


def is_dirty(data: dict) -> bool:
    """Whether the run was made from a tree with uncommitted changes."""
    return str(data.get("git_revision", "")).endswith(DIRTY)
