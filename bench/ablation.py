"""Ablation table specs: `ablations/<table>.toml` loaded into dataclasses."""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from clrender.ngprt.config import VARIANTS

ABLATIONS_DIR = Path(__file__).resolve().parent.parent / "ablations"


@dataclass(frozen=True)
class Row:
    """One row of a table: the model it needs and how it is rendered."""

    name: str
    variant: str
    L: int
    use_G: bool
    paper: dict = field(default_factory=dict)
    baseline: str | None = None     # name of the row this row's speed-up is measured against


@dataclass(frozen=True)
class Table:
    """A paper table to reproduce (one TOML file in ablations/)."""

    key: str
    title: str
    paper_source: str
    scene: str
    preset: str
    paper_columns: tuple[str, ...]
    rows: tuple[Row, ...]


def list_tables() -> list[str]:
    """Names of the tables in ablations/, sorted."""
    return sorted(p.stem for p in ABLATIONS_DIR.glob("*.toml"))


def load_table(key: str) -> Table:
    """Parse and check ``ablations/<key>.toml``."""
    path = ABLATIONS_DIR / f"{key}.toml"
    if not path.is_file():
        raise ValueError(f"unknown table {key!r}; tables: {', '.join(list_tables())}")
    try:
        spec = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: malformed TOML: {exc}") from exc
    missing = {"title", "paper_source", "scene", "preset", "paper_columns", "rows"} - set(spec)
    if missing:
        raise ValueError(f"{path}: missing keys {sorted(missing)}")
    rows = []
    for i, r in enumerate(spec["rows"]):
        if r.get("variant") not in VARIANTS or not isinstance(r.get("L"), int):
            raise ValueError(f"{path}: row {i} needs variant in {VARIANTS} and an integer L")
        unknown = set(r.get("paper", {})) - set(spec["paper_columns"])
        if unknown:
            raise ValueError(f"{path}: row {i} has paper figures for unknown columns {sorted(unknown)}")
        rows.append(Row(name=r["name"], variant=r["variant"], L=r["L"],
                        use_G=bool(r.get("use_G", True)), paper=dict(r.get("paper", {})),
                        baseline=r.get("baseline", spec.get("baseline"))))
    names = {r.name for r in rows}
    for r in rows:
        if r.baseline is not None and r.baseline not in names:
            raise ValueError(f"{path}: row {r.name!r} has unknown baseline {r.baseline!r}")
    return Table(key=key, title=spec["title"], paper_source=spec["paper_source"],
                 scene=spec["scene"], preset=spec["preset"],
                 paper_columns=tuple(spec["paper_columns"]), rows=tuple(rows))
