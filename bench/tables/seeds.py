"""A row measured over several training seeds: the mean, its spread, and whether a paper
effect (one row against another) reproduces beyond that spread.

Verdicts are per comparison, each at its own 95% level, with no correction for the number of
comparisons a table makes (a table of five comparisons with no true effect says
"reproduces" or "opposite" somewhere about once in four runs). The number of seeds is fixed
before a run (``bench.run --seeds N``): nothing here or in the harness adds seeds until a
verdict turns significant, which would void the intervals.
"""
from __future__ import annotations

import math
from dataclasses import fields, replace

import numpy as np
from scipy import stats

from bench.tables.result import RowResult


def _mean(values: list):
    """Mean of one field over seeds: equal values kept as they are (an int count, a note),
    other numbers averaged (None if any seed has None), dicts field by field, anything else
    (sample render, model key) the first seed's."""
    first = values[0]
    if any(v is None for v in values):
        return None
    if isinstance(first, dict):
        return {k: _mean([v.get(k) for v in values]) for k in first}
    if isinstance(first, np.ndarray):
        return first
    if all(v == first for v in values):
        return first
    if all(isinstance(v, (int, float)) for v in values):
        return float(np.mean(values))
    return first


def aggregate(per_seed: list[RowResult], seeds: list[int]) -> RowResult:
    """One row's results (:func:`bench.tables.measure.measure_row`, with their model), one per
    seed, as one result of means (see :func:`_mean`; the sample render is ``seeds[0]``'s)
    with ``seeds`` and ``per_seed`` (the inputs without their sample render). One seed
    gives that seed's result unchanged, plus those two fields."""
    if len(per_seed) != len(seeds) or not seeds:
        raise ValueError(f"aggregate: {len(per_seed)} measurements for seeds {seeds}")
    means = {f.name: _mean([getattr(m, f.name) for m in per_seed]) for f in fields(RowResult)
             if f.name not in ("seeds", "per_seed")}
    means["paired_speedup"] = pooled_pairs([m.paired_speedup for m in per_seed])
    means["paired_at"] = {size: pooled_pairs([(m.paired_at or {}).get(size) for m in per_seed])
                          for size in per_seed[0].paired_at or {}}
    means["paired_with"] = {name: pooled_pairs([(m.paired_with or {}).get(name)
                                                for m in per_seed])
                            for name in per_seed[0].paired_with or {}}
    return RowResult(**means, seeds=list(seeds),
                     per_seed=[replace(m, sample=None) for m in per_seed])


def pooled_pairs(pairs: list) -> dict | None:
    """One interleaved-pair timing (:func:`bench.tables.measure.time_pairs`) per seed as one: its
    interval over every seed's pairs pooled (not an average of intervals), the times the
    seeds' means; None if a seed has none."""
    from bench.tables.measure import speedup_interval

    if not pairs or any(p is None for p in pairs):
        return None
    ratios = [r for p in pairs for r in p["ratios"]]
    return {**pairs[0], **speedup_interval(ratios), "ratios": ratios,
            "ms_row": float(np.mean([p["ms_row"] for p in pairs])),
            "ms_baseline": float(np.mean([p["ms_baseline"] for p in pairs]))}


def spread(values: list) -> dict | None:
    """{std (sample standard deviation, None for one value), min, max} of one metric over
    seeds; None if any seed has no value."""
    if not values or any(v is None for v in values):
        return None
    a = np.asarray(values, dtype=np.float64)
    return {"std": float(a.std(ddof=1)) if a.size > 1 else None,
            "min": float(a.min()), "max": float(a.max())}


