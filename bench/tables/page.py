"""The results page: each committed table run (``docs/results/<name>.json``, the JSON
:func:`bench.tables.report.write_table` wrote) as a generated block of a Markdown page,
between ``<!-- results:<name> begin -->`` and ``<!-- results:<name> end -->`` lines
(:func:`bench.tables.markdown.block`: the run's title and scene, its command, conditions,
rows beside the paper's, and the paper's claims). Text outside the blocks is the page's own
and stays as it is.

Examples:
    >>> text = filled(Path("docs/results.md"), Path("docs/results"))
"""
from __future__ import annotations

import re
from pathlib import Path

from bench.tables import markdown, summary

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


def _block_of(path: Path, data: dict) -> str:
    try:
        return markdown.block(data)
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
