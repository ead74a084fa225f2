"""Write a measured table: its JSON, and from the JSON its Markdown
(:mod:`bench.tables.markdown`), CSV, plot and samples; and the index of every table
written to a folder (README.md)."""
from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from bench.tables import columns, compare, markdown, page, seeds, summary
from clrender.atomic import write_atomic


def slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


def _methods(table) -> list[str]:
    return [r.method for r in table.rows]


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
    """Seeds behind each row (1 for results not from :func:`bench.tables.seeds.aggregate`)."""
    return len(results[0].seeds or [None])


def _plot(table, results: list) -> bytes:
    """Time against PSNR, ours and the paper's side by side. Each row keeps one marker and
    colour in both panels and is named once in a shared legend below them (labels beside
    the points overlapped where rows share a time or a PSNR); markers are hollow and drawn
    larger first, so rows on the same point stay visible."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(table.rows)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    series = [("ours", [m.time["median"] for m in results], [m.psnr for m in results]),
              ("paper", [r.paper.get("Time (ms)") for r in table.rows],
               [r.paper.get("PSNR") for r in table.rows])]
    markers, colours = "osD^vPX*hp<>", plt.get_cmap("tab20").colors
    handles = {}
    for ax, (who, xs, ys) in zip(axes, series):
        for i, (row, x, y) in enumerate(zip(table.rows, xs, ys)):
            if x is not None and y is not None:
                handles[row.name] = ax.scatter(
                    x, y, s=110 - 60 * i / max(n - 1, 1), marker=markers[i % len(markers)],
                    facecolors="none", edgecolors=colours[i % len(colours)], linewidths=1.5,
                    label=row.name)
        ax.set_xlabel("time per frame (ms)")
        ax.set_ylabel("PSNR (dB)")
        ax.set_title(f"{table.key}: {who}")
        ax.grid(alpha=0.3)
    names = [r.name for r in table.rows if r.name in handles]
    fig.tight_layout()
    fig.legend([handles[k] for k in names], names, loc="upper center", ncol=3, fontsize=8,
               frameon=False, bbox_to_anchor=(0.5, 0.0))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
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


def _record(table, row, m, stats: list[str], speedup, sample: str) -> dict:
    """The JSON record of one row."""
    return {"row": row.name, "method": row.method, **row.model, **row.render, **row.bake,
            "PSNR": m.psnr, "SSIM": m.ssim, "LPIPS": m.lpips, "time_ms": m.time,
            "wall_ms": m.wall_ms, "stages_ms": m.stages, "FPS": 1000.0 / m.time["median"],
            "time_ms_at_width": {str(w): t for w, t in m.time_at.items()},
            **{c: m.stats.get(c) for c in stats}, "size_MB": m.size_MB,
            "train_minutes": m.train_minutes, "model_key": m.model_key, "time_note": m.time_note,
            "baseline": row.baseline, "speedup": speedup, "sample": sample, "paper": row.paper,
            "seeds": m.seeds,
            "per_seed": None if m.per_seed is None else [p.to_json() for p in m.per_seed],
            "spread": _spreads(table, m, stats),
            "paired_speedup": m.paired_speedup, "paired_at": m.paired_at,
            "paired_with": m.paired_with,
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
    """Write TABLE.json/.md/.csv/.png and one sample render per row; returns the Markdown
    (:func:`bench.tables.markdown.block` of the JSON).

    ``results``: one :class:`bench.tables.result.RowResult` per row (with its model's
    ``train_minutes`` and ``model_key``), or over several seeds one
    :func:`bench.tables.seeds.aggregate` result per row (JSON rows then carry ``seeds``,
    ``per_seed``, ``spread``; the CSV ``PSNR_std`` and ``SSIM_std``). ``meta``: the run's
    conditions (:func:`bench.options.run_meta`, ``argv``, ``preset``, ``scene``, ...). The
    JSON's ``comparisons``: :func:`bench.tables.compare.measure`.
    """
    n, stats = _n_seeds(results), _stat_columns(table, results)
    records = []
    for row, m, ox in zip(table.rows, results, speedups(table, results)):
        sample = out_dir / table.stem / f"{slug(row.name)}.png"
        write_atomic(sample, iio.imwrite("<bytes>", (np.clip(m.sample, 0, 1) * 255 + 0.5)
                                         .astype(np.uint8), extension=".png"))
        records.append(_record(table, row, m, stats, ox, str(sample.relative_to(out_dir))))
    data = {**meta, "table": table.key, "title": table.title,
            "paper_source": table.paper_source, "columns": list(table.paper_columns),
            "rows": records, "comparisons": compare.measure(table, results)}
    md = markdown.block(data)
    write_atomic(out_dir / f"{table.stem}.json", json.dumps(data, indent=2))
    write_atomic(out_dir / f"{table.stem}.md", md + "\n")
    write_atomic(out_dir / f"{table.stem}.csv", _csv(table, records, stats, n))
    write_atomic(out_dir / f"{table.stem}.png", _plot(table, results))
    return md


def write_index(out_dir: Path) -> None:
    """OUT/README.md: the summary of the paper's claims (:func:`bench.tables.summary.summary`),
    then every table with a ``OUT/<key>.json`` (in :func:`bench.tables.ablation.list_tables`
    order), each with the date, git revision, device, preset and scene of its own run, the
    code fingerprint of each method that trained its models, a link, its plot and one
    sample render per row."""
    lines = ["# clrender benchmark results", "", "## Summary", "", summary.summary(out_dir),
             "## Tables", ""]
    for key, data in summary.load(out_dir):
        seed_list = data["rows"][0].get("seeds") or []
        code = ", ".join(f"{m} {fp}" for m, fp in data.get("code", {}).items())
        run = (f"{data['date']}, {markdown.revision(data)}, {data['device']}, "
               f"`{data['preset']}` preset, {data['scene']} scene"
               + (f", {len(seed_list)} seeds" if len(seed_list) > 1 else "")
               + (f"; trained by code {code} (bench/modelcache/fingerprint.py)" if code else "") + ".")
        rows = [(r["row"], r["sample"]) for r in data["rows"]]
        lines += [f"### [{markdown.title(data)}]({key}.md)", "", run, "",
                  f"![quality vs time]({key}.png)", "",
                  " ".join(f"![{name}]({sample})" for name, sample in rows),
                  "", " | ".join(name for name, _ in rows), ""]
    write_atomic(out_dir / "README.md", "\n".join(lines))


def main(argv=None) -> int:
    """``python -m bench.tables.report [--results DIR | --from DIR] [--docs PAGE]
    [--readme README.md]``: rewrite DIR/README.md (summary and index) from the tables
    ``bench.run`` wrote to DIR; or read the committed runs of ``--from`` (docs/results/,
    nothing written there). ``--docs``: rewrite each run's block in PAGE
    (:mod:`bench.tables.page`); ``--readme``: the summary, without dates, between the
    file's ``<!-- results:begin -->`` and ``<!-- results:end -->`` lines. Both are computed
    before either is written, each written atomically."""
    import argparse
    import sys

    p = argparse.ArgumentParser(prog="python -m bench.tables.report", description=main.__doc__)
    source = p.add_mutually_exclusive_group()
    source.add_argument("--results", type=Path, default=Path("results"), metavar="DIR",
                        help="the folder bench.run wrote (default results/)")
    source.add_argument("--from", dest="runs", type=Path, default=None, metavar="DIR",
                        help="a folder of committed table JSONs (docs/results/) to read instead")
    p.add_argument("--docs", type=Path, default=None, metavar="PAGE",
                   help="a Markdown page whose generated blocks to rewrite (docs/results.md)")
    p.add_argument("--readme", type=Path, default=None, metavar="FILE",
                   help="a Markdown file to copy the summary into, between the markers")
    args = p.parse_args(argv)
    folder = args.runs or args.results
    try:
        if not folder.is_dir():
            raise ValueError(f"{folder}: no such folder (run `python -m bench.run` first)")
        page_text = None if args.docs is None else page.filled(args.docs, folder)
        if args.runs is None:
            write_index(folder)
        if args.readme is not None:
            changed = summary.copy_into(args.readme, summary.readme_summary(folder))
            print(f"{args.readme}: summary {'updated' if changed else 'unchanged'}")
        if page_text is not None:
            changed = page_text != args.docs.read_text()
            if changed:
                write_atomic(args.docs, page_text)
            print(f"{args.docs}: blocks {'updated' if changed else 'unchanged'}")
    except (ValueError, OSError) as exc:
        print(f"bench.tables.report: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
