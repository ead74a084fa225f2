"""The method-agnostic shell: registry, public Renderer/render, evaluation, video and CLI on
both methods (random models: no training), and the NDRF user path
`clrender ndrf extract` -> `clrender ndrf init` -> `render` / `eval`."""
from __future__ import annotations

import itertools
import json
from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest

import clrender
from clrender import cli, methods
from clrender.data import load_dataset, make_scene
from clrender.evaluate import evaluate
from clrender.metrics import psnr
from clrender.ndrf.baked import save_baked as save_ndrf
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ngprt.baked import save_baked as save_ngprt
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.paths import path_cameras


CORNER_SPHERES = [("sphere", 0.75 * np.array(c, float), np.full(3, 0.12))
                  for c in itertools.product((-1, 1), repeat=3)]
# A small random model of each registered method (a new method adds its own here).
MODELS = ("ndrf", "ngprt")


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    # Spheres in the box's corners: an empty centre where G skips (tests/test_render_cl.py).
    ngprt = save_ngprt(random_baked_model(preset("tiny", L_C=32, log2_T=11, G_res=16), 0, 1.0,
                                          shapes=CORNER_SPHERES), root / "ngprt.npz")
    ndrf = save_ndrf(random_ndrf_model(NDRFConfig(), 0), root / "ndrf.npz")
    return {"ngprt": ngprt, "ndrf": ndrf}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene("bounded", tmp_path_factory.mktemp("scene"), seed=2, n_train=6, n_test=2,
                      width=24, height=24)


def test_every_registered_method_has_a_test_model():
    assert sorted(MODELS) == methods.names()


@pytest.mark.parametrize("name", methods.names())
def test_method_meets_the_contract(name):
    """The conformance test: every hook and declaration of clrender.methods.Method, each
    declared option's default valid, each statistic and the preset default consistent."""
    plugin = methods.get(name)
    assert methods.check(plugin) == []
    assert methods.for_format(plugin.FORMAT) is plugin and methods.name_of(plugin) == name
    for opt_name, opt in {**plugin.TRAIN_OPTIONS, **plugin.Renderer.RENDER_OPTIONS}.items():
        if opt.default is not None:
            opt.check(opt_name, opt.default)
        assert opt.help and opt.cli_flag(opt_name).startswith("--")
    assert all(s.fmt.format(0.5) for s in plugin.Renderer.SCALAR_STATS.values())
    assert plugin.TEACHER is None or plugin.TEACHER in methods.names()
    assert plugin.ABLATIONS is None or plugin.ABLATIONS.is_dir()
    n, log_every = plugin.train_steps(plugin.DEFAULT_PRESET)
    assert n >= 1 and log_every >= 1


def test_registry_formats_presets_and_clear_errors(tmp_path):
    formats = [methods.get(n).FORMAT for n in methods.names()]
    assert len(set(formats)) == len(formats)
    presets = {p for n in methods.names() for p in methods.get(n).PRESETS}
    assert set(methods.all_presets()) == presets
    with pytest.raises(ValueError, match=r"unknown method 'gsplat'; methods: "
                                         + ", ".join(methods.names())):
        methods.get("gsplat")
    problems = methods.check(SimpleNamespace(FORMAT="x", PRESETS=["a"], TEACHER=None))
    assert problems[:3] == ["PRESETS should be tuple, is list", "DEFAULT_PRESET is missing",
                            "TRAIN_OPTIONS is missing"]
    assert "train is not callable" in problems and "Renderer is missing" in problems
    assert not any(p.startswith(("FORMAT", "TEACHER")) for p in problems)


def test_old_run_folders_without_a_method_are_ngprt(tmp_path):
    """config.json written before runs named their method: NGP-RT's (LEGACY_RUNS)."""
    (tmp_path / "config.json").write_text(json.dumps({"model": {}, "preset": "cpu"}))
    assert methods.of_run(tmp_path) is methods.get("ngprt")
    (tmp_path / "config.json").write_text(json.dumps({"method": "ndrf"}))
    assert methods.of_run(tmp_path) is methods.get("ndrf")


@pytest.mark.parametrize("method", MODELS)
def test_load_and_render_either_method(models, method):
    model = clrender.load(models[method])
    assert model.method == method
    cam = path_cameras("bounded", "orbit", 4, 20, 16)[0]
    renderer = clrender.Renderer(model)
    out = renderer.render(cam)
    assert out["rgb"].shape == (16, 20, 3) and out["rgb"].dtype == np.float32
    assert out["ms"] == pytest.approx(sum(v for k, v in out.items() if k.startswith("ms_")))
    keys = {s.key for s in renderer.scalar_stats.values()}
    assert keys and keys <= set(renderer.render(cam, stats=True))
    np.testing.assert_array_equal(out["rgb"], clrender.render(str(models[method]), cam))
    rgb, stats = clrender.render(model, cam, stats=True)
    assert keys <= set(stats) and all(v.shape == (16, 20) for v in stats.values())


