"""A table's comparisons measured: each claim of the paper (a row against another,
:class:`bench.tables.ablation.Comparison`) as our PSNR difference paired by seed, its interval and
verdict (:mod:`bench.tables.seeds`), beside the paper's difference and both speed-ups.

Verdicts are per comparison (each at its own level, no correction for how many a table
makes); the seeds are those the run was started with.
"""
from __future__ import annotations

from bench.tables import seeds


def _psnrs(m) -> list[float]:
    """A row's PSNR per seed (one value for a result of one seed)."""
    return [p.psnr for p in m.per_seed] if m.per_seed else [m.psnr]


def _time(m) -> float:
    return m.time["median"]


def speedup(m_row, m_against, row, against, size: str | None = None) -> dict:
    """{ratio: against's time over row's (>1: row faster)}, with ``lo``, ``hi``, ``n`` where
    the row's result carries pairs against this very row: against its baseline the test
    size's (``paired_speedup``), or at ``size`` ("WxH", ``paired_at``) where given; against
    another row the test size's (``paired_with``, ``size`` "test"); without pairs, the
    ratio of the two rows' median times (a result of an older run)."""
    if row.baseline == against.name:
        paired = m_row.paired_speedup if size is None else (m_row.paired_at or {}).get(size)
    else:
        paired, size = (m_row.paired_with or {}).get(against.name), None
    if paired is not None:
        return {k: paired[k] for k in ("ratio", "lo", "hi", "n")} | {"size": size}
    return {"ratio": _time(m_against) / _time(m_row)}


def speedup_cell(s: dict | None) -> str:
    """"1.17x", or with an interval from paired timings "1.17x (1.10-1.25, 20 pairs)"."""
    if s is None:
        return ""
    if "lo" not in s:
        return f"{s['ratio']:.2f}x"
    return f"{s['ratio']:.2f}x ({s['lo']:.2f}-{s['hi']:.2f}, {s['n']} pairs)"


def measure(table, results: list) -> list[dict]:
    """One record per comparison of ``table`` (``results``: one per row, from
    :func:`bench.tables.seeds.aggregate` or of one seed): ``row``, ``against``, ``claim``,
    ``margin`` (dB), ``n`` (seeds), ``mean`` and ``std`` of the paired PSNR differences (dB,
    row minus against; ``std`` None for one seed), ``lo``, ``hi`` and ``confidence`` of their
    interval (95% for a difference, 90% for an equivalence; None for one seed), ``paper``
    (its difference, None where it lacks a PSNR), ``verdict`` ("" for one seed),
    ``seeds_needed`` (where underpowered), ``speedup`` (:func:`speedup`) and
    ``speedup_paper`` (from its times, None without)."""
    rows = {r.name: (r, m) for r, m in zip(table.rows, results)}
    out = []
    for c in table.comparisons:
        (row, m), (against, b) = rows[c.row], rows[c.against]
        a, z = _psnrs(m), _psnrs(b)
        p_row, p_against = row.paper.get("PSNR"), against.paper.get("PSNR")
        paper = None if p_row is None or p_against is None else p_row - p_against
        rec = {"row": c.row, "against": c.against, "claim": c.claim, "margin": c.margin,
               "n": len(a), "mean": a[0] - z[0], "std": None, "lo": None, "hi": None,
               "confidence": None, "paper": paper, "verdict": "", "seeds_needed": None}
        if len(a) > 1:
            mean, std = seeds.paired_delta(a, z)
            equivalent = c.claim == "equivalent"
            conf = seeds.EQUIVALENCE_CONFIDENCE if equivalent else seeds.CONFIDENCE
            lo, hi = seeds.interval(mean, std, len(a), conf)
            verdict = (seeds.equivalence(mean, std, len(a), c.margin) if equivalent
                       else seeds.verdict(paper, mean, std, len(a)))
            target = c.margin if equivalent else paper
            rec.update(mean=mean, std=std, lo=lo, hi=hi, confidence=conf, verdict=verdict,
                       seeds_needed=seeds.seeds_to_resolve(target, std, conf)
                       if verdict == "underpowered" else None)
        t_row, t_against = row.paper.get("Time (ms)"), against.paper.get("Time (ms)")
        rec["speedup"] = speedup(m, b, row, against, table.verdict_size)
        rec["speed_size"] = rec["speedup"].pop("size", None)
        rec["speedup_paper"] = None if t_row is None or t_against is None else t_against / t_row
        rec["speed_verdict"] = speed_verdict(rec["speedup"], rec["speedup_paper"])
        rec["counts"] = count_claims(row, m, against, b)
        if table.row_same_image(row):   # the row must not change the image: no PSNR verdict
            check = m.same_image
            rec["claim"] = "same image"
            rec["verdict"] = ("images not compared" if check is None else "images identical"
                              if check["identical"] is True else "IMAGES DIFFER")
        out.append(rec)
    return out


def speed_verdict(ours: dict, paper: float | None) -> str:
    """Our speed-up against the paper's, on the 95% interval of interleaved pairs:
    "reproduces" where it excludes 1 on the paper's side, "opposite" where it excludes 1 on
    the other, "within spread" where it contains 1; "" without pairs or a paper figure."""
    if paper is None or paper == 1.0 or "lo" not in ours:
        return ""
    if ours["lo"] > 1.0 or ours["hi"] < 1.0:
        return "reproduces" if (ours["lo"] > 1.0) == (paper > 1.0) else "opposite"
    return "within spread"


# A count claim's size rule, fixed before any run: ours "reproduces" a paper's change of a
# count where it moves the same way by at least this share of the paper's relative change.
COUNT_SHARE = 0.5


