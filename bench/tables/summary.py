"""The results summary: one short table per paper table (each claim of the paper: our figure,
the paper's, the verdict) from the tables' JSON (``results/<key>.json``, written by
:func:`bench.tables.report.write_table`), and its copy into a README between two markers.

Examples:
    >>> text = summary(Path("results"))
    >>> copy_into(Path("README.md"), text)      # between <!-- results:begin/end -->
"""
from __future__ import annotations

import json
from pathlib import Path

from bench.tables import ablation, compare
from clrender.atomic import write_atomic

BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"
KEYS = ["title", "rows", "comparisons", "preset", "scene", "device", "date", "git_revision"]


def _ours(rec: dict) -> str:
    """Our difference: "+0.30 ± 0.10 [+0.05, +0.55]" (one seed: the value)."""
    if rec["std"] is None:
        return f"{rec['mean']:+.2f}"
    return f"{rec['mean']:+.2f} ± {rec['std']:.2f} [{rec['lo']:+.2f}, {rec['hi']:+.2f}]"


def run_line(data: dict) -> str:
    """Where and how a table was run: seeds, preset, scene, device, date, git revision."""
    n = len(data["rows"][0].get("seeds") or [None])
    return (f"{n} seed{'s' if n > 1 else ''}, `{data['preset']}` preset, {data['scene']} "
            f"scene, {data['device']}, {data['date']}, git {data['git_revision']}.")


def table_summary(data: dict) -> list[str]:
    """Markdown lines of one table's summary from its JSON ``data``."""
    lines = [f"### {data['title']}", "", run_line(data), ""]
    if not data["comparisons"]:
        return lines + ["No comparisons.", ""]
    lines += ["| Claim | ΔPSNR ours (dB, interval) | ΔPSNR paper | Speed-up ours | "
              "Speed-up paper | Verdict |", "|---|---|---|---|---|---|"]
    for r in data["comparisons"]:
        claim = f"{r['row']} − {r['against']}" + (
            f" (equivalent within ±{r['margin']:.2f} dB)" if r["claim"] == "equivalent" else "")
        lines.append("| " + " | ".join([
            claim, _ours(r), "" if r["paper"] is None else f"{r['paper']:+.2f}",
            compare.speedup_cell(r["speedup"]),
            "" if r["speedup_paper"] is None else f"{r['speedup_paper']:.2f}x",
            compare.verdict_cell(r)]) + " |")
    return lines + [""]


def load(out_dir: Path) -> list[tuple[str, dict]]:
    """(key, JSON) of every table with an ``OUT/<key>.json``, in
    :func:`bench.tables.ablation.list_tables` order."""
    found = []
    for key in map(ablation.file_stem, ablation.list_tables()):
        path = out_dir / f"{key}.json"
        if not path.is_file():
            continue
        try:
            data = json.loads(path.read_text())
        except ValueError as exc:
            raise ValueError(f"{path}: not a table written by bench.run ({exc})") from exc
        missing = sorted(set(KEYS) - set(data)) if isinstance(data, dict) else KEYS
        if missing or not data["rows"]:
            raise ValueError(f"{path}: not a table written by bench.run (no {missing or 'rows'}; "
                             "one written before its comparisons were recorded: run it again)")
        found.append((key, data))
    return found


def summary(out_dir: Path) -> str:
    """The summary of every table in ``out_dir`` (Markdown; a line saying so when none)."""
    tables = load(out_dir)
    lines = []
    for _, data in tables:
        lines += table_summary(data)
    if not tables:
        lines = [f"No table has been run into {out_dir}/ yet.", ""]
    return "\n".join(lines + [compare.NOTE, ""])


def copy_into(readme: Path, text: str) -> bool:
    """Replace what lies between :data:`BEGIN` and :data:`END` in ``readme`` with ``text``
    (written atomically, only when it changes); returns whether it changed."""
    old = readme.read_text()
    if old.count(BEGIN) != 1 or old.count(END) != 1 or old.index(BEGIN) > old.index(END):
        raise ValueError(f"{readme}: expected one {BEGIN} line before one {END} line")
    head, rest = old.split(BEGIN)
    new = head + BEGIN + "\n" + text.strip("\n") + "\n" + END + rest.split(END)[1]
    if new != old:
        write_atomic(readme, new)
    return new != old
