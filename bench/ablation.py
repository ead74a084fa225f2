"""Ablation table specs: ``ablations/<method>/<table>.toml`` loaded into dataclasses.

A table names its method (rows may override it); each row names free-form ``model``
options (what is trained: NGP-RT ``variant``, ``L``; NDRF ``thresholds``, ``teacher``, ...)
and ``render`` options (NGP-RT ``use_G``), checked by the method's plug-in.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from clrender import methods

ABLATIONS_DIR = Path(__file__).resolve().parent.parent / "ablations"


@dataclass(frozen=True)
class Row:
    """One row of a table: the model it needs and how it is rendered."""

    name: str
    method: str
    model: dict
    render: dict
    paper: dict = field(default_factory=dict)
    baseline: str | None = None     # name of the row this row's speed-up is measured against


@dataclass(frozen=True)
class Table:
    """A paper table to reproduce (one TOML file under ablations/<method>/)."""

    key: str
    title: str
    paper_source: str
    scene: str
    preset: str
    paper_columns: tuple[str, ...]
    rows: tuple[Row, ...]
    show_stages: bool = False       # a column with the per-stage times (NDRF tables)
    timing_sizes: tuple[int, ...] = ()   # frame widths also timed (test cameras scaled)


def _paths() -> dict[str, Path]:
    return {p.stem: p for p in sorted(ABLATIONS_DIR.glob("*/*.toml"))}


def list_tables() -> list[str]:
    """Names of the tables under ablations/, sorted."""
    return sorted(_paths())


def _row(spec: dict, i: int, r: dict, path: Path) -> Row:
    if not isinstance(r.get("name"), str):
        raise ValueError(f"{path}: row {i} has no name")
    method = r.get("method", spec.get("method"))
    if method not in methods.names():
        raise ValueError(f"{path}: row {i} names method {method!r}; methods: {methods.names()}")
    plugin = methods.get(method)
    model, render = dict(r.get("model", {})), dict(r.get("render", {}))
    try:
        plugin.check_model_options(model)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: row {i} ({r.get('name')!r}): {exc}") from exc
    allowed = plugin.Renderer.RENDER_OPTIONS
    bad = {k: v for k, v in render.items() if not isinstance(v, allowed.get(k, ()))}
    if bad:
        raise ValueError(f"{path}: row {i}: render options {sorted(bad)} are not among "
                         f"{ {k: t.__name__ for k, t in allowed.items()} }")
    unknown = set(r.get("paper", {})) - set(spec["paper_columns"])
    if unknown:
        raise ValueError(f"{path}: row {i} has paper figures for unknown columns {sorted(unknown)}")
    return Row(name=r["name"], method=method, model=model, render=render,
               paper=dict(r.get("paper", {})), baseline=r.get("baseline", spec.get("baseline")))


def load_table(key: str) -> Table:
    """Parse and check the table ``key`` (``ablations/*/<key>.toml``)."""
    path = _paths().get(key)
    if path is None:
        raise ValueError(f"unknown table {key!r}; tables: {', '.join(list_tables())}")
    try:
        spec = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: malformed TOML: {exc}") from exc
    missing = {"title", "paper_source", "scene", "preset", "paper_columns", "rows"} - set(spec)
    if missing:
        raise ValueError(f"{path}: missing keys {sorted(missing)}")
    rows = [_row(spec, i, r, path) for i, r in enumerate(spec["rows"])]
    names = {r.name for r in rows}
    for r in rows:
        if r.baseline is not None and r.baseline not in names:
            raise ValueError(f"{path}: row {r.name!r} has unknown baseline {r.baseline!r}")
    return Table(key=key, title=spec["title"], paper_source=spec["paper_source"],
                 scene=spec["scene"], preset=spec["preset"],
                 paper_columns=tuple(spec["paper_columns"]), rows=tuple(rows),
                 show_stages=bool(spec.get("show_stages", False)),
                 timing_sizes=tuple(int(w) for w in spec.get("timing_sizes", ())))