def count_verdict(ours: float, paper: float) -> str:
    """Our ratio of a count (row over against) judged against the paper's: where the
    paper's is unchanged, "reproduces" if ours is too, else "differs"; else "reproduces"
    where ours moves the paper's way by at least :data:`COUNT_SHARE` of its relative
    change, "direction only" where it moves that way by less, "opposite" otherwise."""
    if paper == 1.0:
        return "reproduces" if ours == 1.0 else "differs"
    if ours == 1.0 or (ours > 1.0) != (paper > 1.0):
        return "opposite"
    return "reproduces" if abs(ours - 1.0) >= COUNT_SHARE * abs(paper - 1.0) \
        else "direction only"


def count_claims(row, m, against, b) -> dict:
    """{statistic: {ours, paper (row over against), verdict}} for the statistics both the
    paper and our renderer count (Marching, Occupied, Empty): exact counts, compared
    directly (:func:`count_verdict`)."""
    out = {}
    for col in m.stats:
        p_row, p_against = row.paper.get(col), against.paper.get(col)
        if p_row is None or not p_against or not b.stats.get(col):
            continue
        ours, paper = m.stats[col] / b.stats[col], p_row / p_against
        out[col] = {"ours": ours, "paper": paper, "verdict": count_verdict(ours, paper)}
    return out


def counts_cell(rec: dict) -> str:
    """Each count of a claim: ours, the paper's and the verdict."""
    return "; ".join(f"{col} {c['ours']:.3f}x (paper {c['paper']:.3f}x): {c['verdict']}"
                     for col, c in rec["counts"].items())


def verdict_cell(rec: dict) -> str:
    """The verdict as printed: "underpowered" with the seeds that would resolve it."""
    if rec["claim"] == "same image":
        return rec["verdict"]
    if rec["n"] < 2:
        return "one seed: no verdict"
    if rec["verdict"] != "underpowered":
        return rec["verdict"]
    need = rec["seeds_needed"]
    return (f"underpowered (more than {seeds.SEEDS_LIMIT} seeds needed)" if need is None
            else f"underpowered ({need} seeds would resolve it)")


def claim_cell(rec: dict) -> str:
    if rec["claim"] == "same image":
        return "same image, bit for bit"
    return (f"equivalent within ±{rec['margin']:.2f} dB" if rec["claim"] == "equivalent"
            else "difference")


def _delta_cell(rec: dict) -> str:
    return (f"{rec['mean']:+.2f}" if rec["std"] is None
            else f"{rec['mean']:+.2f} ± {rec['std']:.2f}")


def markdown(records: list[dict]) -> list[str]:
    """The comparisons as Markdown lines under a heading, then :data:`NOTE` (none for a
    table without comparisons)."""
    if not records:
        return []
    return ["### The paper's claims", "", *claims_table(records), "", NOTE, ""]


def claims_table(records: list[dict]) -> list[str]:
    """The comparisons (:func:`measure`'s records, or a table JSON's ``comparisons``) as
    the lines of one Markdown table."""
    head = ["Comparison", "Claim", "ΔPSNR ours (dB)", "Interval", "ΔPSNR (paper)", "Verdict",
            "Speed-up", "Speed-up (paper)", "Speed verdict", "Counts (row / against)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in records:
        interval = ("" if r["lo"] is None else
                    f"[{r['lo']:+.2f}, {r['hi']:+.2f}] ({r['confidence']:.0%})")
        lines.append("| " + " | ".join([
            f"{r['row']} − {r['against']}", claim_cell(r), _delta_cell(r), interval,
            "" if r["paper"] is None else f"{r['paper']:+.2f}", verdict_cell(r),
            speedup_cell(r["speedup"]) + (f" at {r['speed_size']}" if r.get("speed_size") else ""),
            "" if r["speedup_paper"] is None else f"{r['speedup_paper']:.2f}x",
            r["speed_verdict"], counts_cell(r)]) + " |")
    return lines


NOTE = ("ΔPSNR: the first row's PSNR minus the second's trained with the same seed, mean ± "
        "sample standard deviation over the N seeds; the paper's from its PSNR column. "
        "Difference: the 95% t interval of the mean (N - 1 degrees of freedom); "
        "\"reproduces\" where it excludes 0 and the mean has the paper's sign, \"opposite\" "
        "where it excludes 0 with the other sign, \"underpowered\" where it contains 0 and "
        "its half-width exceeds the paper's |Δ| (with the seeds that would resolve the "
        "paper's Δ at this spread), \"within spread\" where it contains 0 otherwise. "
        "Equivalent: two one-sided t tests at 5% each, \"equivalent\" where the 90% interval "
        "lies within ± the margin, \"underpowered\" where its half-width reaches the margin. "
        "Each verdict stands alone: no correction for the number of comparisons; the seeds "
        "were fixed before the run. Speed-up: the second row's time over the first's; with "
        "an interval where measured as interleaved pairs (95% t over the pairs' log ratios), "
        "judged against the paper's at the size the paper timed (where the table names one, "
        "e.g. Table 4 at 1920x1080; else the test size): \"reproduces\" where the interval "
        "excludes 1 on the paper's side. Counts: exact, row over against; \"reproduces\" where ours moves "
        f"the paper's way by at least {COUNT_SHARE:g} of the paper's relative change (or "
        "stays equal where the paper's does), \"direction only\" where it moves that way by "
        "less. A table whose rows must not change the image (Table 4) has their images "
        "compared bit for bit instead of a PSNR verdict.")
