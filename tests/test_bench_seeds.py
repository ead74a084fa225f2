"""Rows over several training seeds: mean, spread, paired differences and the verdict,
on hand-made numbers (exact up to float rounding: 1e-12)."""
import math
from dataclasses import replace

import numpy as np
import pytest

from bench import seeds
from bench.result import RowResult


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


@pytest.mark.parametrize("paper, mean, std, n, expected", [
    (0.3, 1.5, 0.5, 3, "reproduces"),       # 1.5 > 2 * 0.5 / sqrt(3) = 0.577
    (-0.3, 1.5, 0.5, 3, "opposite"),
    (0.3, -1.5, 0.5, 3, "opposite"),
    (-0.3, -1.5, 0.5, 3, "reproduces"),
    (0.3, 0.1, 0.3, 3, "within spread"),    # 0.1 <= 0.346
    (0.3, 2.0, 2.0, 4, "within spread"),    # on the threshold 2 * 2 / 2 = 2: within
    (0.3, 2.01, 2.0, 4, "reproduces"),
    (0.3, 0.01, 0.0, 2, "reproduces"),      # no spread: any difference is beyond it
    (None, 1.5, 0.5, 3, ""),                # the paper gives no difference
])
def test_verdict(paper, mean, std, n, expected):
    assert seeds.verdict(paper, mean, std, n) == expected
