"""The method contract's proof: a third method (tests/toymethod, a flat-colour sphere with a
numpy reference and a tiny OpenCL kernel) registered through the ``clrender.methods`` entry
point by writing a distribution's metadata on sys.path, then taken through every shell path
(load, Renderer, render, `clrender train|bake|eval|render`, its own command, a one-row
`bench.run` table, `bench.train_curve`) with no edit to any clrender or bench file.

Tolerances: the kernel and its reference use the same float32 operations (contraction off,
correctly rounded sqrt), so images and hit maps are compared exactly.
"""
from __future__ import annotations

import csv
import importlib
import json
from pathlib import Path

import numpy as np
import pytest

import clrender
from bench import run as bench_run
from conftest import install_toy
from clrender import cli, methods
from clrender.camera import generate_rays
from clrender.contract import MethodSpec
from clrender.data import load_dataset, make_scene
from clrender.evaluate import evaluate
from clrender.paths import path_cameras

TESTS = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    """The toy plug-in module, registered like an installed package (dist-info entry point
    naming the module, whose METHOD the registry hands out)."""
    site = tmp_path_factory.mktemp("site")
    install_toy(site)
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(TESTS))
        mp.syspath_prepend(str(site))
        spec = methods.get("toy")
        plugin = importlib.import_module("toymethod.method")
        assert spec is plugin.METHOD
        yield plugin


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene("bounded", tmp_path_factory.mktemp("scene"), seed=3, n_train=4, n_test=2,
                      width=24, height=24)


@pytest.fixture(scope="module")
def baked(toy, scene, tmp_path_factory):
    """`clrender train --method toy` (its own default preset) then `clrender bake`."""
    root = tmp_path_factory.mktemp("toy")
    assert cli.main(["train", str(scene), "--method", "toy", "--radius", "0.5",
                     "--out", str(root / "run")]) == 0
    conf = json.loads((root / "run" / "config.json").read_text())
    assert conf["method"] == "toy" and conf["preset"] == "tiny" and conf["model"]["radius"] == 0.5
    assert cli.main(["bake", str(root / "run"), "--out", str(root / "toy.npz")]) == 0
    return root / "toy.npz"


def test_the_toy_meets_the_contract_and_is_listed(toy):
    assert "toy" in methods.names() and isinstance(toy.METHOD, MethodSpec)
    assert methods.for_format("clrender-toy") is toy.METHOD
    assert methods.name_of(toy.METHOD) == "toy"


def test_load_renderer_render_match_the_reference(toy, baked, capsys):
    model = clrender.load(baked)
    assert model.method == "toy" and model.config.radius == 0.5
    cam = path_cameras("bounded", "orbit", 3, 20, 16)[1]
    out = clrender.Renderer(model, gain=0.8).render(cam, background=(0.0, 0.2, 0.4), stats=True)
    rgb, hit = toy.render_reference(model, *generate_rays(cam), (0.0, 0.2, 0.4), gain=0.8)
    np.testing.assert_array_equal(out["rgb"], rgb)
    np.testing.assert_array_equal(out["hit"], hit)
    assert 0 < hit.sum() < hit.size and out["ms"] == out["ms_shade"]
    rgb_only, stats = clrender.render(str(baked), cam, stats=True)
    assert set(stats) == {"hit"} and rgb_only.shape == (16, 20, 3)
    assert cli.main(["toy", "colour", str(baked)]) == 0            # the method's own command
    assert np.allclose([float(c) for c in capsys.readouterr().out.split()], model.colour,
                       atol=1e-4)


def test_training_fits_the_colour_the_sphere_covers(toy, baked, scene):
    """20 steps of c += (mean - c) / 2 leave the colour within 2^-20 of the mean over views
    of the covered training pixels (each view's mean differs: within their spread)."""
    model = clrender.load(baked)
    train = load_dataset(scene, split="train")
    means = [im[toy.render_reference(model, *generate_rays(c), train.background)[1] > 0].mean(0)
             for c, im in zip(train.cameras, train.images)]
    lo, hi = np.min(means, axis=0), np.max(means, axis=0)
    assert np.all(model.colour >= lo - 1e-6) and np.all(model.colour <= hi + 1e-6)


def test_eval_and_render_commands(toy, baked, scene, tmp_path, capsys):
    assert cli.main(["eval", str(baked), str(scene), "--gain", "0.9"]) == 0
    mean = json.loads(capsys.readouterr().out)
    ref = evaluate(baked, scene, gain=0.9)["mean"]
    assert mean["psnr"] == pytest.approx(ref["psnr"]) and mean["hit"] == ref["hit"] > 0
    assert cli.main(["eval", str(baked), str(scene), "--no-G"]) == 2
    assert "--no-G does not apply to a model of method toy (--no-G is for ngprt)" \
        in capsys.readouterr().err
    for path, extra in (("orbit", []), ("test", ["--data", str(scene)])):
        frames = tmp_path / path
        assert cli.main(["render", str(baked), "--path", path, "--frames", "2", "--width", "16",
                         "--height", "16", "--out", str(frames), *extra]) == 0
        assert len(list(frames.glob("frame_*.png"))) == 2


def test_a_one_row_bench_table_and_a_train_curve(toy, scene, tmp_path, capsys):
    common = ["--scene", str(scene), "--cache", str(tmp_path / "cache"), "--out",
              str(tmp_path / "out")]
    assert bench_run.main(["toy-table", "--repeats", "1"] + common) == 0
    (row,) = json.loads((tmp_path / "out" / "toy-table.json").read_text())["rows"]
    (model,) = (tmp_path / "cache" / "models").glob("*/model.npz")
    ref = evaluate(model, scene)["mean"]
    assert row["method"] == "toy" and row["PSNR"] == pytest.approx(ref["psnr"], abs=1e-9)
    assert row["Hit"] == pytest.approx(ref["hit"], abs=1e-9)
    md = (tmp_path / "out" / "toy-table.md").read_text()
    assert f"| sphere r=0.6 | {row['PSNR']:.2f} | n/a | {row['Hit']:.3f} | n/a |" in md
    assert bench_run.main(["train-curve", "--method", "toy", "--preset", "tiny"] + common) == 0
    points = list(csv.DictReader((tmp_path / "out" / "train-curve.csv").read_text()
                                 .splitlines()))
    assert [int(p["step"]) for p in points] == [0, 5, 10, 15, 19]
    assert {p["method"] for p in points} == {"toy"} and points[-1]["teacher_test_psnr"] == ""
    final = float(points[-1]["test_psnr"])
    assert final == pytest.approx(ref["psnr"], abs=1e-4)      # the tables' model: same training


def test_toy_in_the_viewer_controls_and_the_device_check(toy, tmp_path):
    """The viewer's controls are the toy's render options; bench.tools.device_check makes and
    checks the toy's example model like any method's (in this process: its registration
    lives on this test's sys.path)."""
    from bench.tools import device_check
    from clrender import viewer

    assert viewer.option_specs(toy.Renderer) == [
        viewer.OptionSpec("gain", float, 1.0, None, "colour gain")]
    assert "toy" in device_check.checked_methods()
    folder = tmp_path / "ref"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(device_check, "SIZES", ((12, 8),))
        device_check.make_reference(folder)
        assert "toy" in json.loads((folder / "reference.json").read_text())["methods"]
        rows = device_check.check_device(0, folder, device_check.load_reference(folder), 1,
                                         ((12, 8),))
    toy_rows = [r for r in rows if r["method"] == "toy"]
    assert len(toy_rows) == 1 and "error" not in toy_rows[0], rows
