"""Ablation table specs: the TOML files of each method's ``ablations`` folder (shipped
with its plug-in: ``clrender/ngprt/ablations/table4.toml``) loaded into dataclasses.

Tables are keyed by (method, name), ``name`` the file's stem; a name two methods use is
asked for as ``method/name``. A table names its method (rows may override it); each row
names ``model`` options (what is trained: the row's method's ``train_options``, NGP-RT
``variant``, ``L``; NDRF ``thresholds``, ``teacher`` (a table of the teacher's), ...),
``render`` options (its renderer's ``RENDER_OPTIONS``: NGP-RT ``use_G``) and ``bake``
options (its ``bake_options``), each checked by :func:`clrender.contract.check_options`.

A row's ``baseline`` (or the table's) is the row its speed-up is measured against. The
paper's claims are the table's comparisons, each a row against another (PSNR difference
row minus other, the paper's the same way). A row declares its own with ``compare``, a list
of ``{ against = "ROW" }`` (a difference: :func:`bench.tables.seeds.verdict`) or ``{ against =
"ROW", claim = "equivalent", margin = 0.3 }`` (equivalent within ±margin dB:
:func:`bench.tables.seeds.equivalence`). A table where no row declares ``compare`` compares each
row that has a baseline with it; one where any row does has exactly the declared ones.
"""
from __future__ import annotations

import sys
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from bench.tables import columns
from clrender import methods
from clrender.contract import check_options


@dataclass(frozen=True)
class Row:
    """One row of a table: the model it needs and how it is rendered."""

    name: str
    method: str
    model: dict
    render: dict
    paper: dict = field(default_factory=dict)
    baseline: str | None = None     # name of the row this row's speed-up is measured against
    bake: dict = field(default_factory=dict)    # the method's bake_options for this row
    same_image: bool | None = None  # must render its baseline's image (None: the table's)


CLAIMS = ("difference", "equivalent")


@dataclass(frozen=True)
class Comparison:
    """A claim of the paper about two rows: ``row`` against ``against`` (PSNR difference row
    minus against). ``claim``: "difference" (the paper's difference, by its sign) or
    "equivalent" (within ±``margin`` dB)."""

    row: str
    against: str
    claim: str = "difference"
    margin: float | None = None


@dataclass(frozen=True)
class Table:
    """A paper table to reproduce (one TOML file of a method's ``ablations`` folder)."""

    key: str                        # a name, or method/name (list_tables)
    method: str
    title: str
    paper_source: str
    scene: str
    preset: str
    paper_columns: tuple[str, ...]
    rows: tuple[Row, ...]
    show_stages: bool = False       # a column with the per-stage times (NDRF tables)
    timing_sizes: tuple[int, ...] = ()   # frame widths also timed (test cameras scaled)
    comparisons: tuple[Comparison, ...] = ()
    # Rows with a baseline are timed against it as interleaved pairs (bench.tables.measure
    # .measure_pair) on the renderer's ms_<paired_stage> (None: the frame), at the test
    # size and at paired_sizes ("WxH"); same_image: a row must render its baseline's image
    # (unless the row says otherwise: Table.row_same_image); verdict_size: the one of
    # paired_sizes the paper timed at, whose pairs judge its speed claims (None: the test
    # size).
    paired_stage: str | None = None
    paired_sizes: tuple[str, ...] = ()
    same_image: bool = False
    verdict_size: str | None = None

    @property
    def stem(self) -> str:
        """The name of the table's result files (``results/<stem>.md``)."""
        return file_stem(self.key)

    def row_same_image(self, row: Row) -> bool:
        """Whether ``row`` must render its baseline's image: the row's ``same_image``, else
        the table's."""
        return self.same_image if row.same_image is None else row.same_image


def file_stem(key: str) -> str:
    """The result files' name of the table ``key`` (``method/name`` -> ``method-name``)."""
    return key.replace("/", "-")


def _paths() -> dict[tuple[str, str], Path]:
    """{(method, name): TOML path} over every registered method's ablations folder."""
    found: dict[tuple[str, str], Path] = {}
    for method, bench in methods.benched().items():
        folder = bench.ablations
        for path in sorted(folder.glob("*.toml")) if folder is not None else ():
            found[(method, path.stem)] = path
    return found


