"""A row measured over several training seeds: the mean, its spread, and whether a paper
effect (a row against its baseline) reproduces beyond that spread."""
from __future__ import annotations

import math
from dataclasses import fields, replace

import numpy as np

from bench.result import RowResult


def _mean(values: list):
    """Mean of one field over seeds: equal values kept as they are (an int count, a note),
    other numbers averaged (None if any seed has None), dicts field by field, anything else
    (sample render, model key) the first seed's."""
    first = values[0]
    if isinstance(first, dict):
        return {k: _mean([v.get(k) for v in values]) for k in first}
    if any(v is None for v in values):
        return None
    if isinstance(first, np.ndarray):
        return first
    if all(v == first for v in values):
        return first
    if all(isinstance(v, (int, float)) for v in values):
        return float(np.mean(values))
    return first


def aggregate(per_seed: list[RowResult], seeds: list[int]) -> RowResult:
    """One row's results (:func:`bench.measure.measure_row`, with their model), one per
    seed, as one result of means (see :func:`_mean`; the sample render is ``seeds[0]``'s)
    with ``seeds`` and ``per_seed`` (the inputs without their sample render). One seed
    gives that seed's result unchanged, plus those two fields."""
    if len(per_seed) != len(seeds) or not seeds:
        raise ValueError(f"aggregate: {len(per_seed)} measurements for seeds {seeds}")
    means = {f.name: _mean([getattr(m, f.name) for m in per_seed]) for f in fields(RowResult)
             if f.name not in ("seeds", "per_seed")}
    return RowResult(**means, seeds=list(seeds),
                     per_seed=[replace(m, sample=None) for m in per_seed])


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


def verdict(paper_delta: float | None, mean: float, std: float, n: int) -> str:
    """Whether our paired difference (``mean`` ± ``std`` over ``n`` seeds) reproduces the
    paper's: beyond the spread when ``|mean| > 2 std / sqrt(n)`` (about a 95% interval of the
    mean excluding 0), then "reproduces" (same sign as the paper's) or "opposite";
    otherwise "within spread". "" where the paper gives no difference."""
    if paper_delta is None or paper_delta == 0:
        return ""
    if abs(mean) <= 2.0 * std / math.sqrt(n):
        return "within spread"
    return "reproduces" if (mean > 0) == (paper_delta > 0) else "opposite"