def paired_delta(row: list[float], base: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation over seeds of ``row[i] - base[i]`` (same seed i)."""
    if len(row) != len(base) or len(row) < 2:
        raise ValueError(f"paired_delta: needs two or more paired seeds, got {len(row)} "
                         f"and {len(base)} values")
    d = np.asarray(row, np.float64) - np.asarray(base, np.float64)
    return float(d.mean()), float(d.std(ddof=1))




CONFIDENCE = 0.95       # two-sided level of a difference's interval
EQUIVALENCE_CONFIDENCE = 0.90   # two one-sided tests at 5% each: a 90% interval
SEEDS_LIMIT = 100_000   # the most seeds :func:`seeds_to_resolve` looks for


def half_width(std: float, n: int, confidence: float = CONFIDENCE) -> float:
    """Half-width of the two-sided ``confidence`` t interval of a mean of ``n`` paired
    differences with sample standard deviation ``std``: t_{(1+c)/2, n-1} std / sqrt(n)."""
    if n < 2:
        raise ValueError(f"an interval needs two or more paired seeds, got n = {n}")
    return float(stats.t.ppf(0.5 + confidence / 2, n - 1)) * std / math.sqrt(n)


def interval(mean: float, std: float, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """(lo, hi): the two-sided ``confidence`` t interval of the mean (:func:`half_width`)."""
    h = half_width(std, n, confidence)
    return mean - h, mean + h


def seeds_to_resolve(effect: float, std: float, confidence: float = CONFIDENCE,
                     limit: int = SEEDS_LIMIT) -> int | None:
    """The smallest number of seeds n >= 2 whose interval at today's ``std`` is narrower
    than ``|effect|`` (t_{(1+c)/2, n-1} std / sqrt(n) < |effect|); None for no effect or
    beyond ``limit`` seeds."""
    if not effect:
        return None
    n = np.arange(2, limit + 1)
    ok = np.nonzero(stats.t.ppf(0.5 + confidence / 2, n - 1) * std / np.sqrt(n) < abs(effect))[0]
    return int(n[ok[0]]) if ok.size else None


def verdict(paper_delta: float | None, mean: float, std: float, n: int) -> str:
    """Whether our paired difference (``mean`` ± ``std`` over ``n`` >= 2 seeds) reproduces
    the paper's, by its 95% t interval (:func:`interval`, n - 1 degrees of freedom):

    - "reproduces": the interval excludes 0 and ``mean`` has the paper's sign;
    - "opposite": the interval excludes 0, ``mean`` has the other sign;
    - "underpowered": the interval contains 0 and its half-width exceeds ``|paper_delta|``
      (a true difference of the paper's size could not have been told from 0 at this
      spread; :func:`seeds_to_resolve` gives the seeds that would);
    - "within spread": the interval contains 0, though narrow enough to have resolved the
      paper's difference;
    - "" where the paper gives no difference.

    Significance comes first: an interval that excludes 0 is reported as reproduces or
    opposite even when it is wider than the paper's difference (the difference was
    resolved, whatever the power); "underpowered" only qualifies a null result.
    """
    if paper_delta is None or paper_delta == 0:
        return ""
    h = half_width(std, n)
    if abs(mean) > h:
        return "reproduces" if (mean > 0) == (paper_delta > 0) else "opposite"
    return "underpowered" if h > abs(paper_delta) else "within spread"


def equivalence(mean: float, std: float, n: int, margin: float) -> str:
    """An equivalence claim ("comparable") by two one-sided t tests at 5% each (TOST):
    "equivalent" where the 90% interval of the paired difference (``mean`` ± ``std`` over
    ``n`` >= 2 seeds) lies inside (-``margin``, +``margin``); "underpowered" where its
    half-width is ``margin`` or more (no mean could show equivalence at this spread:
    ``seeds_to_resolve(margin, std, EQUIVALENCE_CONFIDENCE)`` seeds could); otherwise "not
    shown equivalent"."""
    if not margin > 0:
        raise ValueError(f"an equivalence margin must be > 0, got {margin!r}")
    h = half_width(std, n, EQUIVALENCE_CONFIDENCE)
    if h >= margin:
        return "underpowered"
    return "equivalent" if abs(mean) + h < margin else "not shown equivalent"
