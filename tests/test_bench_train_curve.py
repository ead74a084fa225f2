"""`python -m bench.train_curve`: the command line, the evaluation steps, the files, and
(slow) a short `tiny` curve on a small scene, whose last point is the model the tables would
bake and whose training is the one a run without evaluations gives."""
from __future__ import annotations

import csv
import json

import pytest

from bench import run, train_curve


def csv_rows(path) -> list[dict]:
    """The rows of a CSV file, read whole (no file left open)."""
    return list(csv.DictReader(path.read_text().splitlines()))


def stand_in_points(preset, seed) -> list[dict]:
    """A curve's points as :func:`train_curve.measure_curve` returns them, without training:
    steps 0, 1, 2 at 10 s a step."""
    return [{"method": "ngprt", "preset": preset, "seed": seed, "step": s,
             "train_seconds": 10.0 * s, "eval_seconds": 1.0, "test_psnr": 10.0 + s,
             "test_ssim": 0.5, "test_lpips": 0.25, "train_psnr": None if s else 12.0,
             "teacher_test_psnr": None} for s in (0, 1, 2)]


def test_argparse_accepts_repeated_presets_for_the_curve_only(tmp_path, capsys):
    args = train_curve.build_parser().parse_args(["--preset", "cpu", "--preset", "tiny"])
    assert args.presets == ["cpu", "tiny"]
    assert run.main(["table4", "--preset", "cpu", "--preset", "tiny", "--cache",
                     str(tmp_path)]) == 2
    assert "a table takes one --preset" in capsys.readouterr().err
    assert run.main(["--list"]) == 0
    assert "train-curve" in capsys.readouterr().out


@pytest.mark.parametrize("iterations, log_every", [(1800, 25), (300, 10), (30, 10), (1, 10)])
def test_eval_steps_span_the_run_on_logged_steps(iterations, log_every):
    steps = train_curve.eval_steps(iterations, log_every)
    assert steps[0] == 0 and steps[-1] == iterations - 1 and steps == sorted(set(steps))
    assert all(s % log_every == 0 for s in steps[:-1]) and len(steps) <= train_curve.N_POINTS
    if iterations >= 300:
        assert len(steps) >= 10


