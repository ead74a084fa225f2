"""The results page: each committed table run (``docs/results/<name>.json``, the JSON
:func:`bench.tables.report.write_table` wrote) as a generated block of a Markdown page,
between ``<!-- results:<name> begin -->`` and ``<!-- results:<name> end -->`` lines: the
run's conditions, its rows beside the paper's, and the paper's claims. Text outside the
blocks is the page's own and stays as it is.

Examples:
    >>> text = filled(Path("docs/results.md"), Path("docs/results"))
"""
from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

from bench.tables import columns, compare, summary

MARK = re.compile(r"<!-- results:(?P<name>[\w.-]+) (?P<edge>begin|end) -->")
KEYS = summary.KEYS + ["resolution", "paper_source"]


def begin(name: str) -> str:
    return f"<!-- results:{name} begin -->"


def end(name: str) -> str:
    return f"<!-- results:{name} end -->"


def load(folder: Path) -> dict[str, dict]:
    """{name: JSON} of every ``folder/<name>.json``, by name; a ValueError naming the file
    where one is not a table written by ``bench.run``."""
    runs = {}
    for path in sorted(folder.glob("*.json")):
        data = summary.read(path)
        missing = [k for k in KEYS if k not in data]
        if missing:
            raise ValueError(f"{path}: not a table written by bench.run (no {missing})")
        runs[path.stem] = data
    return runs


def _seeds(seed_list: list) -> str:
    n = len(seed_list)
    return f"{n} seed{'s' if n != 1 else ''} ({', '.join(map(str, seed_list))})"


def conditions(data: dict) -> str:
    """The run's conditions: seeds, preset, scene, test size, device, date, git revision,
    wall time (``wall_s``: the table's share of its ``bench.run``), the code that trained
    its models, the paper's source."""
    wall = data.get("wall_s")
    code = ", ".join(f"{m} {fp}" for m, fp in (data.get("code") or {}).items())
    return (f"Conditions: {_seeds(data['rows'][0]['seeds'])}, `{data['preset']}` preset, "
            f"{data['scene']} scene, test views at {data['resolution']}, {data['device']}; "
            f"{data['date']}, git {data['git_revision']}, wall time "
            + ("not recorded" if wall is None else f"{wall / 60:.1f} min")
            + (f"; models trained by code {code}" if code else "")
            + f". Paper: {data['paper_source']}.")


def _measured(rec: dict, stats) -> SimpleNamespace:
    """A row's JSON record as the fields :mod:`bench.tables.columns` reads."""
    return SimpleNamespace(psnr=rec["PSNR"], ssim=rec["SSIM"], lpips=rec.get("LPIPS"),
                           time=rec["time_ms"], stages=rec["stages_ms"],
                           stats={c: rec.get(c) for c in stats})


def _cell(rec: dict, col: str, methods: list[str]) -> str:
    """Our value of ``col`` ("mean ± std" over several seeds)."""
    get, fmt = columns.column(col, methods)
    value = get(_measured(rec, columns.stats_of(methods)))
    if value is None:
        return "n/a"
    std = ((rec.get("spread") or {}).get(col) or {}).get("std")
    return fmt.format(value) + ("" if std is None else f" ± {fmt.format(std)}")


def _image(check: dict | None) -> str:
    if check is None:
        return ""
    return "identical" if check["identical"] is True else f"differs (max {check['max_diff']:.2g})"


def rows_table(data: dict) -> list[str]:
    """The rows as Markdown lines: each column of the paper ours beside the paper's, the
    speed-up against the row's baseline (at the test size and each paired size), the image
    against the baseline's where compared, the training minutes."""
    rows, methods = data["rows"], [r["method"] for r in data["rows"]]
    paper_cols = list(dict.fromkeys(c for r in rows for c in r["paper"]))
    sizes = list(dict.fromkeys(s for r in rows for s in r.get("paired_at") or {}))
    baselines, images = any(r["baseline"] for r in rows), any(r["same_image"] for r in rows)
    head = ["Row"] + [h for c in paper_cols for h in (c, f"{c} (paper)")]
    head += (["Speed-up", "Speed-up (paper)"] + [f"Speed-up at {s}" for s in sizes]
             if baselines else [])
    head += (["Image vs baseline"] if images else []) + ["Train (min)"]
    paper_time = {r["row"]: r["paper"].get("Time (ms)") for r in rows}
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["row"]]
        for col in paper_cols:
            fmt = columns.column(col, methods)[1]
            cells += [_cell(r, col, methods),
                      "n/a" if r["paper"].get(col) is None else fmt.format(r["paper"][col])]
        if baselines:
            base, mine = paper_time.get(r["baseline"]), paper_time[r["row"]]
            cells += [compare.speedup_cell(None if r["speedup"] is None else
                                           r["paired_speedup"] or {"ratio": r["speedup"]}),
                      "" if base is None or mine is None else f"{base / mine:.2f}x"]
            cells += [compare.speedup_cell((r.get("paired_at") or {}).get(s)) for s in sizes]
        cells += ([_image(r["same_image"])] if images else []) + [f"{r['train_minutes']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def block(data: dict) -> str:
    """One run's generated block: :func:`conditions`, :func:`rows_table`, what the time
    covers, the paper's claims (:func:`bench.tables.compare.claims_table`)."""
    time = data["rows"][0]["time_ms"]
    note = data["rows"][0]["per_seed"][0]["time_note"]
    lines = [conditions(data), "", *rows_table(data), "",
             f"Time (ms): {note}, median of {time['n']} timed frames; speed-ups with an "
             "interval from interleaved pairs against the row's baseline."]
    if data["comparisons"]:
        lines += ["", *compare.claims_table(data["comparisons"])]
    return "\n".join(lines)


def _block_of(path: Path, data: dict) -> str:
    try:
        return block(data)
    except (KeyError, TypeError, IndexError, AttributeError, ValueError) as exc:
        raise ValueError(f"{path}: not a table written by bench.run "
                         f"({type(exc).__name__}: {exc})") from exc


def fill(text: str, blocks: dict[str, str], where, folder: Path) -> str:
    """``text`` (the page ``where``) with each marked block replaced by ``blocks[name]``;
    a ValueError where a block has no run in ``folder`` or a run has no block."""
    marks = [(m["name"], m["edge"]) for m in MARK.finditer(text)]
    named = {n for n, _ in marks}
    unmatched = sorted(n for n in named if (n, "begin") not in marks or (n, "end") not in marks)
    if unmatched:
        raise ValueError(f"{where}: {', '.join(unmatched)}: expected a begin and an end line")
    if named - set(blocks):
        raise ValueError(f"{where}: blocks {', '.join(sorted(named - set(blocks)))} have no "
                         f"{folder}/<name>.json")
    if set(blocks) - named:
        raise ValueError(", ".join(f"{folder / n}.json" for n in sorted(set(blocks) - named))
                         + f": no block in {where} (add {begin('<name>')} and {end('<name>')} "
                         "lines where it belongs)")
    for name, text_block in blocks.items():
        text = summary.replace_between(text, begin(name), end(name), text_block, where)
    return text


def filled(page: Path, folder: Path) -> str:
    """``page``'s text with every block generated from ``folder``'s runs (nothing written)."""
    blocks = {name: _block_of(folder / f"{name}.json", data)
              for name, data in load(folder).items()}
    return fill(page.read_text(), blocks, page, folder)
