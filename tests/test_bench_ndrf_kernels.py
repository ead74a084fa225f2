"""bench.speed.ndrf_kernels on a random model with a random NGP-RT teacher: the student's
speed-up over its teacher is timed as interleaved pairs, with an interval. No timing is
asserted (tests never time); a 16x16 frame, two repeats."""
import importlib.util
import json


from bench.speed import ndrf_kernels
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ngprt.baked import save_baked
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.paths import path_cameras
from deps import require


def test_the_teacher_speedup_is_a_paired_geometric_mean_with_an_interval(tmp_path,
                                                                         monkeypatch):
    require(importlib.util.find_spec("embreex") is not None, "embreex")
    teacher = save_baked(random_baked_model(preset("tiny"), 0), tmp_path / "teacher.npz")
    monkeypatch.setattr(ndrf_kernels, "flop_rate", lambda runtime: 1e10)     # not timed here
    monkeypatch.setattr(ndrf_kernels, "gather_rate", lambda nbytes, runtime: 1e9)
    frames = {"16x16": [path_cameras("bounded", "orbit", 8, 16, 16)[1]]}
    rows = ndrf_kernels.run(random_ndrf_model(NDRFConfig(), 0), frames, 2, tmp_path,
                            "random K=2 model (seed 0)", "orbit view", teacher=str(teacher))
    raster = next(r for r in rows if r["hits"] == "raster")
    pairs = raster["teacher"]
    assert pairs["n"] == 2 and 0 < pairs["lo"] <= pairs["ratio"] <= pairs["hi"]
    assert pairs["ms_baseline"] > 0 and pairs["size"] == "16x16"
    assert all("teacher" not in r for r in rows if r["hits"] != "raster")
    text = (tmp_path / "ndrf_kernels.md").read_text()
    assert "speed-up vs teacher (95%)" in text and ", 2 pairs)" in text
    assert json.loads((tmp_path / "ndrf_kernels.json").read_text())["rows"][0]["frame"] == "16x16"
