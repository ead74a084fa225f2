"""The method-agnostic shell: registry, public Renderer/render, evaluation, video and CLI on
both methods (random models: no training), and the NDRF user path
`clrender ndrf extract` -> `clrender ndrf init` -> `render` / `eval`."""
from __future__ import annotations

import itertools
import json
import subprocess
import sys
from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest

import clrender
from clrender import cli, methods
from clrender.bakedfile import BakedFormatError
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
    assert plugin.TEACHER is None or plugin.TEACHER.method in methods.names()
    assert plugin.CONTRACT == methods.CONTRACT
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
    assert problems[:4] == ["CONTRACT is missing", "PRESETS should be tuple, is list",
                            "DEFAULT_PRESET is missing", "TRAIN_OPTIONS is missing"]
    assert "train is not callable" in problems and "Renderer is missing" in problems
    assert not any(p.startswith(("FORMAT", "TEACHER")) for p in problems)


def _plugin_like(base, **changes):
    """A copy of plug-in module ``base``'s declarations and hooks with ``changes``."""
    plugin = SimpleNamespace(**{k: getattr(base, k) for k in dir(base) if not k.startswith("__")})
    for k, v in changes.items():
        setattr(plugin, k, v)
    return plugin


def test_hook_signatures_and_the_contract_version_are_checked():
    ngprt = methods.get("ngprt")

    def train(data, out, preset, *, seed=0, iterations=None, torch_device=None, progress=True,
              on_step=None, variant="separate-v", L=2):           # no downscale
        raise AssertionError("never called")

    problems = methods.check(_plugin_like(ngprt, train=train))
    assert len(problems) == 1 and problems[0].startswith("train(data, out, preset, *, seed=0")
    assert "cannot be called as train(data, out, preset, seed=, " in problems[0]
    assert "unexpected keyword argument 'downscale'" in problems[0]

    class Renderer(ngprt.Renderer):
        def __init__(self, model, device=None):               # no use_G
            raise AssertionError("never called")

        def render(self, camera):                             # no background, stats
            raise AssertionError("never called")

    problems = methods.check(_plugin_like(ngprt, CONTRACT=0, bake_run=lambda run_dir: None))
    assert problems[0] == (f"CONTRACT is 0; this clrender's method contract is version "
                           f"{methods.CONTRACT}")
    assert problems[1].startswith("bake_run(run_dir) cannot be called as bake_run(run_dir, "
                                  "out_path)") and len(problems) == 2
    problems = methods.check(_plugin_like(ngprt, Renderer=Renderer))
    assert len(problems) == 2
    assert problems[0].startswith("Renderer(model, device=None) cannot be called as "
                                  "Renderer(model, device=, use_G=, march=)")
    assert problems[1].startswith("Renderer.render(self, camera) cannot be called")
    assert methods.check(_plugin_like(ngprt, train=lambda data, out, preset, **kw: None)) == []
    teacher = methods.Teacher("mentor", "ngprt")
    assert methods.check(_plugin_like(methods.get("ndrf"), TEACHER=teacher)) == [
        "TEACHER.option 'mentor' is not in TRAIN_OPTIONS"]


def test_a_plugin_that_breaks_the_contract_is_one_line_from_the_cli(monkeypatch, capsys):
    broken = _plugin_like(methods.get("ngprt"), CONTRACT=methods.CONTRACT + 1)
    real = methods._entry_points()
    ep = SimpleNamespace(name="broken", value="broken.method", load=lambda: broken)
    monkeypatch.setattr(methods, "_entry_points", lambda: {**real, "broken": ep})
    assert cli.main(["info"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(
        "clrender: error: method 'broken' (broken.method) does not meet the method contract")
    assert "CONTRACT is 2; this clrender's method contract is version 1" in err


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
