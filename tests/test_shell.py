"""The method-agnostic shell: registry, public Renderer/render, evaluation, video and CLI on
both methods (random models: no training), and the NDRF user path
`clrender ndrf extract` -> `clrender ndrf init` -> `render` / `eval`."""
from __future__ import annotations

import itertools
import json
import subprocess
import sys
from dataclasses import replace
from importlib import metadata
from types import ModuleType, SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest

import clrender
from clrender import cli, methods
from clrender.bakedfile import BakedFormatError
from clrender.contract import BenchSpec, MethodSpec, PluginError, Teacher
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
# A small random model of each of this package's methods (another installed plug-in is
# checked by the conformance test and its own tests: tests/test_toy_method.py).
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


def test_this_packages_methods_are_registered_with_a_default():
    assert set(MODELS) <= set(methods.names())
    assert methods.default() == "ngprt"


@pytest.mark.parametrize("name", methods.names())
def test_method_meets_the_contract(name):
    """The conformance test: a registered method is a MethodSpec (checked when made: hooks
    and their signatures), each declared option's default valid, each statistic and its
    bench spec consistent."""
    spec = methods.get(name)
    assert isinstance(spec, MethodSpec)
    assert methods.for_format(spec.format) is spec and methods.name_of(spec) == name
    for opt_name, opt in {**spec.train_options, **spec.bake_options,
                          **spec.renderer.RENDER_OPTIONS}.items():
        if opt.default is not None:
            opt.check(opt_name, opt.default)
        assert opt.help and opt.cli_flag(opt_name).startswith("--")
    assert all(s.fmt.format(0.5) for s in spec.renderer.SCALAR_STATS.values())
    if spec.bench is not None:
        bench = spec.bench
        assert bench.teacher is None or bench.teacher.method in methods.names()
        assert bench.ablations is None or bench.ablations.is_dir()
        n, log_every = bench.train_steps(spec.default_preset)
        assert n >= 1 and log_every >= 1
        assert bench.train_steps(spec.default_preset, 7) == (7, log_every)


def test_registry_formats_presets_and_clear_errors(monkeypatch):
    formats = [methods.get(n).format for n in methods.names()]
    assert len(set(formats)) == len(formats)
    presets = {p for n in methods.names() for p in methods.get(n).presets}
    assert set(methods.all_presets()) == presets
    with pytest.raises(ValueError, match=r"unknown method 'gsplat'; methods: "
                                         + ", ".join(methods.names())):
        methods.get("gsplat")
    ngprt = methods.get("ngprt")
    with pytest.raises(PluginError, match=r"^MethodSpec: presets should be tuple, is list; "
                                          r"load_baked is not callable$"):
        replace(ngprt, presets=["cpu"], load_baked=None)
    with pytest.raises(PluginError) as err:
        replace(ngprt, default_preset="huge", train_options={**ngprt.train_options, "x": 1})
    assert str(err.value).startswith("MethodSpec: default_preset 'huge' not in presets; "
                                     "train_options['x'] is not Option; train(")
    with pytest.raises(PluginError, match=r"^BenchSpec: ablations should be Path or NoneType, "
                                          r"is str; model_spec is not callable$"):
        BenchSpec(None, lambda preset: (1, 1), ablations="tables")
    # An entry point may name the spec itself (module:METHOD) as well as its module.
    real = methods._entry_points()
    spec_ep = metadata.EntryPoint("direct", "clrender.ngprt.method:METHOD", methods.GROUP)
    monkeypatch.setattr(methods, "_entry_points", lambda: {**real, "direct": spec_ep})
    assert methods.get("direct") is ngprt


