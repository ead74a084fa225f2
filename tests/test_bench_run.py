"""`python -m bench.run` end to end (slow): the suite's small built-in scene, the `tiny`
preset, the suite's bench cache (tests/trained_models.py; its L=2 model is the suite's
shared NGP-RT model, trained by whichever asks first).

Trains the models of Table 4 the cache lacks once, renders each with the three marches,
and checks what the table must show whatever the figures: one model per L shared by its
three rows, the marches changing the marching points and reads only (same occupied points,
images identical bit for bit, checked by the harness), each row with G timed against the
paper's w/o G row as interleaved pairs at the test size and at 1920x1080, and a cached
second run that trains nothing.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from bench import run
from bench.tables.result import RowResult
from clrender.evaluate import evaluate


@pytest.mark.slow
def test_table4_end_to_end(tiny_scene, bench_cache, tmp_path, capsys):
    args = ["table4", "--preset", "tiny", "--scene", str(tiny_scene), "--cache",
            str(bench_cache), "--out", str(tmp_path / "out"), "--repeats", "1"]
    assert run.main(args) == 0
    data = json.loads((tmp_path / "out" / "table4.json").read_text())
    rows = data["rows"]
    assert [(r["L"], r["march"], r["use_G"], r.get("G_metric")) for r in rows] == [
        (L, m, g, metric) for L in (2, 3, 4) for m, g, metric in (
            ("paper", 0, None), ("paper", 1, None), ("paper", 1, "centre"), ("ours", 1, None))]
    assert data["preset"] == "tiny" and data["resolution"] == "40x40"
    for base, paper_g, centre, ours in zip(rows[::4], rows[1::4], rows[2::4], rows[3::4]):
        assert base["model_key"] == paper_g["model_key"] == centre["model_key"] \
            == ours["model_key"]
        assert base["paired_speedup"] is None and base["same_image"] is None
        for on in (paper_g, ours):
            assert on["Occupied"] == base["Occupied"] and on["PSNR"] == base["PSNR"]
            assert on["same_image"] == {"identical": True, "max_diff": 0.0, "views": 2}
        for on in (paper_g, centre, ours):
            assert on["speedup"] == pytest.approx(base["time_ms"]["median"]
                                                  / on["time_ms"]["median"])
            for size, pair in [("40x40", on["paired_speedup"]),
                               ("1920x1080", on["paired_at"]["1920x1080"])]:
                assert pair["size"] == size and pair["stage"] == "march" and pair["n"] == 2
                assert 0 < pair["lo"] <= pair["ratio"] <= pair["hi"]
        # The centre metric's row: the same run baked again beside the model, its images
        # compared (not required to match: its steps may pass an occupied point).
        folder = bench_cache / "models" / centre["model_key"]
        assert (folder / "model-G_metric=centre.npz").is_file()
        assert centre["same_image"]["views"] == 2
        # Ours visits no more points than the paper's w/o G and reads one code a point.
        assert ours["Marching"] <= base["Marching"] and ours["Reads"] < base["Reads"]
        assert ours["Skip reads"] == pytest.approx(ours["Marching"])
        assert base["Skip reads"] > base["Marching"]
        # The table's quality is `clrender eval`'s on the cached model (one scoring loop).
        baked = bench_cache / "models" / ours["model_key"] / "model.npz"
        assert ours["PSNR"] == pytest.approx(evaluate(baked, tiny_scene)["mean"]["psnr"],
                                             abs=1e-9)
    assert len({r["model_key"] for r in rows}) == 3
    md = (tmp_path / "out" / "table4.md").read_text()
    same_centre = sum(r["same_image"]["identical"] for r in rows[2::4])
    assert "| L=4 ours |" in md and md.count("| identical |") == 6 + same_centre
    models = sorted(bench_cache / "models" / key for key in {r["model_key"] for r in rows})
    stamps = [(m / name).stat().st_mtime_ns for m in models
              for name in ("model.npz", "model-G_metric=centre.npz")]
    assert run.main(args) == 0                  # cached: nothing retrained or rebaked
    assert [(m / name).stat().st_mtime_ns for m in models
            for name in ("model.npz", "model-G_metric=centre.npz")] == stamps


def test_unknown_scene_is_a_clear_error(tmp_path, capsys):
    assert run.main(["table4", "--scene", str(tmp_path / "missing"), "--cache",
                     str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "neither a built-in scene" in capsys.readouterr().err


def test_seeds_must_be_a_positive_count(capsys):
    assert run.build_parser().parse_args(["table4", "--seeds", "3"]).seeds == 3
    assert run.build_parser().parse_args(["table4"]).seeds == 1
    for bad in ("0", "-1", "two"):
        with pytest.raises(SystemExit) as exc:
            run.build_parser().parse_args(["table4", "--seeds", bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"--seeds: expected a whole number of seeds >= 1, got '{bad}'" in err


def test_bake_option_reaches_every_row_under_its_own_key(tmp_path, capsys):
    from bench.tables import ablation

    table = ablation.load_table("table4")
    paper = ablation.with_bake(table, run.bake_options(["grids=paper"]))
    assert paper.key == "table4-grids-paper" and "grids=paper" in paper.title
    assert all(r.bake["grids"] == "paper" for r in paper.rows)
    centre = [r for r in paper.rows if "centre" in r.name]
    assert centre and all(r.bake == {"G_metric": "centre", "grids": "paper"} for r in centre)
    assert ablation.with_bake(table, {}) is table
    with pytest.raises(ValueError, match="option 'grids' is 'huge'"):
        ablation.with_bake(table, {"grids": "huge"})
    with pytest.raises(ValueError, match=r"bake options \['grids'\] do not apply to method 'ndrf'"):
        ablation.with_bake(ablation.load_table("ndrf-table3"), {"grids": "paper"})
    with pytest.raises(ValueError, match="expected NAME=VALUE"):
        run.bake_options(["grids"])
    assert run.main(["table4", "--bake", "grid=paper", "--cache", str(tmp_path),
                     "--out", str(tmp_path / "out")]) == 2
    assert "bake options ['grid'] do not apply to method 'ngprt'" in capsys.readouterr().err


@pytest.fixture
def fake_training(monkeypatch):
    """run.main without training or rendering: every (row, seed) gets a fake model whose
    PSNR is 20 + seed; returns the (method, seed, downscale) of every ensure_model call
    (and ("load", split, downscale) of every dataset load, ("pair", row, baseline) of every
    paired timing, faked too)."""
    from pathlib import Path
    from types import SimpleNamespace

    import clrender.data
    import clrender.device
    from bench.modelcache import cache
    from bench.tables import measure

    calls = []

    def ensure_model(root, data, fingerprint, preset, method, options, seed=0, torch_device=None,
                     downscale=1):
        assert fingerprint == f"fp{downscale}"
        calls.append((method, seed, downscale))
        return cache.ModelEntry(f"{method}-{seed}", Path(str(seed)), root, 1.0)

    def measure_row(baked, test_set, render, **kw):
        ms = {"median": 10.0, "p10": 9.0, "p90": 11.0, "min": 9.0, "n": 4}
        return RowResult(psnr=20.0 + int(baked.name), ssim=0.8, lpips=None, time=ms,
                         wall_ms=11.0, stages={"intersect": 1.0}, stats={"Coverage": 0.5},
                         size_MB=1.0, time_note="fake", time_at={800: ms},
                         sample=np.zeros((2, 2, 3), np.float32))

    def measure_pair(row_baked, row_render, base_baked, base_render, test_set, **kw):
        calls.append(("pair", row_baked.name, base_baked.name))
        pair = {"ratio": 1.5, "lo": 1.2, "hi": 1.9, "n": 8, "stage": "frame", "size": "4x4",
                "ms_row": 10.0, "ms_baseline": 15.0, "ratios": [1.5] * 8}
        return {"paired_speedup": pair, "paired_at": {}, "same_image": None}

    cam = SimpleNamespace(width=4, height=4)
    monkeypatch.setattr(measure, "measure_pair", measure_pair)
    monkeypatch.setattr(cache, "ensure_model", ensure_model)
    monkeypatch.setattr(cache, "resolve_scene", lambda scene, root: root)
    monkeypatch.setattr(cache, "data_fingerprint", lambda path, downscale=1: f"fp{downscale}")
    monkeypatch.setattr(measure, "measure_row", measure_row)
    def load_dataset(path, split, downscale=1):
        calls.append(("load", split, downscale))
        return SimpleNamespace(cameras=[cam])

    monkeypatch.setattr(clrender.data, "load_dataset", load_dataset)
    monkeypatch.setattr(clrender.device, "get_runtime", lambda spec: SimpleNamespace(name="fake"))
    return calls


def test_seeds_train_every_row_per_seed_and_the_index_lists_each_table(fake_training, tmp_path):
    common = ["--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "out")]
    assert run.main(["ndrf-teacher", "--seed", "5", "--seeds", "2"] + common) == 0
    # Each seed's row timed against the same seed's baseline, after both were measured.
    assert fake_training == [("load", "test", 1), ("ngprt", 5, 1), ("ngprt", 6, 1),
                             ("ndrf", 5, 1), ("ndrf", 6, 1), ("pair", "5", "5"),
                             ("pair", "6", "6")]
    data = json.loads((tmp_path / "out" / "ndrf-teacher.json").read_text())
    assert data["wall_s"] >= 0                       # the table's wall time, for its conditions
    rows = data["rows"]
    assert rows[0]["paired_speedup"] is None and rows[1]["paired_speedup"]["ratio"] == 1.5
    assert rows[0]["seeds"] == [5, 6] and rows[0]["PSNR"] == 25.5
    assert [p["model_key"] for p in rows[1]["per_seed"]] == ["ndrf-5", "ndrf-6"]
    assert "25.50 ± 0.71" in (tmp_path / "out" / "ndrf-teacher.md").read_text()
    assert run.main(["ndrf-layers"] + common) == 0             # one seed, another run
    index = (tmp_path / "out" / "README.md").read_text()
    assert "(ndrf-layers.md)" in index and "(ndrf-teacher.md)" in index


def test_builtin_scene_made_once_and_again_when_the_generator_changed(tmp_path, monkeypatch):
    import clrender.data
    from bench.modelcache import cache
    from clrender.data.scene import scene_key

    made = []

    def make_scene(kind, out, seed):
        made.append(kind)
        (out / "transforms_train.json").write_text(json.dumps({"clrender": scene_key(kind, seed)}))
        return out

    monkeypatch.setattr(clrender.data, "make_scene", make_scene)
    path = cache.resolve_scene("builtin-bounded", tmp_path)
    assert cache.resolve_scene("builtin-bounded", tmp_path) == path and made == ["bounded"]
    meta = json.loads((path / "transforms_train.json").read_text())
    meta["clrender"]["supersample"] = 2            # images of an older generator
    (path / "transforms_train.json").write_text(json.dumps(meta))
    assert cache.resolve_scene("builtin-bounded", tmp_path) == path
    assert made == ["bounded", "bounded"] and not list(path.parent.glob(".tmp-scene-*"))


def test_downscale_reaches_the_test_set_the_models_and_their_fingerprint(fake_training, tmp_path):
    common = ["--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "out")]
    assert run.main(["ndrf-teacher", "--downscale", "4"] + common) == 0
    assert fake_training == [("load", "test", 4), ("ngprt", 0, 4), ("ndrf", 0, 4),
                             ("pair", "0", "0")]
    assert "downscale 4" in (tmp_path / "out" / "ndrf-teacher.md").read_text()
    for curve_only in (["--test-stride", "2"], ["--points", "3"], ["--iterations", "3"]):
        with pytest.raises(SystemExit) as exc:
            run.main(["ndrf-teacher", *curve_only] + common)
        assert exc.value.code == 2


def test_fingerprint_holds_the_downscale(tmp_path):
    from bench.modelcache import cache

    (tmp_path / "a.txt").write_text("a")
    plain = cache.data_fingerprint(tmp_path)
    assert cache.data_fingerprint(tmp_path, 1) == plain
    assert len({plain, cache.data_fingerprint(tmp_path, 2), cache.data_fingerprint(tmp_path, 4)}) == 3


def test_a_resumed_training_counts_the_earlier_processes_up_to_where_each_was_resumed(tmp_path):
    """Three processes of one run: killed after step 450 (checkpoint at 400), resumed at 400
    and killed after 950 (checkpoint at 900), resumed at 900 to the end; each logs every 50
    steps, its clock from its own start. The earlier two count up to steps 350 and 850."""
    from bench.modelcache import cache

    def process(first, last, seconds_a_step):
        return [{"step": s, "seconds": (s - first + 1) * seconds_a_step}
                for s in range(first, last + 1, 50)]

    log = process(0, 450, 0.1) + process(400, 950, 0.2) + process(900, 1999, 0.3)
    (tmp_path / "log.jsonl").write_text("".join(json.dumps(line) + "\n" for line in log))
    assert cache.earlier_seconds(tmp_path) == pytest.approx(351 * 0.1 + 451 * 0.2)
    (tmp_path / "log.jsonl").write_text("".join(json.dumps(line) + "\n"
                                                for line in process(0, 1999, 0.1)))
    assert cache.earlier_seconds(tmp_path) == 0.0


def test_a_run_records_its_command_and_folders_as_a_user_types_them(fake_training, tmp_path,
                                                                    monkeypatch):
    """The scene relative to the working directory, the cache from the home folder; the
    table's Markdown shows the command without the folders files go to."""
    home = tmp_path / "home"
    work = home / "work"
    (work / "data" / "scene").mkdir(parents=True)
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    assert run.main(["ndrf-teacher", "--scene", str(work / "data" / "scene"), "--downscale",
                     "2", f"--cache={home / '.cache' / 'c'}", "--out", str(work / "out")]) == 0
    data = json.loads((work / "out" / "ndrf-teacher.json").read_text())
    assert data["argv"] == ["ndrf-teacher", "--scene", "data/scene", "--downscale", "2",
                            "--cache=~/.cache/c", "--out", "out"]
    assert data["scene"] == "data/scene (downscale 2)" and data["cache"]["root"] == "~/.cache/c"
    assert data["public_scene"] is None
    md = (work / "out" / "ndrf-teacher.md").read_text()
    assert "```bash\npython -m bench.run ndrf-teacher --scene data/scene --downscale 2\n```" in md
    assert "**NDRF Table 4 analog" in md and "data/scene (downscale 2) scene**" in md