def _keys(paths: dict) -> dict[tuple[str, str], str]:
    """{(method, name): key}: the bare name where one method has it, else ``method/name``
    (its files ``method-name.*``). Two tables whose files would collide are refused."""
    counts = Counter(name for _, name in paths)
    keys = {(m, n): n if counts[n] == 1 else f"{m}/{n}" for m, n in paths}
    files = Counter(k.replace("/", "-") for k in keys.values())
    clash = sorted(f for f, c in files.items() if c > 1)
    if clash:
        raise ValueError(f"tables would write the same results {clash}: "
                         + ", ".join(str(paths[mn]) for mn, k in keys.items()
                                     if k.replace("/", "-") in clash))
    return keys


def list_tables() -> list[str]:
    """The tables' keys, sorted: a bare name, or ``method/name`` where names collide."""
    return sorted(_keys(_paths()).values())


def check_model_options(method: str, options: dict) -> None:
    """Raise ValueError unless ``options`` are model options of ``method`` (its
    ``train_options``), the option its bench spec's ``teacher`` names a table of the
    teacher's model options (checked the same way)."""
    spec = methods.get(method)
    teacher = spec.bench and spec.bench.teacher
    own = dict(options)
    nested = own.pop(teacher.option, None) if teacher else None
    check_options(own, spec.train_options, "model options", method)
    if nested is not None:
        if not isinstance(nested, dict):
            raise ValueError(f"model option {teacher.option!r} takes a table of "
                             f"{teacher.method} model options, got {nested!r}")
        check_model_options(teacher.method, nested)


def _row(spec: dict, i: int, r: dict, path: Path) -> Row:
    if not isinstance(r.get("name"), str):
        raise ValueError(f"{path}: row {i} has no name")
    method = r.get("method", spec.get("method"))
    if method not in methods.names():
        raise ValueError(f"{path}: row {i} names method {method!r}; methods: {methods.names()}")
    plugin = methods.get(method)
    model, render, bake = (dict(r.get(kind, {})) for kind in ("model", "render", "bake"))
    try:
        check_model_options(method, model)
        check_options(render, plugin.renderer.RENDER_OPTIONS, "render options", method)
        check_options(bake, plugin.bake_options, "bake options", method)
    except ValueError as exc:
        raise ValueError(f"{path}: row {i} ({r.get('name')!r}): {exc}") from exc
    unknown = set(r.get("paper", {})) - set(spec["paper_columns"])
    if unknown:
        raise ValueError(f"{path}: row {i} has paper figures for unknown columns {sorted(unknown)}")
    return Row(name=r["name"], method=method, model=model, render=render,
               paper=dict(r.get("paper", {})), baseline=r.get("baseline", spec.get("baseline")),
               bake=bake, same_image=r.get("same_image"))


def _compare(r: dict, names: set, path: Path) -> list[Comparison]:
    """A row's declared comparisons (its ``compare`` list), checked."""
    where = f"{path}: row {r['name']!r}: compare"
    declared = r.get("compare", [])
    if not isinstance(declared, list) or not all(isinstance(c, dict) for c in declared):
        raise ValueError(f"{where} takes a list of tables ({{ against = \"ROW\" }}), "
                         f"got {declared!r}")
    out = []
    for c in declared:
        unknown = sorted(set(c) - {"against", "claim", "margin"})
        if unknown:
            raise ValueError(f"{where}: unknown keys {unknown}; expected against, claim, margin")
        against, claim, margin = c.get("against"), c.get("claim", "difference"), c.get("margin")
        if against not in names or against == r["name"]:
            raise ValueError(f"{where}: against {against!r} is not another row of the table")
        if claim not in CLAIMS:
            raise ValueError(f"{where}: claim {claim!r} is none of {list(CLAIMS)}")
        if (claim == "equivalent") != (margin is not None):
            raise ValueError(f"{where}: a margin (dB) is for claim \"equivalent\" and needed "
                             f"there, got claim {claim!r} and margin {margin!r}")
        if margin is not None and (isinstance(margin, bool) or not isinstance(margin, (int, float))
                                   or not margin > 0):
            raise ValueError(f"{where}: margin {margin!r} must be a number of dB > 0")
        out.append(Comparison(r["name"], against, claim,
                              None if margin is None else float(margin)))
    return out


