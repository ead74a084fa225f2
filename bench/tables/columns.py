"""The columns a table may show (its ``paper_columns`` and the statistics beside them): how
to read each from a :class:`bench.tables.result.RowResult` and how to format it.

A column is one of :data:`CORE`, a statistic a row's method declares
(``Renderer.SCALAR_STATS``, with its format) or a stage time ``"<Stage> (ms)"`` (the
renderer's ``ms_<stage>``, e.g. ``Intersect (ms)``).
"""
from __future__ import annotations

import re
from typing import Callable

from clrender import methods

CORE: dict[str, tuple[Callable, str]] = {
    "PSNR": (lambda m: m.psnr, "{:.2f}"),
    "SSIM": (lambda m: m.ssim, "{:.3f}"),
    "LPIPS": (lambda m: m.lpips, "{:.3f}"),
    "Time (ms)": (lambda m: m.time["median"], "{:.1f}"),
    "FPS": (lambda m: 1000.0 / m.time["median"], "{:.1f}"),
}
STAGE = re.compile(r"^(?P<stage>\w+) \(ms\)$")


def stats_of(method_names) -> dict:
    """{column: :class:`clrender.contract.Stat`} the methods declare, first declaration kept."""
    out = {}
    for name in dict.fromkeys(method_names):
        for col, stat in methods.get(name).renderer.SCALAR_STATS.items():
            out.setdefault(col, stat)
    return out


def column(col: str, method_names) -> tuple[Callable, str]:
    """(getter of a RowResult, format) of column ``col`` in a table of rows of
    ``method_names``; the getter gives None where a row has no value."""
    if col in CORE:
        return CORE[col]
    stats = stats_of(method_names)
    if col in stats:
        return (lambda m: m.stats.get(col)), stats[col].fmt
    stage = STAGE.match(col)
    if stage:
        return (lambda m: m.stages.get(stage["stage"].lower())), "{:.1f}"
    raise ValueError(f"column {col!r} is none of {', '.join(CORE)}, a statistic of "
                     f"{', '.join(dict.fromkeys(method_names))} ({', '.join(stats) or 'none'}) "
                     "or a stage time '<Stage> (ms)'")
