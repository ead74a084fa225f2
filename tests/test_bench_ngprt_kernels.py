"""bench.speed.ngprt_kernels on a baked model and a dataset (``--model --data``): the file is
written with one row per frame size, the model's variant, bounds and counters, and the
larger frames keep the test cameras' pixel aspect. No timing is asserted (tests never
time); the model is a random `tiny` one on a 2-view 24x16 scene, so it runs in seconds.
And ``--baseline``: kernels built from another folder render beside the installed ones."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from bench.speed.ngprt_kernels import main, measure, run
from bench.speed.sizes import at_size, trained_test_set
from clrender.camera import Camera, look_at
from clrender.data import make_scene
from clrender.device import _kernel_dir
from clrender.ngprt.baked import save_baked
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer


def test_trained_model_benchmark_writes_a_row_per_size(tmp_path):
    scene = make_scene("bounded", tmp_path / "scene", n_train=1, n_test=2, width=24, height=16)
    model = random_baked_model(preset("tiny", variant="shared-v"), 0)
    path = save_baked(model, tmp_path / "tiny.npz")
    out = tmp_path / "results"
    assert main(["--model", str(path), "--data", str(scene), "--sizes", "32x32", "40x20",
                 "--repeats", "1", "--out", str(out)]) == 0
    result = json.loads((out / "ngprt_kernels_tiny.json").read_text())
    rows = result["rows"]
    assert [r["size"] for r in rows] == ["24x16", "32x32", "40x20"]
    assert result["meta"]["views"] == 2
    for r in rows:
        assert r["variant"] == "shared-v" and r["use_G"] and "vs_mlp" not in r
        assert r["march"]["n"] == 2 and r["deferred"]["n"] == 2      # 2 cameras x 1 repeat
        assert r["marching"] > 0 and r["bound"]["march"]["ms"] > 0
        assert r["bound"]["deferred"]["ms"] == 0 or r["covered"] > 0
        assert (r["camera"]["width"], r["camera"]["height"]) == tuple(map(int, r["size"].split("x")))
        assert np.isclose(r["camera"]["fx"], r["camera"]["fy"])    # a from_fov test camera
    text = (out / "ngprt_kernels_tiny.md").read_text()
    table = [line for line in text.splitlines() if line.startswith("| ") and "shared-v" in line]
    assert [line.split(" | ")[0] for line in table] == ["| 24x16", "| 32x32", "| 40x20"]
    assert "vs mlp" not in text


def test_trained_model_cameras_at_its_training_downscale(tmp_path):
    """A model baked from a run at --downscale 2 is timed on its test cameras at that size
    (as `clrender eval` does), unless --downscale says otherwise."""
    scene = make_scene("bounded", tmp_path / "scene", n_train=1, n_test=2, width=24, height=16)
    model = random_baked_model(preset("tiny"), 0)
    path = save_baked(model, tmp_path / "m.npz", trained_on={"data": str(scene), "downscale": 2})
    assert [(c.width, c.height) for c in trained_test_set(path, scene).cameras] == [(12, 8)] * 2
    assert trained_test_set(path, scene, downscale=1).cameras[0].width == 24
    out = tmp_path / "results"
    assert main(["--model", str(path), "--data", str(scene), "--sizes", "12x8", "--repeats",
                 "1", "--out", str(out)]) == 0
    rows = json.loads((out / "ngprt_kernels_m.json").read_text())["rows"]
    assert [r["size"] for r in rows] == ["12x8"]


def test_at_size_keeps_the_pixel_aspect_and_the_vertical_field():
    cam = Camera(300.0, 200.0, 101.0, 50.0, 200, 100, look_at([0.0, -3.0, 1.0]))
    c = at_size(cam, 1920, 1080)
    assert (c.width, c.height) == (1920, 1080)
    assert np.isclose(c.fy, 200.0 * 10.8) and np.isclose(c.fx / c.fy, 1.5)
    assert np.isclose(c.cx, 101.0 * 9.6) and np.isclose(c.cy, 50.0 * 10.8)


def test_baseline_kernels_render_interleaved(tmp_path):
    """--baseline builds from another folder of kernel sources: a copy of the installed
    kernels renders the same image and counters; a folder without them is named."""
    copy = tmp_path / "kernels"
    shutil.copytree(_kernel_dir(), copy, ignore=shutil.ignore_patterns("__pycache__", "*.py"))
    model = random_baked_model(preset("tiny"), 0)
    camera = Camera.from_fov(0.8, 12, 10, look_at([0.3, -2.5, 1.2]))
    row = measure(model, [camera], True, 2, baseline=copy)
    assert row["baseline_same_counts"] and row["baseline_rgb_diff"] == 0.0
    pairs = row["vs_baseline"]
    assert row["baseline"]["total"]["n"] == 2 and pairs["n"] == 2
    assert 0 < pairs["lo"] <= pairs["ratio"] <= pairs["hi"]
    with pytest.raises(FileNotFoundError, match="ngprt_march.cl"):
        Renderer(model, kernel_dir=str(tmp_path / "none"))


def test_random_model_speedups_are_interleaved_pairs_with_an_interval(tmp_path, monkeypatch):
    """Each variant against mlp, G on against off: a geometric mean over the repeats'
    pairs with its 95% interval, as the tables state a speed-up (the device's rates, which
    take longer to measure than the rest, given)."""
    from bench.speed import ngprt_bounds, ngprt_kernels

    def rates(model, device=None):
        sizes = ngprt_bounds.table_bytes(model, "ours")
        return {"gathers_per_s": {name: 1e9 for name in sizes}, "reference_gathers_per_s": {},
                "flops_per_s": 1e10, "stream_bytes_per_s": 1e10, "table_bytes": sizes,
                "march": "ours", "device": "d"}

    monkeypatch.setattr(ngprt_kernels, "measure_limits", rates)
    rows = run(16, 2, "tiny", "bounded", 8, tmp_path, variants=("mlp", "sum"))
    by = {(r["variant"], r["use_G"]): r for r in rows}
    assert "vs_mlp" not in by["mlp", True] and "G_speedup" not in by["sum", False]
    for pairs in (by["sum", True]["vs_mlp"], by["sum", False]["vs_mlp"],
                  by["sum", True]["G_speedup"], by["mlp", True]["G_speedup"]):
        assert pairs["n"] == 2 and 0 < pairs["lo"] <= pairs["ratio"] <= pairs["hi"]
    text = (tmp_path / "ngprt_kernels.md").read_text()
    assert "speed-up vs mlp (95%)" in text and "geometric mean over interleaved pairs" in text
