"""bench.studies.ngprt_g_step: each change of the paper's march with G against the march
without G, on a random unbounded model and a tiny built-in scene's test views."""
import numpy as np
import pytest

from bench.studies import ngprt_g_step
from clrender.data import load_dataset, make_scene
from clrender.ngprt.baked import build_distance_grid, save_baked
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model


def test_rows_hold_counts_psnr_and_pairs(tmp_path):
    model = random_baked_model(preset("tiny", scene="unbounded", variant="separate-v"), seed=2)
    path = save_baked(model, tmp_path / "m.npz")
    data = make_scene("unbounded", tmp_path / "scene", n_train=1, n_test=2, width=16, height=12)
    test_set = load_dataset(data, split="test")
    rows = ngprt_g_step.measure(path, test_set, None, views=1, repeats=2, sizes=["20x16"])
    grids = ", 32^3 / G 16^3"
    assert [r["row"] for r in rows] == [n + grids for n in (
        "paper w/o G", "w/ G, cut at jumps (box)", "w/ G, cut at jumps, centre metric",
        "ours (box)")]
    base, box, centre, ours = rows
    assert "pairs" not in base and base["same image"] is None
    for r in (box, ours):
        assert r["same image"] is True and r["Occupied"] == base["Occupied"]
    for r in rows:
        assert r["Marching"] == pytest.approx(r["Occupied"] + r["Empty"]) and r["Marching"] > 0
    assert set(centre["pairs"]) == {"test", "20x16"} and centre["pairs"]["test"]["n"] == 2
    variant = ngprt_g_step.centre_variant(model)
    assert variant.G_metric == "centre" and np.array_equal(
        variant.arrays["G"], build_distance_grid(model.arrays["occupancy_0"],
                                                 model.config.G_res, "centre"))
    text = ngprt_g_step.markdown(rows, {"model": "m", "data": "d", "downscale": 1, "views": 2,
                                        "device": "dev", "git_revision": "r", "date": "t"})
    assert "same image" in text and "march speed-up at 20x16" in text