def _comparisons(spec: dict, rows: list[Row], path: Path) -> tuple[Comparison, ...]:
    """The declared comparisons, or with none declared each row against its baseline."""
    names = {r.name for r in rows}
    declared = [c for r in spec["rows"] for c in _compare(r, names, path)]
    if declared:
        return tuple(declared)
    return tuple(Comparison(r.name, r.baseline) for r in rows
                 if r.baseline is not None and r.baseline != r.name)


def load_table(key: str) -> Table:
    """Parse and check the table ``key`` (a name, or ``method/name``; :func:`list_tables`)."""
    paths = _paths()
    keys = _keys(paths)
    found = [mn for mn, k in keys.items() if key in (k, "/".join(mn))]
    if not found:
        raise ValueError(f"unknown table {key!r}; tables: {', '.join(sorted(keys.values()))}")
    (method, _), path = found[0], paths[found[0]]
    key = keys[found[0]]
    try:
        spec = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: malformed TOML: {exc}") from exc
    missing = {"title", "paper_source", "scene", "preset", "paper_columns", "rows"} - set(spec)
    if missing:
        raise ValueError(f"{path}: missing keys {sorted(missing)}")
    if spec.setdefault("method", method) != method:
        raise ValueError(f"{path}: a table of method {method!r} names method "
                         f"{spec['method']!r}")
    rows = [_row(spec, i, r, path) for i, r in enumerate(spec["rows"])]
    for col in spec["paper_columns"]:
        try:
            columns.column(col, [r.method for r in rows])
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc
    names = {r.name for r in rows}
    for r in rows:
        if r.baseline is not None and r.baseline not in names:
            raise ValueError(f"{path}: row {r.name!r} has unknown baseline {r.baseline!r}")
    return Table(key=key, method=method, title=spec["title"], paper_source=spec["paper_source"],
                 scene=spec["scene"], preset=spec["preset"],
                 paper_columns=tuple(spec["paper_columns"]), rows=tuple(rows),
                 show_stages=bool(spec.get("show_stages", False)),
                 timing_sizes=tuple(int(w) for w in spec.get("timing_sizes", ())),
                 comparisons=_comparisons(spec, rows, path),
                 paired_stage=spec.get("paired_stage"),
                 paired_sizes=tuple(_sizes(spec.get("paired_sizes", ()), path)),
                 verdict_size=_verdict_size(spec, path),
                 same_image=bool(spec.get("same_image", False)))


def with_bake(table: Table, options: dict) -> Table:
    """``table`` with bake ``options`` (``{name: value}`` of its methods' ``bake_options``)
    on every row, over the rows' own, under the key ``KEY-name-value`` (so its results
    files stand beside the table's); ``table`` itself without options."""
    if not options:
        return table
    for method in {row.method for row in table.rows}:
        check_options(options, methods.get(method).bake_options, f"{table.key}: bake options",
                      method)
    rows = tuple(replace(row, bake={**row.bake, **options}) for row in table.rows)
    suffix = "-".join(f"{k}-{options[k]}" for k in sorted(options))
    return replace(table, key=f"{table.key}-{suffix}", rows=rows,
                   title=f"{table.title} ({', '.join(f'{k}={v}' for k, v in options.items())})")


def _verdict_size(spec: dict, path: Path) -> str | None:
    size = spec.get("verdict_size")
    if size is not None and size not in spec.get("paired_sizes", ()):
        raise ValueError(f"{path}: verdict_size {size!r} is not one of paired_sizes "
                         f"{spec.get('paired_sizes', [])}")
    return size


def _sizes(sizes, path: Path) -> list[str]:
    """The table's ``paired_sizes``, each "WxH" (:func:`bench.speed.sizes.parse_size`)."""
    from bench.speed.sizes import parse_size

    try:
        return [f"{w}x{h}" for w, h in map(parse_size, sizes)]
    except (ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: paired_sizes: {exc}") from exc
