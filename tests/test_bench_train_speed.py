"""bench.speed.train_speed end to end on a tiny scene (2 timed steps per engine): its files, each
engine's samples a second under its name, every stage timed, the speed-up over the first
engine from the steps as pairs (nothing timed is asserted)."""
import json

import pytest


@pytest.mark.slow
def test_train_speed_writes_each_engines_rate(tmp_path):
    from bench.speed.train_speed import BACKWARD, FORWARD, run
    from clrender.data import make_scene

    pytest.importorskip("clrender.ngprt.fused")
    data = make_scene("bounded", tmp_path / "scene", seed=0, n_train=4, n_test=1, width=24,
                      height=24)
    run("tiny", data, steps=2, warmup=1, out=tmp_path / "out", names=["torch", "fast"])
    res = json.loads((tmp_path / "out" / "train_speed.json").read_text())
    for name in ("torch", "fast"):
        assert res[name]["samples_per_s"] > 0 and res[name]["samples"] > 0
        assert set(res[name]["forward_s"]) == {*FORWARD, "optimiser"}
        assert set(res[name]["backward_s"]) == set(BACKWARD)
        assert all(res[name]["backward_s"][s] > 0 for s in ("fine", "aux", "fusion"))
    assert set(res["meta"]["bounds_s"]) >= {*FORWARD, "optimiser"}
    assert "speedup" not in res["torch"]
    for kind in ("step", "encoding"):                # fast against torch, step by step
        pairs = res["fast"]["speedup"][kind]
        assert pairs["n"] == 2 and 0 < pairs["lo"] <= pairs["ratio"] <= pairs["hi"]
    text = (tmp_path / "out" / "train_speed.md").read_text()
    assert "| fast |" in text and "speed-up vs torch (samples/s, 95%)" in text