def test_all_records_each_tables_own_command():
    assert run._one_table(["all", "--seeds", "3"], "table2") == ["table2", "--seeds", "3"]
    assert run._one_table(["table3", "--bake", "a=b"], "table3") == ["table3", "--bake", "a=b"]


def test_a_folder_outside_the_working_directory_and_home_is_recorded_as_given(tmp_path,
                                                                              monkeypatch):
    from bench.options import shown_path

    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    assert shown_path(tmp_path / "a" / "b") == "a/b" and shown_path("a/../c") == "c"
    assert shown_path(tmp_path) == "."
    assert shown_path(tmp_path / "home" / "x") == "home/x"    # the working directory first
    (tmp_path / "a").mkdir()
    monkeypatch.chdir(tmp_path / "a")
    assert shown_path(tmp_path / "home" / "x") == "~/x" and shown_path("~/y") == "~/y"
    assert shown_path("/mnt/shared/cache") == "/mnt/shared/cache"


def test_a_claim_against_another_row_than_the_baseline_is_timed_as_pairs(fake_training,
                                                                        tmp_path):
    """Table 3 sets Separate-Att (V) against SUM, ... besides its baseline MLP: each claim's
    speed-up is a geometric mean over interleaved pairs, pooled over the seeds."""
    common = ["--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "out")]
    assert run.main(["table3", "--seeds", "2"] + common) == 0
    data = json.loads((tmp_path / "out" / "table3.json").read_text())
    row = next(r for r in data["rows"] if r["row"] == "Separate-Att (V)")
    assert set(row["paired_with"]) == {"SUM", "Shared-Att (Inv)", "Separate-Att (Inv)",
                                       "Shared-Att (V)"}
    for claim in data["comparisons"]:
        assert claim["speedup"] == {"ratio": 1.5, "lo": 1.5, "hi": 1.5, "n": 16}
        assert claim["speed_size"] is None
