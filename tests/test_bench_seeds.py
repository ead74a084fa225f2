"""Rows over several training seeds: mean, spread, paired differences and the verdict,
on hand-made numbers (exact up to float rounding: 1e-12)."""
import math
from dataclasses import replace

import numpy as np
import pytest

from bench.tables import seeds
from bench.tables.result import RowResult


def _m(psnr, ms, lpips=0.2, minutes=1.0, key="k"):
    return RowResult(psnr=psnr, ssim=0.8, lpips=lpips, time={"median": ms, "p10": ms - 1, "n": 10},
                     wall_ms=ms, stages={"march": ms / 2}, stats={"Marching": ms}, size_MB=1.0,
                     time_note="kernels", sample=np.full((2, 2, 3), psnr, np.float32),
                     train_minutes=minutes, model_key=key)


def test_aggregate_means_numbers_keeps_equal_values_and_the_first_seeds_sample():
    m = seeds.aggregate([_m(20.0, 10.0, minutes=1.5, key="a"),
                         _m(22.0, 12.0, lpips=None, minutes=2.5, key="b")], [3, 4])
    assert m.psnr == 21.0 and m.ssim == 0.8 and m.train_minutes == 2.0
    assert m.time == {"median": 11.0, "p10": 10.0, "n": 10} and isinstance(m.time["n"], int)
    assert m.stages == {"march": 5.5} and m.time_note == "kernels" and m.stats == {"Marching": 11.0}
    assert m.lpips is None                           # one seed without LPIPS: none
    assert m.model_key == "a" and m.sample[0, 0, 0] == 20.0
    assert m.seeds == [3, 4] and [p.model_key for p in m.per_seed] == ["a", "b"]
    assert all(p.sample is None for p in m.per_seed)


def test_aggregate_of_one_seed_is_that_seed():
    one = _m(20.0, 10.0)
    m = seeds.aggregate([one], [0])
    assert replace(m, seeds=None, per_seed=None) == one
    with pytest.raises(ValueError, match="2 measurements for seeds"):
        seeds.aggregate([one, one], [0])


def test_spread_is_the_sample_standard_deviation():
    assert seeds.spread([20.0, 22.0]) == {"std": pytest.approx(math.sqrt(2), abs=1e-12),
                                          "min": 20.0, "max": 22.0}
    assert seeds.spread([5.0]) == {"std": None, "min": 5.0, "max": 5.0}
    assert seeds.spread([5.0, None]) is None


def test_paired_delta_pairs_the_same_seed():
    mean, std = seeds.paired_delta([21.0, 22.0, 23.0], [20.0, 20.5, 21.0])   # 1, 1.5, 2
    assert mean == pytest.approx(1.5, abs=1e-12) and std == pytest.approx(0.5, abs=1e-12)
    with pytest.raises(ValueError, match="two or more paired seeds"):
        seeds.paired_delta([21.0, 22.0], [20.0])


def test_half_width_and_interval_are_the_t_interval_with_n_minus_1_degrees_of_freedom():
    # t quantiles from a printed table: t_0.975 with 2 / 3 degrees of freedom 4.3027 / 3.1824,
    # t_0.95 with 2: 2.9200.
    assert seeds.half_width(0.14, 3) == pytest.approx(4.3027 * 0.14 / math.sqrt(3), abs=1e-4)
    assert seeds.interval(1.0, 0.5, 4) == pytest.approx((1 - 3.1824 / 4, 1 + 3.1824 / 4), abs=1e-4)
    assert seeds.half_width(0.1, 3, 0.90) == pytest.approx(2.9200 * 0.1 / math.sqrt(3), abs=1e-4)
    with pytest.raises(ValueError, match="two or more paired seeds, got n = 1"):
        seeds.half_width(0.1, 1)


