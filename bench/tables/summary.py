"""The results summary: one short table per paper table (each claim of the paper: our figure,
the paper's, the verdict) from the tables' JSON (``results/<key>.json`` or the committed
``docs/results/<key>.json``, written by :func:`bench.tables.report.write_table`), and its
copy into a README between two markers.

Examples:
    >>> text = summary(Path("results"))                     # results/README.md's
    >>> copy_into(Path("README.md"), readme_summary(Path("docs/results")))
"""
from __future__ import annotations

import json
from pathlib import Path

from bench.tables import ablation, command, compare, markdown
from clrender.atomic import write_atomic

BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"
KEYS = ["title", "rows", "comparisons", "preset", "scene", "device", "date", "git_revision",
        "argv"]


def _ours(rec: dict) -> str:
    """Our difference: "+0.30 ± 0.10 [+0.05, +0.55]" (one seed: the value)."""
    if rec["std"] is None:
        return f"{rec['mean']:+.2f}"
    return f"{rec['mean']:+.2f} ± {rec['std']:.2f} [{rec['lo']:+.2f}, {rec['hi']:+.2f}]"


def run_line(data: dict) -> str:
    """Where and how a table was run: seeds, preset, scene, device, its date and git
    revision (marked where made from uncommitted changes), then its ``bench.run``
    command."""
    n = len(data["rows"][0].get("seeds") or [None])
    line = (f"{n} seed{'s' if n > 1 else ''}, `{data['preset']}` preset, {data['scene']} "
            f"scene, {data['device']}, {data['date']}, {markdown.revision(data)}.")
    return line + f" `{command.lines(data)[-1]}`"


def _speedup(data: dict, rec: dict) -> str:
    """Our speed-up of a claim (at the size its verdict is judged at, where not the test
    size), then at each other size the row was timed at against this very row (its
    baseline) as interleaved pairs."""
    row = next(r for r in data["rows"] if r["row"] == rec["row"])
    at = (row.get("paired_at") or {}) if row.get("baseline") == rec["against"] else {}
    judged = rec.get("speed_size")
    return "; ".join([compare.speedup_cell(rec["speedup"]) + (f" at {judged}" if judged else "")]
                     + [f"{size}: {compare.speedup_cell(s)}" for size, s in at.items()
                        if s and size != judged])


def table_summary(data: dict) -> list[str]:
    """Markdown lines of one table's summary from its JSON ``data`` (a column of counts
    where a claim has some)."""
    lines = [f"### {markdown.title(data)}", "", run_line(data), ""]
    if not data["comparisons"]:
        return lines + ["No comparisons.", ""]
    counts = any(r.get("counts") for r in data["comparisons"])
    head = ["Claim", "ΔPSNR ours (dB, interval)", "ΔPSNR paper", "Speed-up ours",
            "Speed-up paper"] + (["Counts ours (paper): verdict"] if counts else []) + ["Verdict"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in data["comparisons"]:
        lines.append("| " + " | ".join([
            _claim(r), _ours(r), "" if r["paper"] is None else f"{r['paper']:+.2f}",
            _speedup(data, r),
            "" if r["speedup_paper"] is None else f"{r['speedup_paper']:.2f}x"]
            + ([compare.counts_cell(r)] if counts else []) + [compare.verdict_cell(r)]) + " |")
    return lines + [""]


def readme_summary(out_dir: Path) -> str:
    """The README's summary: one Markdown table of every claim of every table in
    ``out_dir``, each table named on its first claim (no dates, commands or counts: the
    results page holds them)."""
    head = ["Table", "Claim", "ΔPSNR ours (dB, interval)", "ΔPSNR paper", "Speed-up ours",
            "Speed-up paper", "Verdict"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    tables = load(out_dir)
    for _, data in tables:
        for i, r in enumerate(data["comparisons"]):
            lines.append("| " + " | ".join([
                _named(data) if i == 0 else "", _claim(r), _ours(r),
                "" if r["paper"] is None else f"{r['paper']:+.2f}", _speedup(data, r),
                "" if r["speedup_paper"] is None else f"{r['speedup_paper']:.2f}x",
                compare.verdict_cell(r)]) + " |")
    if not tables:
        return f"No table has been run into {out_dir}/ yet.\n"
    return "\n".join(lines) + "\n"


def _named(data: dict) -> str:
    """A table's title, marked where its run was made from uncommitted changes."""
    return markdown.title(data) + (" (**uncommitted changes**)" if command.is_dirty(data)
                                   else "")


def _claim(r: dict) -> str:
    return f"{r['row']} − {r['against']}" + (
        f" (equivalent within ±{r['margin']:.2f} dB)" if r["claim"] == "equivalent" else "")


def read(path: Path) -> dict:
    """A table's JSON, checked for what the summary and the results page read; a
    ValueError naming ``path`` where it is not one."""
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"{path}: not a table written by bench.run ({exc})") from exc
    missing = sorted(set(KEYS) - set(data)) if isinstance(data, dict) else KEYS
    if missing or not data["rows"]:
        raise ValueError(f"{path}: not a table written by bench.run (no {missing or 'rows'}; "
                         "one written before its comparisons were recorded: run it again)")
    return data


def load(out_dir: Path) -> list[tuple[str, dict]]:
    """(key, JSON) of every table with an ``OUT/<key>.json``, in
    :func:`bench.tables.ablation.list_tables` order."""
    found = []
    for key in map(ablation.file_stem, ablation.list_tables()):
        path = out_dir / f"{key}.json"
        if path.is_file():
            found.append((key, read(path)))
    return found


def summary(out_dir: Path) -> str:
    """The summary of every table in ``out_dir`` (Markdown; a line saying so when none):
    each run's conditions, its claims, then the verdicts' rule
    (:data:`bench.tables.compare.NOTE`)."""
    tables = load(out_dir)
    lines = []
    for _, data in tables:
        lines += table_summary(data)
    if not tables:
        lines = [f"No table has been run into {out_dir}/ yet.", ""]
    return "\n".join(lines + [compare.NOTE, ""])


def replace_between(old: str, begin: str, end: str, text: str, where) -> str:
    """``old`` with what lies between its one ``begin`` line and its one ``end`` line
    replaced by ``text``; ``where`` names the file in the error where the lines are not so."""
    if old.count(begin) != 1 or old.count(end) != 1 or old.index(begin) > old.index(end):
        raise ValueError(f"{where}: expected one {begin} line before one {end} line")
    head, rest = old.split(begin)
    return head + begin + "\n" + text.strip("\n") + "\n" + end + rest.split(end)[1]


def copy_into(readme: Path, text: str) -> bool:
    """Replace what lies between :data:`BEGIN` and :data:`END` in ``readme`` with ``text``
    (written atomically, only when it changes); returns whether it changed."""
    old = readme.read_text()
    new = replace_between(old, BEGIN, END, text, readme)
    if new != old:
        write_atomic(readme, new)
    return new != old
