"""`python -m bench.run` end to end (slow): a small built-in scene, the `tiny` preset.

Trains the three models of Table 4 once, renders with and without G, and checks what the
table must show whatever the figures: one model per L shared by its two rows, G changing
the marching points only (same occupied points and images), and a cached second run that
trains nothing.
"""
from __future__ import annotations

import json

import pytest

from bench import run
from clrender.data import make_scene


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    return make_scene("bounded", tmp_path_factory.mktemp("scene"), seed=1, n_train=12,
                      n_test=2, width=40, height=40)


@pytest.mark.slow
def test_table4_end_to_end(small_scene, tmp_path, capsys):
    args = ["table4", "--preset", "tiny", "--scene", str(small_scene), "--cache",
            str(tmp_path / "cache"), "--out", str(tmp_path / "out"), "--repeats", "1"]
    assert run.main(args) == 0
    data = json.loads((tmp_path / "out" / "table4.json").read_text())
    rows = data["rows"]
    assert [(r["L"], r["use_G"]) for r in rows] == [(L, g) for L in (2, 3, 4) for g in (0, 1)]
    assert data["preset"] == "tiny" and data["resolution"] == "40x40"
    for off, on in zip(rows[::2], rows[1::2]):
        assert off["model_key"] == on["model_key"]
        assert on["Occupied"] == off["Occupied"] and on["PSNR"] == pytest.approx(off["PSNR"], abs=1e-6)
        assert on["Marching"] <= off["Marching"]
        assert on["speedup"] == pytest.approx(off["time_ms"]["median"] / on["time_ms"]["median"])
        assert 10.0 < on["PSNR"] < 60.0
    assert len({r["model_key"] for r in rows}) == 3
    assert "| L=4 w/ G |" in (tmp_path / "out" / "table4.md").read_text()
    models = sorted((tmp_path / "cache" / "models").iterdir())
    stamps = [(m / "model.npz").stat().st_mtime_ns for m in models]
    assert run.main(args) == 0                  # cached: nothing retrained or rebaked
    assert [(m / "model.npz").stat().st_mtime_ns for m in models] == stamps


def test_unknown_scene_is_a_clear_error(tmp_path, capsys):
    assert run.main(["table4", "--scene", str(tmp_path / "missing"), "--cache",
                     str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "neither a built-in scene" in capsys.readouterr().err