def test_run_writes_every_preset_to_one_csv_and_png(tmp_path, monkeypatch, capsys):
    """The command's plumbing, training replaced by a stand-in: presets in the order given,
    one CSV and one PNG for all of them."""
    out = tmp_path / "out"
    seen = []

    def fake_curve(root, data, fingerprint, preset, seed=0, on_point=None, **kwargs):
        points = stand_in_points(preset, seed)
        on_point(points[:1])            # the files hold the curves so far after each point
        seen.append(len(csv_rows(out / "train-curve.csv")))
        return points

    monkeypatch.setattr(train_curve, "measure_curve", fake_curve)
    (tmp_path / "scene").mkdir()
    assert run.main(["train-curve", "--preset", "tiny", "--preset", "cpu", "--seed", "3",
                     "--scene", str(tmp_path / "scene"), "--cache", str(tmp_path / "cache"),
                     "--out", str(out)]) == 0
    rows = csv_rows(out / "train-curve.csv")
    assert [(r["preset"], r["seed"], r["step"]) for r in rows] == \
        [(p, "3", s) for p in ("tiny", "cpu") for s in "012"]
    assert rows[1]["train_psnr"] == "" and rows[0]["train_psnr"] == "12.0000"
    assert seen == [1, 4] and rows[0]["test_lpips"] == "0.2500"
    assert (out / "train-curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "test PSNR" in capsys.readouterr().out


def test_option_values_seeds_downscale_and_stride_reach_every_curve(tmp_path, monkeypatch,
                                                                    capsys):
    """`--option engine=torch,fast --seeds 2`: a curve per value and seed, each given the
    downscale, the test stride, the number of points and the iterations, and each value
    after the first compared with the first at every step, paired by seed."""
    calls = []

    def fake_curve(root, data, fingerprint, preset, seed=0, option=None, downscale=1,
                   test_stride=1, n_points=None, iterations=None, **kwargs):
        calls.append((preset, option, seed, downscale, test_stride, n_points, iterations))
        fast = option == {"engine": "fast"}
        return [{"method": "ngprt", "preset": preset, "option": f"engine={option['engine']}",
                 "seed": seed, "step": s, "train_seconds": 1.0 + s, "eval_seconds": 1.0,
                 "test_psnr": 20.0 + s + (0.5 + 0.1 * seed if fast else 0.0),
                 "test_ssim": 0.5, "train_psnr": 12.0, "teacher_test_psnr": None}
                for s in (0, 10)]

    monkeypatch.setattr(train_curve, "measure_curve", fake_curve)
    (tmp_path / "scene").mkdir()
    out = tmp_path / "out"
    assert train_curve.main(["--preset", "tiny", "--option", "engine=torch,fast",
                     "--seeds", "2", "--downscale", "2", "--test-stride", "3", "--points", "4",
                     "--iterations", "50", "--scene", str(tmp_path / "scene"),
                     "--cache", str(tmp_path / "cache"),
                     "--out", str(out)]) == 0
    assert calls == [("tiny", {"engine": e}, s, 2, 3, 4, 50) for s in (0, 1)
                     for e in ("torch", "fast")]
    rows = csv_rows(out / "train-curve.csv")
    assert [(r["option"], r["seed"]) for r in rows][::2] == \
        [("engine=torch", "0"), ("engine=fast", "0"), ("engine=torch", "1"), ("engine=fast", "1")]
    text = capsys.readouterr().out
    # differences 0.5 and 0.6 dB: mean 0.55, std 0.0707, t(0.975, 1) = 12.706: +- 0.635
    assert "engine=fast - engine=torch step      0: +0.55 dB [-0.09, +1.19] (n = 2), 0 inside" in text
    points = [dict(r, seed=int(r["seed"]), step=int(r["step"]), test_psnr=float(r["test_psnr"]))
              for r in rows]
    (c0, c10) = train_curve.compare_options(points)
    assert (c0["step"], c10["step"]) == (0, 10)
    assert c0["mean"] == pytest.approx(0.55) and c0["lo"] < 0 < c0["hi"]


@pytest.mark.parametrize("text, message", [
    ("engine", "expected NAME=V1"), ("colour=red", "expected NAME=V1"),
    ("engine=warp", "engine"), ("L=two", "'two' is not a int")])
def test_option_values_refuse_what_the_method_does_not_take(text, message):
    with pytest.raises(ValueError, match=message):
        train_curve.option_values("ngprt", text)
    assert train_curve.option_values("ngprt", "L=2,3") == ("L", [2, 3])


def test_curve_options_fix_single_values_and_vary_one_option():
    """`--option L=4 --option variant=separate-v,sum`: L = 4 on both curves, one curve per
    variant; without options one curve of the row's own; two varied options or a repeated
    name are refused."""
    assert train_curve.curve_options("ngprt", None) == [None]
    assert train_curve.curve_options("ngprt", ["L=4", "variant=separate-v,sum"]) == [
        {"L": 4, "variant": "separate-v"}, {"L": 4, "variant": "sum"}]
    assert train_curve.curve_options("ngprt", ["L=3"]) == [{"L": 3}]
    with pytest.raises(ValueError, match="only one option"):
        train_curve.curve_options("ngprt", ["L=2,4", "variant=separate-v,sum"])
    with pytest.raises(ValueError, match="given twice"):
        train_curve.curve_options("ngprt", ["L=2", "L=4"])


def test_test_stride_keeps_every_kth_view_from_the_first(tmp_path):
    from clrender.data import make_scene

    scene = make_scene("bounded", tmp_path / "scene", seed=1, n_train=2, n_test=5, width=8,
                       height=8)
    full = train_curve.test_views(scene)
    some = train_curve.test_views(scene, stride=2)
    assert len(full.cameras) == 5 and len(some.cameras) == len(some.images) == 3
    assert all((a.c2w == b.c2w).all() for a, b in zip(some.cameras, full.cameras[::2]))
    assert (some.images == full.images[::2]).all()


def test_resumed_points_keep_what_the_checkpoint_holds(tmp_path):
    """A curve cut short: the points before the checkpoint's step are kept, later ones
    dropped, and the clock resumes at the last kept point's seconds plus the untimed
    steps at its mean step time; nothing to resume without a checkpoint."""
    import torch

    points = [{"step": s, "train_seconds": 2.0 * (s + 1), "test_psnr": 20.0 + s}
              for s in (0, 9, 19)]
    (tmp_path / train_curve.POINTS_FILE).write_text(
        "".join(json.dumps(p) + "\n" for p in points))
    assert train_curve.resumed_points(tmp_path) == ([], 0.0)
    torch.save({"step": 15}, tmp_path / "checkpoint.pt")
    kept, seconds = train_curve.resumed_points(tmp_path)
    assert kept == points[:2]
    assert seconds == pytest.approx(20.0 + 2.0 * (15 - 1 - 9))


@pytest.mark.slow
def test_tiny_curve_measures_the_deployed_model_without_changing_training(tmp_path,
                                                                          one_torch_thread):
    """A short `tiny` run on a small scene: the CSV and PNG, the training clock, the last
    point equal to the run's checkpoint baked and evaluated as the tables do it, and the
    training bit-identical to one without evaluations (one torch thread)."""
    import torch

    from clrender.data import make_scene
    from clrender.evaluate import evaluate
    from clrender.ngprt.bake import bake_run
    from clrender.ngprt.train import train

    scene = make_scene("bounded", tmp_path / "scene", seed=1, n_train=10, n_test=2, width=32,
                       height=32)
    cache = tmp_path / "cache"
    calls = []
    points = train_curve.measure_curve(cache, scene, "fingerprint", "tiny", iterations=20,
                                       progress=False, on_point=calls.append)
    assert [len(c) for c in calls] == [1, 2, 3] and calls[-1] == points
    meta = {"scene": "small", "device": "cpu", "git_revision": "test", "date": "today"}
    train_curve.write_curve(tmp_path / "out", points, meta)
    rows = csv_rows(tmp_path / "out" / "train-curve.csv")
    assert tuple(rows[0]) == train_curve.COLUMNS
    assert [int(r["step"]) for r in rows] == train_curve.eval_steps(20, 10) == [0, 10, 19]
    seconds = [float(r["train_seconds"]) for r in rows]
    assert seconds == sorted(seconds) and seconds[0] > 0
    assert all(float(r["eval_seconds"]) > 0 and r["train_psnr"] for r in rows)
    assert all(5.0 < float(r["test_psnr"]) < 60.0 for r in rows)
    assert (tmp_path / "out" / "train-curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (run_dir,) = (cache / "curves").glob("*/run")
    logged = [json.loads(line)
              for line in (run_dir / train_curve.POINTS_FILE).read_text().splitlines()]
    assert [p["test_psnr"] for p in logged] == [p["test_psnr"] for p in points]
    tables = evaluate(bake_run(run_dir, tmp_path / "model.npz"), scene, use_G=True)
    assert points[-1]["test_psnr"] == pytest.approx(tables["mean"]["psnr"], abs=1e-6)
    resumed = train_curve.measure_curve(cache, scene, "fingerprint", "tiny", iterations=20,
                                        progress=False, resume=True)
    assert resumed == points                # finished: its checkpoint is past every point
    plain = train(scene, tmp_path / "plain", preset="tiny", iterations=20, progress=False)
    curve, plain = (torch.load(d / "checkpoint.pt", weights_only=True) for d in (run_dir, plain))
    torch.testing.assert_close(curve["model"], plain["model"], rtol=0, atol=0)


@pytest.mark.slow
def test_ndrf_curve_through_its_step_hook(tmp_path, monkeypatch, one_torch_thread):
    """`train-curve --method ndrf`: the teacher from the model cache (here a random NGP-RT
    model) drawn as a line, the in-memory bake of the last step equal to the run's baked
    checkpoint evaluated as the tables do, and the training unchanged by the hook."""
    import torch

    from bench.modelcache import cache
    from clrender.data import make_scene
    from clrender.evaluate import evaluate
    from clrender.ndrf.train import bake_run
    from clrender.ngprt.baked import save_baked
    from clrender.ngprt.config import preset
    from clrender.ngprt.random_model import random_baked_model
    from clrender import methods

    scene = make_scene("bounded", tmp_path / "scene", seed=1, n_train=6, n_test=2, width=24,
                       height=24)
    teacher = save_baked(random_baked_model(preset("tiny", variant="sum"), seed=2),
                         tmp_path / "teacher.npz")
    asked = []

    def ensure_model(root, data, fingerprint, preset, method, options, **kw):
        asked.append((method, options))
        return cache.ModelEntry("teacher-key", teacher, tmp_path, 0.0)

    monkeypatch.setattr(cache, "ensure_model", ensure_model)
    points = train_curve.measure_curve(tmp_path / "cache", scene, "fp", "tiny", iterations=30,
                                       progress=False, method="ndrf")
    assert asked == [("ngprt", {"variant": "separate-v", "L": 2})]
    assert [p["step"] for p in points] == train_curve.eval_steps(30, 25) == [0, 25, 29]
    line = evaluate(teacher, scene)["mean"]["psnr"]
    assert all(p["method"] == "ndrf" and p["teacher_test_psnr"] == line for p in points)
    (run_dir,) = (tmp_path / "cache" / "curves").glob("*/run")
    tables = evaluate(bake_run(run_dir, tmp_path / "student.npz"), scene)
    assert points[-1]["test_psnr"] == pytest.approx(tables["mean"]["psnr"], abs=1e-6)
    plain = methods.get("ndrf").train(str(scene), tmp_path / "plain", "tiny", iterations=30,
                                      progress=False, teacher=str(teacher))
    curve, plain = (torch.load(d / "checkpoint.pt", weights_only=True) for d in (run_dir, plain))
    torch.testing.assert_close(curve["model"], plain["model"], rtol=0, atol=0)


@pytest.mark.parametrize("x_axis, expected", [(None, [0.0, 1 / 6, 1 / 3]), ("steps", [0, 1, 2])])
def test_x_axis_plots_minutes_or_steps(tmp_path, monkeypatch, x_axis, expected):
    """What the command's plot draws against: training minutes by default, steps with
    ``--x-axis steps`` (the three panels, one curve each; training replaced by a stand-in)."""
    import matplotlib.axes

    drawn, plot = [], matplotlib.axes.Axes.plot
    monkeypatch.setattr(matplotlib.axes.Axes, "plot",
                        lambda ax, x, *a, **k: drawn.append(list(x)) or plot(ax, x, *a, **k))
    monkeypatch.setattr(train_curve, "measure_curve",
                        lambda root, data, fingerprint, preset, seed=0, **kwargs:
                        stand_in_points(preset, seed))
    (tmp_path / "scene").mkdir()
    assert run.main(["train-curve", "--preset", "tiny", "--scene", str(tmp_path / "scene"),
                     "--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "out")]
                    + ([] if x_axis is None else ["--x-axis", x_axis])) == 0
    assert drawn == [pytest.approx(expected)] * 3
