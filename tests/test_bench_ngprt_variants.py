"""bench.speed.ngprt_variants on a baked model and a dataset: the per-stage table at each
size and one interleaved-pair row per variant and size, on the stage the variant changes,
written as JSON and markdown. No timing is asserted (tests never time); a random `tiny`
model on a 2-view 24x16 scene, so it runs in seconds. Variants that keep the default's
values render its image (PoCL, fast builds: max rgb diff 1e-6); half-tables differs by
the tables' rounding only (below 1e-2 here)."""
from __future__ import annotations

import json

import pytest

from bench.speed.ngprt_variants import VARIANTS, main
from clrender.data import make_scene
from clrender.ngprt.baked import save_baked
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model


def test_every_variant_paired_at_every_size(tmp_path):
    scene = make_scene("bounded", tmp_path / "scene", n_train=1, n_test=2, width=24, height=16)
    path = save_baked(random_baked_model(preset("tiny", variant="separate-v"), 0),
                      tmp_path / "tiny.npz")
    out = tmp_path / "results"
    assert main(["--model", str(path), "--data", str(scene), "--sizes", "32x32", "40x20",
                 "--repeats", "2", "--out", str(out)]) == 0
    result = json.loads((out / "ngprt_variants_tiny.json").read_text())
    stages, pairs = result["rows"]["stages"], result["rows"]["pairs"]
    assert [s["size"] for s in stages] == ["32x32", "40x20"]
    assert all(s["bound"]["march"]["stream_ms"] > 0 for s in stages)
    assert [(p["size"], p["variant"]) for p in pairs] == [
        (size, name) for size in ("32x32", "40x20") for name in VARIANTS]
    for p in pairs:
        assert p["stage"] == VARIANTS[p["variant"]][1]
        assert p["n"] == 4 and len(p["ratios"]) == 4 and p["lo"] <= p["ratio"] <= p["hi"]
        if VARIANTS[p["variant"]][0].half_tables:
            assert 0 < p["max_rgb_diff"] < 1e-2
        else:
            assert p["max_rgb_diff"] <= 1e-6
    text = (out / "ngprt_variants_tiny.md").read_text()
    assert text.count("| 40x20 | ") == 1 + len(VARIANTS)


def test_model_and_data_go_together(tmp_path):
    with pytest.raises(SystemExit):
        main(["--model", str(tmp_path / "m.npz")])