@pytest.mark.parametrize("paper, mean, std, n, expected", [
    (0.36, 0.32, 0.14, 3, "within spread"),   # t = 3.96 < 4.30; half-width 0.348 < 0.36
    (0.36, 0.32, 0.05, 3, "reproduces"),      # half-width 0.124
    (-0.36, 0.32, 0.05, 3, "opposite"),
    (0.36, -0.32, 0.05, 3, "opposite"),
    (-0.36, -0.32, 0.05, 3, "reproduces"),
    (0.17, 0.19, 0.08, 3, "underpowered"),    # half-width 0.199 > 0.17, and > 0.19
    (0.17, 0.25, 0.08, 3, "reproduces"),      # significant: reported as such, power aside
    (-0.17, 0.25, 0.08, 3, "opposite"),
    (1.0, 3.1824 * 0.5 / 2 - 1e-4, 0.5, 4, "within spread"),   # just inside the interval
    (1.0, 3.1824 * 0.5 / 2 + 1e-4, 0.5, 4, "reproduces"),      # just outside
    (0.3, 0.01, 0.0, 2, "reproduces"),        # no spread: any difference is resolved
    (0.3, 0.0, 0.0, 3, "within spread"),
    (None, 1.5, 0.5, 3, ""),                  # the paper gives no difference
    (0.0, 1.5, 0.5, 3, ""),
])
def test_verdict(paper, mean, std, n, expected):
    assert seeds.verdict(paper, mean, std, n) == expected


def test_verdict_needs_two_seeds():
    with pytest.raises(ValueError, match="two or more paired seeds"):
        seeds.verdict(0.3, 1.0, 0.0, 1)


def test_seeds_to_resolve_is_the_smallest_n_whose_interval_is_narrower_than_the_effect():
    assert seeds.seeds_to_resolve(0.36, 0.14) == 3      # 0.348 < 0.36 already at n = 3
    assert seeds.seeds_to_resolve(0.17, 0.08) == 4      # n = 3: 0.199; n = 4: 0.127
    assert seeds.seeds_to_resolve(-0.17, 0.08) == 4     # the size of the effect counts
    assert seeds.seeds_to_resolve(0.3, 0.0) == 2
    for effect, std in ((0.17, 0.08), (0.05, 0.4), (0.3, 0.2)):
        n = seeds.seeds_to_resolve(effect, std)
        assert seeds.half_width(std, n) < effect
        assert n == 2 or seeds.half_width(std, n - 1) >= effect
    assert seeds.seeds_to_resolve(0.0, 0.1) is None and seeds.seeds_to_resolve(None, 0.1) is None
    assert seeds.seeds_to_resolve(1e-4, 1.0, limit=1000) is None   # beyond the limit


@pytest.mark.parametrize("mean, std, n, expected", [
    (-0.05, 0.1, 3, "equivalent"),            # 90% interval -0.05 ± 0.169 inside ±0.3
    (0.2, 0.1, 3, "not shown equivalent"),    # 0.2 + 0.169 > 0.3
    (0.0, 0.2, 3, "underpowered"),            # half-width 0.337 >= 0.3: no mean could show it
    (0.0, 0.2, 8, "equivalent"),              # the same spread over more seeds
])
def test_equivalence_is_two_one_sided_tests(mean, std, n, expected):
    assert seeds.equivalence(mean, std, n, margin=0.3) == expected


def test_equivalence_needs_a_positive_margin():
    with pytest.raises(ValueError, match="margin must be > 0"):
        seeds.equivalence(0.0, 0.1, 3, margin=0.0)


def test_seeds_pool_their_timing_pairs():
    """With several seeds the speed-up interval is over every seed's pairs pooled: the
    geometric mean of all ratios, n their count (an average of the seeds' intervals would
    be no interval of anything)."""
    def pair(ratios, ms):
        logs = np.log(ratios)
        return {"ratio": float(np.exp(logs.mean())), "lo": 0.0, "hi": 0.0, "n": len(ratios),
                "stage": "march", "size": "4x4", "ms_row": ms, "ms_baseline": 2 * ms,
                "ratios": list(ratios)}

    a = replace(_m(20.0, 10.0), paired_speedup=pair([1.0, 2.0], 4.0),
                paired_at={"8x8": pair([1.0, 1.0], 8.0)})
    b = replace(_m(21.0, 10.0), paired_speedup=pair([4.0, 8.0], 6.0),
                paired_at={"8x8": pair([1.0, 1.0], 8.0)})
    m = seeds.aggregate([a, b], [0, 1])
    p = m.paired_speedup
    assert p["n"] == 4 and p["ratio"] == pytest.approx(64 ** 0.25, rel=1e-12)
    assert p["lo"] < p["ratio"] < p["hi"] and p["ms_row"] == 5.0 and p["ms_baseline"] == 10.0
    assert m.paired_at["8x8"]["n"] == 4 and m.paired_at["8x8"]["ratio"] == pytest.approx(1.0)
    assert seeds.aggregate([a, replace(b, paired_speedup=None)], [0, 1]).paired_speedup is None
