"""The method-agnostic shell: registry, public Renderer/render, evaluation, video and CLI on
both methods (random models: no training), and the NDRF user path
`clrender ndrf extract` -> `clrender ndrf init` -> `render` / `eval`."""
from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest

import clrender
from clrender import cli, methods
from clrender.data import make_scene
from clrender.evaluate import evaluate
from clrender.ndrf.baked import save_baked as save_ndrf
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ngprt.baked import save_baked as save_ngprt
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.paths import path_cameras


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    ngprt = save_ngprt(random_baked_model(preset("tiny", L_C=32, log2_T=11, G_res=16), 0, 1.0),
                       root / "ngprt.npz")
    ndrf = save_ndrf(random_ndrf_model(NDRFConfig(), 0), root / "ndrf.npz")
    return {"ngprt": ngprt, "ndrf": ndrf}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene("bounded", tmp_path_factory.mktemp("scene"), seed=2, n_train=6, n_test=2,
                      width=24, height=24)


def test_registry_names_every_method_once():
    assert methods.names() == ["ngprt", "ndrf"]
    formats = [methods.get(n).FORMAT for n in methods.names()]
    assert len(set(formats)) == 2
    assert sorted(methods.all_presets()) == ["cpu", "paper", "tiny"]


@pytest.mark.parametrize("method", ["ngprt", "ndrf"])
def test_load_and_render_either_method(models, method):
    model = clrender.load(models[method])
    assert model.method == method
    cam = path_cameras("bounded", "orbit", 4, 20, 16)[0]
    renderer = clrender.Renderer(model)
    out = renderer.render(cam)
    assert out["rgb"].shape == (16, 20, 3) and out["rgb"].dtype == np.float32
    assert out["ms"] == pytest.approx(sum(v for k, v in out.items() if k.startswith("ms_")))
    assert set(renderer.scalar_stats.values()) <= set(renderer.render(cam, stats=True))
    np.testing.assert_array_equal(out["rgb"], clrender.render(str(models[method]), cam))
    rgb, stats = clrender.render(model, cam, stats=True)
    assert stats and all(v.shape == (16, 20) for v in stats.values())


def test_render_options_are_checked_per_method(models):
    with pytest.raises(ValueError, match=r"render options \['use_G'\] do not apply to method 'ndrf'"):
        clrender.Renderer(models["ndrf"], use_G=False)
    cam = path_cameras("bounded", "orbit", 4, 12, 12)[0]
    off = clrender.Renderer(models["ngprt"], use_G=False).render(cam, stats=True)
    on = clrender.Renderer(models["ngprt"]).render(cam, stats=True)
    assert off["n_march"].sum() >= on["n_march"].sum()


@pytest.mark.parametrize("method", ["ngprt", "ndrf"])
def test_evaluate_and_cli_on_either_method(models, scene, method, tmp_path, capsys):
    result = evaluate(models[method], scene, out_dir=tmp_path / "views")
    assert result["n_views"] == 2 and 0.0 < result["mean"]["psnr"] < 60.0
    assert sorted(p.name for p in (tmp_path / "views").iterdir()) == ["test_000.png", "test_001.png"]
    assert cli.main(["eval", str(models[method]), str(scene)]) == 0
    assert json.loads(capsys.readouterr().out)["psnr"] == pytest.approx(result["mean"]["psnr"])
    gif = tmp_path / "orbit.gif"
    assert cli.main(["render", str(models[method]), "--frames", "3", "--width", "16",
                     "--height", "12", "--out", str(gif)]) == 0
    assert iio.imread(gif, index=None).shape == (3, 12, 16, 3)


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