def test_render_options_are_checked_per_method(models):
    with pytest.raises(ValueError,
                       match=r"render options \['use_G'\] do not apply to method 'ndrf'"):
        clrender.Renderer(models["ndrf"], use_G=False)
    with pytest.raises(ValueError, match=r"option 'use_G' takes bool, got 0"):
        clrender.Renderer(models["ngprt"], use_G=0)
    with pytest.raises(ValueError, match=r"option 'hits' is 'gl', expected one of"):
        clrender.Renderer(models["ndrf"], hits="gl")
    cam = path_cameras("bounded", "orbit", 4, 12, 12)[0]
    off = clrender.Renderer(models["ngprt"], use_G=False).render(cam, stats=True)
    on = clrender.Renderer(models["ngprt"]).render(cam, stats=True)       # use_G: True
    np.testing.assert_array_equal(off["n_occ"], on["n_occ"])
    assert off["n_march"].sum() > on["n_march"].sum()


@pytest.mark.parametrize("method", MODELS)
def test_evaluate_and_cli_on_either_method(models, scene, method, tmp_path, capsys):
    result = evaluate(models[method], scene, out_dir=tmp_path / "views")
    test = load_dataset(scene, split="test")
    renders = [np.clip(clrender.render(models[method], c, background=test.background), 0, 1)
               for c in test.cameras]
    assert result["n_views"] == 2 and result["mean"]["psnr"] == pytest.approx(
        np.mean([psnr(r, gt) for r, gt in zip(renders, test.images)]), abs=1e-9)
    assert sorted(p.name for p in (tmp_path / "views").iterdir()) == ["test_000.png",
                                                                      "test_001.png"]
    assert cli.main(["eval", str(models[method]), str(scene)]) == 0
    assert json.loads(capsys.readouterr().out)["psnr"] == pytest.approx(result["mean"]["psnr"])
    gif = tmp_path / "orbit.gif"
    assert cli.main(["render", str(models[method]), "--frames", "3", "--width", "16",
                     "--height", "12", "--out", str(gif)]) == 0
    assert iio.imread(gif, index=None).shape == (3, 12, 16, 3)


def test_cli_options_are_the_chosen_methods(models, scene, tmp_path, capsys):
    """Each method's flags in its own group; another method's flag is an error, not ignored."""
    out = str(tmp_path / "run")
    assert cli.main(["train", str(scene), "--method", "ndrf", "--variant", "mlp",
                     "--out", out]) == 2
    assert "--variant does not apply to --method ndrf (--variant is for ngprt)" \
        in capsys.readouterr().err
    assert cli.main(["train", str(scene), "--method", "ndrf", "--out", out]) == 2
    assert "--method ndrf needs --teacher" in capsys.readouterr().err
    assert cli.main(["eval", str(models["ndrf"]), str(scene), "--no-G"]) == 2
    assert "--no-G does not apply to a model of method ndrf (--no-G is for ngprt)" \
        in capsys.readouterr().err
    assert cli.main(["eval", str(models["ndrf"]), str(scene), "--hits", "embree"]) == 0
    capsys.readouterr()
    assert cli.main(["eval", str(models["ngprt"]), str(scene), "--no-G"]) == 0
    no_g = json.loads(capsys.readouterr().out)
    assert no_g["n_march"] > evaluate(models["ngprt"], scene)["mean"]["n_march"]
    help_text = cli.build_parser()._subparsers._group_actions[0].choices["train"].format_help()
    assert "ngprt training options" in help_text and "ndrf training options" in help_text
    assert not (tmp_path / "run").exists()


def test_cli_refuses_a_non_model_with_a_clear_error(tmp_path, capsys):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    assert cli.main(["render", str(junk), "--out", str(tmp_path / "x.gif")]) == 2
    assert "junk.npz: not a readable .npz archive" in capsys.readouterr().err
    assert not (tmp_path / "x.gif").exists()


def test_ndrf_extract_init_render_eval(models, scene, tmp_path, capsys):
    """The NDRF user path on an NGP-RT teacher (random, so the meshes are its shells)."""
    meshes = tmp_path / "meshes"
    assert cli.main(["ndrf", "extract", str(models["ngprt"]), "--out", str(meshes),
                     "--preset", "tiny", "--grid", "48"]) == 0
    report = json.loads((meshes / "report.json").read_text())
    assert [m["threshold"] for m in report["meshes"]] == [1e-4, 1e-2]
    assert all(m["faces"] > 0 for m in report["meshes"])
    model = tmp_path / "untrained.npz"
    assert cli.main(["ndrf", "init", str(meshes), "--out", str(model)]) == 0
    loaded = clrender.load(model)
    assert [m["faces"] for m in loaded.mesh_sizes()] == [m["faces"] for m in report["meshes"]]
    assert cli.main(["eval", str(model), str(scene)]) == 0
    assert cli.main(["render", str(model), "--frames", "2", "--width", "16", "--height", "16",
                     "--out", str(tmp_path / "frames")]) == 0
    assert len(list((tmp_path / "frames").glob("frame_*.png"))) == 2
    capsys.readouterr()
    assert cli.main(["ndrf", "extract", str(model), "--out", str(tmp_path / "m2")]) == 2
    assert "a teacher must be a baked NGP-RT model" in capsys.readouterr().err