def test_hook_signatures_are_checked():
    ngprt = methods.get("ngprt")

    def train(data, out, preset, *, seed=0, iterations=None, torch_device=None, progress=True,
              on_step=None, variant="separate-v", L=2, engine="fast"):      # no downscale
        raise AssertionError("never called")

    with pytest.raises(PluginError) as err:
        replace(ngprt, train=train)
    problem = str(err.value)
    assert problem.startswith("MethodSpec: train(data, out, preset, *, seed=0") and \
        "; " not in problem
    assert "cannot be called as train(data, out, preset, seed=, " in problem
    assert "unexpected keyword argument 'downscale'" in problem

    class Renderer(ngprt.renderer):
        def __init__(self, model, device=None):               # no use_G
            raise AssertionError("never called")

        def render(self, camera):                             # no background, stats
            raise AssertionError("never called")

    with pytest.raises(PluginError, match=r"^MethodSpec: bake_run\(run_dir\) cannot be called "
                                          r"as bake_run\(run_dir, out_path, G_metric=, grids=\)"):
        replace(ngprt, bake_run=lambda run_dir: None)
    with pytest.raises(PluginError) as err:
        replace(ngprt, renderer=Renderer)
    first, second = str(err.value).split("; ")
    assert first.startswith("MethodSpec: renderer(model, device=None) cannot be called as "
                            "renderer(model, device=, use_G=, march=)")
    assert second.startswith("renderer.render(self, camera) cannot be called")
    assert replace(ngprt, train=lambda data, out, preset, **kw: None).train is not ngprt.train
    ndrf = methods.get("ndrf")
    with pytest.raises(PluginError, match=r"^MethodSpec: bench.teacher.option 'mentor' is not "
                                          r"in train_options$"):
        replace(ndrf, bench=replace(ndrf.bench, teacher=Teacher("mentor", "ngprt")))


@pytest.mark.parametrize("load, error", [
    (lambda: replace(methods.get("ngprt"), default_preset="huge"),
     "method 'broken' (broken.method) does not meet the method contract "
     "(clrender.contract.MethodSpec): MethodSpec: default_preset 'huge' not in presets"),
    (lambda: ModuleType("broken.method"),       # a module of names, no METHOD
     "method 'broken' (broken.method) is a module, expected a clrender.contract.MethodSpec "
     "or a module whose METHOD is one")])
def test_a_plugin_that_breaks_the_contract_is_one_line_from_the_cli(monkeypatch, capsys, load,
                                                                   error):
    real = methods._entry_points()
    ep = SimpleNamespace(name="broken", value="broken.method", load=load)
    monkeypatch.setattr(methods, "_entry_points", lambda: {**real, "broken": ep})
    assert cli.main(["info"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"clrender: error: {error}"


def test_load_stamps_the_method_and_checks_the_scene(models):
    model = methods.load(models["ngprt"])
    assert model.method == "ngprt"
    bad = SimpleNamespace(config=SimpleNamespace(scene="indoor"))
    with pytest.raises(BakedFormatError,
                       match=r"x.npz: a toy model's config.scene is 'indoor', expected one of "):
        methods.stamp(bad, "toy", "x.npz")
    assert methods.stamp(SimpleNamespace(config=SimpleNamespace(scene="bounded")), "toy").method \
        == "toy"


@pytest.mark.parametrize("command", [
    "from clrender import cli; cli.main(['info'])",
    "import clrender; m = clrender.load(sys.argv[1]); clrender.Renderer(m)",
    "import clrender; m = clrender.load(sys.argv[2]); clrender.Renderer(m)"])
def test_info_and_rendering_do_not_import_embree(models, command):
    """embreex is imported where NDRF casts with Embree (its reference hit path), not by
    `clrender info`, an NGP-RT model, or NDRF's default raster path."""
    code = f"import sys; {command}; assert 'embreex' not in sys.modules, 'embreex imported'"
    proc = subprocess.run([sys.executable, "-c", code, str(models["ngprt"]),
                           str(models["ndrf"])], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_a_run_whose_config_lacks_its_method_says_what_to_add(tmp_path, capsys):
    """config.json written before runs named their method (NGP-RT's, then): the error names
    the key to add and the methods it may name."""
    (tmp_path / "config.json").write_text(json.dumps({"model": {}, "preset": "cpu"}))
    message = (f'{tmp_path / "config.json"}: no "method"; a run\'s config names the method '
               f'that trained it: add "method": "NAME" to it, NAME one of '
               f'{", ".join(methods.names())}')
    with pytest.raises(ValueError) as err:
        methods.of_run(tmp_path)
    assert str(err.value) == message
    assert cli.main(["bake", str(tmp_path), "--out", str(tmp_path / "m.npz")]) == 2
    assert capsys.readouterr().err.strip() == f"clrender bake: error: {message}"
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
