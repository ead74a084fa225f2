"""Interleaved pairs (bench.tables.measure.time_pairs) and the speed-up's 95% interval, on fake
renderers whose times are given (no rendering, no timing)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from bench.tables import ablation
from bench.tables.measure import compare_images, speedup_interval, time_pairs
from conftest import replace_bench


def test_interval_is_t_over_the_pairs_log_ratios():
    assert speedup_interval([2.0, 2.0, 2.0]) == {"ratio": 2.0, "lo": 2.0, "hi": 2.0, "n": 3}
    out = speedup_interval([1.0, 4.0])          # logs 0 and ln 4: sd ln4 / sqrt 2, t(1) 12.706
    half = 12.7062047361747 * (math.log(4.0) / math.sqrt(2)) / math.sqrt(2)
    assert out["ratio"] == pytest.approx(2.0)
    assert out["lo"] == pytest.approx(2.0 * math.exp(-half))
    assert out["hi"] == pytest.approx(2.0 * math.exp(half))
    assert speedup_interval([1.5])["lo"] == speedup_interval([1.5])["hi"] == 1.5
    with pytest.raises(ValueError, match="finite positive ratios"):
        speedup_interval([1.0, 0.0])


class _Fake:
    """A renderer whose ``ms_march`` is ``ms`` plus ``load`` when rendered right after the
    other one (a shared core's load that moves both of a pair)."""

    def __init__(self, name, ms, log):
        self.name, self.ms, self.log = name, ms, log

    def render(self, cam, background=None):
        self.log.append((self.name, cam.width))
        return {"ms_march": self.ms * cam.load, "ms": 99.0, "rgb": np.zeros((1, 1, 3))}


def test_pairs_interleave_the_two_renderers_and_swap_the_order():
    log = []
    row, base = _Fake("row", 5.0, log), _Fake("base", 10.0, log)
    cams = [SimpleNamespace(width=4, height=3, load=1.0), SimpleNamespace(width=4, height=3,
                                                                           load=3.0)]
    out = time_pairs(row, base, cams, repeats=2, stage="march")
    assert log[:2] == [("row", 4), ("base", 4)]                       # warm-up
    assert [n for n, _ in log[2:]] == ["row", "base", "base", "row", "base", "row", "row", "base"]
    assert out["ratio"] == pytest.approx(2.0) and out["lo"] == pytest.approx(2.0)
    assert out["n"] == 4 and out["stage"] == "march" and out["size"] == "4x3"
    assert out["ms_row"] == pytest.approx(10.0) and out["ms_baseline"] == pytest.approx(20.0)
    assert time_pairs(row, base, cams[:1], 1, None)["stage"] == "frame"


def test_images_are_compared_bit_for_bit():
    class Img:
        def __init__(self, value):
            self.value = value

        def render(self, cam, background=None):
            return {"rgb": np.full((2, 2, 3), self.value, np.float32)}

    ds = SimpleNamespace(cameras=[None, None], background=(1.0, 1.0, 1.0))
    assert compare_images(Img(0.5), Img(0.5), ds) == {"identical": True, "max_diff": 0.0,
                                                     "views": 2}
    out = compare_images(Img(0.5), Img(0.5 + 2**-20), ds)
    assert not out["identical"] and out["max_diff"] == pytest.approx(2**-20)


@pytest.mark.parametrize("sizes,message", [
    ('paired_sizes = ["1920"]', r"bad.toml: paired_sizes: frame size '1920'"),
    ('paired_sizes = ["64x48"]\nverdict_size = "1920x1080"',
     r"verdict_size '1920x1080' is not one of paired_sizes"),
])
def test_paired_sizes_must_be_frame_sizes(sizes, message, tmp_path, monkeypatch):
    replace_bench(monkeypatch, "ngprt", ablations=tmp_path)
    (tmp_path / "bad.toml").write_text(
        'title = "t"\npaper_source = "p"\nscene = "builtin-bounded"\npreset = "cpu"\n'
        f'paper_columns = ["PSNR"]\n{sizes}\n[[rows]]\nname = "a"\n'
        'model = { variant = "sum", L = 2 }\n')
    with pytest.raises(ValueError, match=message):
        ablation.load_table("bad")


def test_march_bound_counts_what_each_march_reads():
    from bench.speed.ngprt_bounds import march_bound, sample_flops, table_bytes
    from clrender.ngprt.config import preset
    from clrender.ngprt.random_model import random_baked_model

    model = random_baked_model(preset("tiny", L_C=32, G_res=16), 0)
    cfg = model.config
    ours, paper = table_bytes(model, "ours"), table_bytes(model, "paper")
    assert ours["occupancy"] == 2 * 32 ** 3 and ours["G"] == 16 ** 3
    assert paper["occupancy"] == sum((32 >> lev) ** 3 for lev in range(5))
    rates = {"occupancy": 1e3, "G": 2e3, "coarse": 4e3, "fine": 8e3}
    limits = {"gathers_per_s": rates, "flops_per_s": 1e9}
    b = march_bound(cfg, {"occupancy": 100.0, "G": 10.0}, 5.0, limits)
    chunks = 1 + -(-cfg.n_attention // 8)
    gathers = 100 / 1e3 + 10 / 2e3 + 5 * 8 * chunks / 4e3 + 5 * 8 * cfg.L / 8e3
    assert b["gather_ms"] == pytest.approx(1e3 * gathers)
    assert b["flop_ms"] == pytest.approx(1e3 * 5 * sample_flops(cfg) / 1e9)
    more = march_bound(cfg, {"occupancy": 300.0, "G": 10.0}, 5.0, limits)
    assert more["ms"] == pytest.approx(b["ms"] + 200.0)            # 200 reads at 1e3 / s
