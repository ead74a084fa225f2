"""The baked NDRF format (clrender/ndrf/baked.py): round trip, and a clear error naming the
file and the problem for each kind of malformed file; nothing reaches a renderer unchecked."""
from __future__ import annotations

import json

import numpy as np
import pytest

from clrender import bakedfile, methods
from clrender.bakedfile import BakedFormatError
from clrender.ndrf.baked import FORMAT, NDRFModel, load_baked, save_baked, validate
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model


@pytest.fixture(scope="module")
def model():
    return random_ndrf_model(NDRFConfig(), seed=1)


def _with(model, **arrays) -> NDRFModel:
    return NDRFModel(model.config, {**model.arrays, **arrays})


def test_round_trip_and_registry(model, tmp_path):
    path = save_baked(model, tmp_path / "m.npz")
    back = load_baked(path)
    assert back.config == model.config and back.method == "ndrf"
    for name, a in model.arrays.items():
        np.testing.assert_array_equal(back.arrays[name], a)
    assert bakedfile.peek_format(path) == FORMAT
    assert type(methods.load(path)) is NDRFModel
    assert [m["faces"] for m in back.mesh_sizes()] == [len(model.arrays["faces_0"]),
                                                        len(model.arrays["faces_1"])]


def test_input_width_derives_from_K():
    assert NDRFConfig().c_in == 55                     # the paper's 55 -> 32 (supp. Table 1)
    assert NDRFConfig(thresholds=(1e-4,)).c_in == 8 + 3 + 33
    assert NDRFConfig(thresholds=(1e-4, 1e-3, 1e-2, 5e-2)).c_in == 32 + 12 + 33


@pytest.mark.parametrize("arrays, message", [
    (lambda m: {"faces_0": m.arrays["faces_0"] + len(m.arrays["vertices_0"])},
     r"faces_0 has vertex indices in \[\d+, \d+\], expected \[0, \d+\)"),
    (lambda m: {"faces_1": -m.arrays["faces_1"] - 1}, r"faces_1 has vertex indices in \[-"),
    (lambda m: {"faces_0": np.zeros((0, 3), np.int32)}, "faces_0 is empty"),
    (lambda m: {"features_0": m.arrays["features_0"][:-1]}, r"features_0 has shape"),
    (lambda m: {"features_1": m.arrays["features_1"].astype(np.float64)},
     "features_1 has dtype float64, expected float32"),
    (lambda m: {"vertices_0": np.where(np.arange(3) == 1, np.nan, m.arrays["vertices_0"])
                .astype(np.float32)}, "vertices_0 has .* non-finite"),
    (lambda m: {"conv0_w": m.arrays["conv0_w"][:, :, :54]}, r"conv0_w has shape .*55, 32\)"),
    (lambda m: {"conv1_b": np.full(3, np.inf, np.float32)}, "conv1_b has 3 non-finite"),
    (lambda m: {"background": np.array([0.5, 2.0, 0.5], np.float32)}, r"background .* \[0, 1\]"),
    (lambda m: {"extra": np.zeros(3, np.float32)}, r"unexpected arrays \['extra'\]"),
])
def test_malformed_models_are_refused(model, tmp_path, arrays, message):
    bad = _with(model, **arrays(model))
    with pytest.raises(BakedFormatError, match=message):
        validate(bad, "bad.npz")
    with pytest.raises(BakedFormatError, match=r"out\.npz: " + message):
        save_baked(bad, tmp_path / "out.npz")
    assert not (tmp_path / "out.npz").exists()


def test_missing_mesh_is_refused(model):
    arrays = {k: v for k, v in model.arrays.items() if not k.endswith("_1")}
    with pytest.raises(BakedFormatError, match=r"missing arrays \['faces_1', 'features_1', 'vertices_1'\]"):
        validate(NDRFModel(model.config, arrays), "m.npz")


def _rewrite(path, out, edit):
    with np.load(path, allow_pickle=False) as z:
        payload = {n: z[n] for n in z.files}
    manifest = json.loads(str(payload["manifest"]))
    edit(manifest, payload)
    payload["manifest"] = np.array(json.dumps(manifest))
    with open(out, "wb") as f:
        np.savez(f, **payload)
    return out


@pytest.mark.parametrize("edit, message", [
    (lambda m, p: m.update(version=7), "unknown version 7"),
    (lambda m, p: m.update(format="clrender-ngprt"), "format is 'clrender-ngprt'"),
    (lambda m, p: m["config"].update(thresholds=[1e-2, 1e-4]), "thresholds .* increasing"),
    (lambda m, p: m["config"].update(kernel_size=3), "kernel_size=3 must be 1 or 2"),
    (lambda m, p: m["config"].update(scene="unbounded"), "bounded scenes only"),
    (lambda m, p: m["config"].update(colour=1), r"unknown NDRF config keys \['colour'\]"),
    (lambda m, p: m.pop("config"), "manifest has no 'config'"),
    (lambda m, p: p.pop("conv1_b"), "manifest lists arrays"),
])
def test_malformed_files_are_refused(model, tmp_path, edit, message):
    good = save_baked(model, tmp_path / "good.npz")
    bad = _rewrite(good, tmp_path / "bad.npz", edit)
    with pytest.raises(BakedFormatError, match=r"bad\.npz: .*" + message):
        load_baked(bad)


def test_truncated_and_foreign_files(model, tmp_path):
    good = save_baked(model, tmp_path / "good.npz")
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(BakedFormatError, match=r"cut\.npz: not a readable \.npz archive"):
        methods.load(cut)
    np.save(tmp_path / "plain.npy", np.zeros(3))
    with pytest.raises(BakedFormatError, match="plain.npy: not an .npz archive"):
        methods.load(tmp_path / "plain.npy")
    other = _rewrite(good, tmp_path / "other.npz", lambda m, p: m.update(format="nerf-x"))
    with pytest.raises(BakedFormatError, match=r"other\.npz: format is 'nerf-x', expected one of"):
        methods.load(other)
