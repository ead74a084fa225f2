"""NDRF training (clrender/ndrf/train.py, clrender/ndrf/distill.py).

Tolerances:
- torch shader vs the numpy reference ``shade_reference`` (float32 both): max abs RGB
  difference 1e-5, full frames and random patches (border patches included), K = 1, 2, 3,
  kernel sizes 2 and 1;
- model -> torch shader -> baked arrays: bit-equal;
- a full frame shaded on its coverage box only (training's full-frame path) vs the whole
  frame: values and the loss's gradients within 1e-5 (max abs; float32 sums reordered);
- views disk-backed (memory-mapped, over the memory budget) vs in memory: equal arrays,
  windows and targets, and bit-equal trainings (a disk-backed one interrupted and resumed);
- distillation cameras: r, theta, phi within the training cameras' ranges up to 1e-9 rad /
  world units, optical axis through the centre within 1e-9 (cosine);
- end-to-end (slow): the baked student beats a constant colour (the mean training pixel) by
  at least 5 dB PSNR on the test views.
"""
from __future__ import annotations

import gc
import json
import os
import tempfile
from dataclasses import replace

import numpy as np
import pytest
import torch

from clrender.camera import Camera, generate_rays, look_at
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.distill import (azimuth_arc, cached_distillation, distillation_cameras,
                                   load_distill, spherical_frame, to_spherical)
from clrender.ndrf.hits import HitCaster
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ndrf.shader_ref import shade_reference
from clrender.ndrf.shader_torch import NDRFShader, ViewSet, coverage_boxes, crop, shade_image
from clrender.ndrf.view_memory import VIEW_BUDGET_ENV, parse_bytes, view_budget
from clrender.ndrf.train import MODEL_OPTIONS, TrainConfig, configs, learning_rate, model_spec

TOL = 1e-5
THRESHOLDS = {1: (1e-2,), 2: (1e-4, 1e-2), 3: (1e-4, 1e-3, 1e-2)}


def _camera(seed: int, size=(37, 29)) -> Camera:
    rng = np.random.default_rng(seed)
    eye = rng.normal(size=3)
    eye = 2.6 * eye / np.linalg.norm(eye)
    w, h = size
    return Camera.from_fov(np.deg2rad(45.0), w, h, look_at(eye, rng.uniform(-0.1, 0.1, 3)))


@pytest.mark.parametrize("S", [2, 1])
@pytest.mark.parametrize("K", [1, 2, 3])
def test_torch_shader_matches_reference(K, S):
    model = random_ndrf_model(NDRFConfig(thresholds=THRESHOLDS[K], kernel_size=S), seed=K + 7 * S)
    cam = _camera(K)
    hits = HitCaster(model).cast_camera(cam)
    assert (hits.tri >= 0).any() and (hits.tri < 0).any()      # hits and misses both
    _, dirs = generate_rays(cam)
    ref = shade_reference(model, hits.tri, hits.bary, dirs, model.background)
    shader = NDRFShader.from_model(model)
    tri, bary = torch.as_tensor(hits.tri), torch.as_tensor(hits.bary)
    with torch.no_grad():
        out = shade_image(shader, tri, bary, torch.as_tensor(dirs), model.background).numpy()
    assert out.shape == ref.shape
    np.testing.assert_allclose(out, ref, rtol=0, atol=TOL)
    # Patches, the training path: a window with an S-1 halo, cropped to its interior.
    H, W = hits.tri.shape[1:]
    halo = S - 1
    for y0, x0, ph, pw in [(0, 0, 8, 8), (H - 7, W - 9, 7, 9), (5, 11, 10, 6), (0, W - 4, H, 4)]:
        t, b, inside, rows, cols = crop(tri, bary, y0, x0, ph, pw, halo)
        with torch.no_grad():
            patch = shader(t, b, torch.as_tensor(dirs)[rows][:, cols], inside,
                           torch.as_tensor(model.background)).numpy()
        np.testing.assert_allclose(patch, ref[y0:y0 + ph, x0:x0 + pw], rtol=0, atol=TOL)


def test_shader_round_trip_is_exact():
    model = random_ndrf_model(NDRFConfig(), seed=3)
    arrays = NDRFShader.from_model(model).to_arrays(model.background)
    assert set(arrays) == set(model.arrays)
    for name, a in model.arrays.items():
        assert arrays[name].dtype == a.dtype and np.array_equal(arrays[name], a), name


def test_shader_gradients_reach_features_and_weights():
    model = random_ndrf_model(NDRFConfig(), seed=4)
    shader = NDRFShader.from_model(model)
    cam = _camera(5)
    hits = HitCaster(model).cast_camera(cam)
    _, dirs = generate_rays(cam)
    out = shade_image(shader, torch.as_tensor(hits.tri), torch.as_tensor(hits.bary),
                      torch.as_tensor(dirs), model.background)
    out.sum().backward()
    for name, p in shader.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name
    # Vertices of faces no ray hits get no gradient.
    seen = np.unique(model.arrays["faces_0"][hits.tri[0][hits.tri[0] >= 0]])
    unseen = np.setdiff1d(np.arange(len(model.arrays["vertices_0"])), seen)
    assert shader.features[0].grad[unseen].abs().sum() == 0


@pytest.mark.parametrize("S", [2, 1])
def test_coverage_box_frame_equals_full_frame(S):
    model = random_ndrf_model(NDRFConfig(kernel_size=S), seed=11 + S)
    cam = Camera.from_fov(np.deg2rad(30.0), 48, 40, look_at([0.0, -4.5, 1.0], [0.2, 0, 0]))
    meshes = [model.mesh(k)[:2] for k in range(model.config.K)]
    target = np.random.default_rng(1).uniform(0, 1, (1, 40, 48, 3)).astype(np.float32)
    vs = ViewSet.build(meshes, [cam], target, "cpu")
    y0, x0, h, w = vs.boxes[0]
    assert 0 < h * w < 40 * 48 * 0.8                  # the box leaves pixels out
    bg = torch.as_tensor(model.background)
    grads = []
    for full in (True, False):
        shader = NDRFShader.from_model(model)
        if full:
            _, dirs = generate_rays(cam)
            rgb = shade_image(shader, vs.tri[0], vs.bary[0], torch.as_tensor(dirs), bg)
        else:
            rgb = vs.frame(shader, 0, bg)
        torch.nn.functional.mse_loss(rgb, vs.images[0]).backward()
        grads.append([rgb.detach()] + [p.grad.clone() for p in shader.parameters()])
    for a, b in zip(*grads):
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=0, atol=TOL)


def test_coverage_boxes():
    tri = np.full((3, 2, 5, 6), -1, np.int32)
    tri[0, 1, 1, 2] = tri[0, 0, 3, 4] = 7
    tri[2, :, :, :] = 0
    assert coverage_boxes(tri).tolist() == [[1, 2, 3, 3], [0, 0, 5, 6], [0, 0, 5, 6]]


def _mapped_file(tensor) -> str | None:
    """The file /proc/self/maps names for the mapping that holds ``tensor``'s data ("" for
    anonymous memory), None when the mapping is not found."""
    ptr = tensor.data_ptr()
    for line in open("/proc/self/maps"):
        parts = line.split(maxsplit=5)
        lo, hi = (int(x, 16) for x in parts[0].split("-"))
        if lo <= ptr < hi:
            return parts[5].strip() if len(parts) > 5 else ""
    return None


@pytest.mark.parametrize("dtype", [np.float32, np.float16])   # training, distillation targets
def test_viewset_over_budget_is_disk_backed_and_equal(tmp_path, monkeypatch, dtype):
    model = random_ndrf_model(NDRFConfig(), seed=5)
    cams = [Camera.from_fov(np.deg2rad(30.0), 36, 28, look_at([0.3 * i, -4.5, 1.0], [0.2, 0, 0]))
            for i in range(3)]
    images = np.random.default_rng(2).uniform(0, 1, (3, 28, 36, 3)).astype(dtype)
    ram = ViewSet.build(model, cams, images, "cpu", budget=1 << 40)
    need = ViewSet.array_bytes(3, 2, 28, 36, images.itemsize)
    assert not ram.disk_backed and ram.resident_bytes == need + 3 * 96
    at_limit = ViewSet.build(model, cams, images, "cpu", budget=need, folder=tmp_path)
    assert not at_limit.disk_backed
    disk = ViewSet.build(model, cams, images, "cpu", budget=need - 1, folder=tmp_path)
    assert disk.disk_backed and disk.resident_bytes == 3 * 96
    assert list(tmp_path.iterdir()) == []          # the files' names are gone at once
    if os.path.exists("/proc/self/maps"):          # ... their data mapped until freed
        for t in (disk.tri, disk.bary, disk.images):
            where = _mapped_file(t)
            assert where.startswith(str(tmp_path)) and where.endswith("(deleted)"), where
        assert not (_mapped_file(ram.tri) or "").startswith(str(tmp_path))
    for name in ("tri", "bary", "images", "cams"):
        a, b = getattr(ram, name), getattr(disk, name)
        assert a.dtype == b.dtype and a.device == b.device and torch.equal(a, b), name
    assert np.array_equal(ram.boxes, disk.boxes) and (ram.tri >= 0).any()
    for args in [(1, 0, 0, 28, 36), (2, 5, 7, 10, 12), (0, 20, 30, 8, 6)]:
        for a, b in zip(ram.window(*args, 1), disk.window(*args, 1)):
            assert torch.equal(a, b)
        t = disk.target(*args)
        assert t.dtype == torch.float32 and torch.equal(t, ram.target(*args))
    shader = NDRFShader.from_model(model)
    bg = torch.as_tensor(model.background)
    with torch.no_grad():
        assert torch.equal(ram.frame(shader, 1, bg), disk.frame(shader, 1, bg))
    # Without a folder: the temporary directory, nothing left there either; and the
    # budget from the environment.
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setenv(VIEW_BUDGET_ENV, "1k")
    assert view_budget() == 1000 and view_budget(budget="2G") == 2 * 10 ** 9
    again = ViewSet.build(model, cams, images, "cpu")
    assert again.disk_backed and torch.equal(again.bary, ram.bary)
    assert list(tmp_path.iterdir()) == []
    del disk, again, t
    gc.collect()
    if os.path.exists("/proc/self/maps"):          # freed with the views
        assert str(tmp_path) not in open("/proc/self/maps").read()


def test_viewset_on_a_full_disk_fails_at_build(tmp_path, monkeypatch):
    import errno

    def full(fd, offset, size):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "posix_fallocate", full, raising=False)
    model = random_ndrf_model(NDRFConfig(), seed=5)
    cam = Camera.from_fov(0.7, 8, 6, look_at([0.0, -3.0, 0.5]))
    with pytest.raises(OSError, match="disk-backed views do not fit"):
        ViewSet.build(model, [cam], np.zeros((1, 6, 8, 3), np.float32), "cpu", budget=0,
                      folder=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_parse_bytes():
    assert [parse_bytes(t) for t in ("0", "12G", "500MB", "12e9", "1.5k", 7)] == \
        [0, 12 * 10 ** 9, 5 * 10 ** 8, 12 * 10 ** 9, 1500, 7]
    for bad in ("x", "-1", "12Q", ""):
        with pytest.raises(ValueError, match="byte count"):
            parse_bytes(bad)


def _ring_cameras(az_deg, el_deg, radius, up=(0.0, 0.0, 1.0)):
    cams = []
    for i, (a, e) in enumerate(zip(np.deg2rad(az_deg), np.deg2rad(el_deg))):
        eye = radius[i] * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        cams.append(Camera.from_fov(0.7, 16, 12, look_at(eye, (0, 0, 0), up)))
    return cams


@pytest.mark.parametrize("az, arc", [([-40.0, -10.0, 5.0, 30.0], 70.0),       # across phi = 0
                                     ([150.0, 170.0, -170.0, -160.0], 50.0),  # across phi = pi
                                     ([10.0, 100.0, 200.0, 300.0], 260.0)])   # around
def test_distillation_cameras_within_ranges(az, arc):
    el = [10.0, 60.0, 35.0, 20.0]
    radius = [2.5, 3.0, 2.8, 3.4]
    train = _ring_cameras(az, el, radius)
    views = distillation_cameras(train, 300, seed=2)
    assert len(views) == 300
    frame = spherical_frame(train)
    np.testing.assert_allclose(frame[2], [0, 0, 1], atol=1e-9)    # no roll: exact up
    r0, t0, p0 = to_spherical(np.stack([c.origin for c in train]), frame)
    r, t, p = to_spherical(np.stack([c.origin for c in views]), frame)
    eps = 1e-9
    assert r.min() >= r0.min() - eps and r.max() <= r0.max() + eps
    assert t.min() >= t0.min() - eps and t.max() <= t0.max() + eps
    start, width = azimuth_arc(p0)
    assert np.isclose(np.rad2deg(width), arc)
    offset = np.mod(p - start, 2 * np.pi)
    assert offset.max() <= width + eps
    assert offset.max() > 0.9 * width and offset.min() < 0.1 * width      # spans the arc
    for c in views:
        assert (c.fx, c.width, c.height) == (train[0].fx, train[0].width, train[0].height)
        forward = -c.c2w[:3, 2]
        to_centre = -c.origin / np.linalg.norm(c.origin)
        assert forward @ to_centre >= 1.0 - eps


def test_azimuth_arc_wraps():
    start, width = azimuth_arc(np.deg2rad([170.0, -170.0, 175.0]))
    assert np.isclose(np.rad2deg(start), 170.0) and np.isclose(np.rad2deg(width), 20.0)


def test_distillation_cache(tmp_path, monkeypatch):
    model = random_ndrf_model(NDRFConfig(), seed=1)
    train = _ring_cameras([0.0, 90.0, 180.0], [20.0, 30.0, 40.0], [3.0, 3.0, 3.0])
    from clrender.ndrf import distill

    calls = []

    def fake_render(teacher, cams, background, device=None, progress=True):
        calls.append(len(cams))
        return np.full((len(cams), cams[0].height, cams[0].width, 3), 0.25, np.float32)

    monkeypatch.setattr(distill, "render_teacher", fake_render)
    cams, images = cached_distillation(tmp_path, model, train, 5, 0, (1, 1, 1), "t")
    again, images2 = cached_distillation(tmp_path, model, train, 5, 0, (1, 1, 1), "t")
    cached_distillation(tmp_path, model, train, 5, 1, (1, 1, 1), "t")         # other seed
    assert calls == [5, 5]
    assert images.shape == (5, 12, 16, 3) and np.array_equal(images, images2)
    assert all(np.array_equal(a.c2w, b.c2w) for a, b in zip(cams, again))
    _, _, spec = load_distill(tmp_path / "distill.npz")
    assert spec["seed"] == 1


def test_configs_and_spec():
    assert set(MODEL_OPTIONS) == {"thresholds", "kernel_size", "distill", "outer_only"}
    cfg, tcfg, ecfg = configs("paper")
    assert tcfg.iterations == 200_000 and tcfg.n_distill == 1000 and ecfg.N == 512
    assert (tcfg.lr, tcfg.lr_final, tuple(tcfg.betas)) == (1e-3, 1e-5, (0.9, 0.999))
    cfg, tcfg, _ = configs("tiny", thresholds=[1e-3], kernel_size=1, distill=False)
    assert cfg.K == 1 and cfg.kernel_size == 1 and not tcfg.distill
    spec = model_spec("cpu", kernel_size=1)
    assert spec["model"]["kernel_size"] == 1 and json.loads(json.dumps(spec)) == spec
    assert spec != model_spec("cpu") and model_spec("cpu") == model_spec("cpu")
    with pytest.raises(ValueError, match="unknown NDRF options"):
        configs("cpu", hidden=3)
    t = TrainConfig(iterations=100)
    assert learning_rate(0, t) == 1e-3 and np.isclose(learning_rate(100, t), 1e-5)
    assert np.isclose(learning_rate(50, t), 1e-4)


@pytest.fixture(scope="module")
def small_run_inputs():
    """A random NGP-RT teacher (thin shells) and an in-memory 24x20 dataset of 6 views."""
    from clrender.data import Dataset
    from clrender.ngprt.config import preset as ngprt_preset
    from clrender.ngprt.random_model import random_baked_model

    teacher = random_baked_model(ngprt_preset("tiny", variant="sum"), seed=2)
    cams = _ring_cameras(np.arange(6) * 60.0, [20.0, 40.0] * 3, [2.8] * 6)
    cams = [c.scaled_to(24, 20) for c in cams]
    rng = np.random.default_rng(0)
    ds = Dataset(rng.uniform(0, 1, (6, 20, 24, 3)).astype(np.float32), cams, "bounded",
                 np.ones(3, np.float32), "", "train")
    return teacher, ds


def _features(run):
    state = torch.load(run / "checkpoint.pt", weights_only=True)
    return int(state["step"]), {k: v for k, v in state["model"].items()}


def _train_stopped_at(monkeypatch, step: int, *args, **kwargs) -> None:
    """NDRF's train(*args, **kwargs) interrupted right after its checkpoint at ``step``."""
    from clrender.ndrf import train as ndrf_train
    from clrender.runs import RunFolder

    save = RunFolder.save_checkpoint

    def save_then_stop(run, state):
        save(run, state)
        if state["step"] == step:
            raise KeyboardInterrupt

    monkeypatch.setattr(RunFolder, "save_checkpoint", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        ndrf_train.train(*args, **kwargs)
    monkeypatch.setattr(RunFolder, "save_checkpoint", save)


@pytest.mark.slow
def test_train_resume_and_bake(tmp_path, small_run_inputs, monkeypatch):
    from clrender.ndrf import train as ndrf_train
    from clrender.ndrf.baked import load_baked

    teacher, ds = small_run_inputs
    tcfg = replace(ndrf_train.TRAIN_PRESETS["tiny"], iterations=20, n_distill=4,
                   checkpoint_every=10, log_every=1, patch=8)
    run_a = ndrf_train.train(ds, tmp_path / "a", teacher, preset="tiny", progress=False,
                             train_config=tcfg)
    step, state_a = _features(run_a)
    assert step == 20 and set(state_a) == {"features.0", "features.1", "conv0.weight",
                                           "conv0.bias", "conv1.weight", "conv1.bias"}
    # An interrupted run resumes from its checkpoint and ends where the whole run ended.
    _train_stopped_at(monkeypatch, 10, ds, tmp_path / "b", teacher, preset="tiny",
                      progress=False, train_config=tcfg)
    assert _features(tmp_path / "b")[0] == 10
    run_b = ndrf_train.train(ds, tmp_path / "b", teacher, preset="tiny", progress=False,
                             train_config=tcfg)
    step, state_b = _features(run_b)
    assert step == 20
    for name in state_a:
        assert torch.equal(state_a[name], state_b[name]), name
    steps = [json.loads(line)["step"] for line in (run_b / "log.jsonl").read_text().splitlines()]
    assert steps == list(range(20))
    # A finished run is not trained again; a changed config starts afresh.
    ndrf_train.train(ds, run_a, teacher, preset="tiny", progress=False, train_config=tcfg)
    assert len((run_a / "log.jsonl").read_text().splitlines()) == 20
    ndrf_train.train(ds, run_a, teacher, preset="tiny", progress=False,
                     train_config=replace(tcfg, iterations=5))
    assert _features(run_a)[0] == 5
    # Baking: the checkpoint's values, the conv weights as [dy, dx, in, out].
    model = load_baked(ndrf_train.bake_run(run_b, tmp_path / "b.npz"))
    assert np.array_equal(model.arrays["features_1"], state_b["features.1"].numpy())
    assert np.array_equal(model.arrays["conv0_w"],
                          state_b["conv0.weight"].permute(2, 3, 1, 0).numpy())
    assert model.background == (1.0, 1.0, 1.0)


def _poisoned_shader(monkeypatch, bad_calls: set) -> None:
    """NDRFShader's output NaN at its calls numbered in ``bad_calls`` (0-based)."""
    from clrender.ndrf.shader_torch import NDRFShader

    forward, calls = NDRFShader.forward, []

    def poisoned(self, *args, **kwargs):
        out = forward(self, *args, **kwargs)
        calls.append(1)
        return out * float("nan") if len(calls) - 1 in bad_calls else out

    monkeypatch.setattr(NDRFShader, "forward", poisoned)


@pytest.mark.slow
def test_a_nonfinite_step_is_skipped_as_in_every_method(tmp_path, small_run_inputs,
                                                        monkeypatch):
    """NDRF's steps pass the shell's guard (clrender.runs): a step whose loss and gradients
    are NaN leaves the features and conv weights as they were, is counted in the log and the
    checkpoint, and is saved to reproduce it; the steps around it train. A run of such
    steps stops with an error."""
    from clrender import runs
    from clrender.ndrf import train as ndrf_train

    teacher, ds = small_run_inputs
    tcfg = replace(ndrf_train.TRAIN_PRESETS["tiny"], iterations=5, n_distill=4,
                   checkpoint_every=10, log_every=1, patch=8)
    _poisoned_shader(monkeypatch, {2})       # one forward a step (patches, no hook bake)
    states = {}

    def hook(step, bake):
        states[step] = {k: v.copy() for k, v in bake().arrays.items()}

    run = ndrf_train.train(ds, tmp_path / "run", teacher, preset="tiny", progress=False,
                           train_config=tcfg, on_step=hook)
    assert all(np.array_equal(states[2][k], states[1][k]) for k in states[1])
    assert any(not np.array_equal(states[3][k], states[2][k]) for k in states[2])
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    assert ckpt["skipped"] == 1
    assert all(bool(torch.isfinite(v).all()) for v in ckpt["model"].values())
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [r["skipped"] for r in log] == [0, 0, 1, 1, 1]
    saved = torch.load(run / "nonfinite-step-2.pt", weights_only=True)
    assert saved["step"] == 2 and len(saved["window"]) == 4
    assert (saved["phase"], saved["view"]) == (log[2]["phase"], log[2]["view"])
    assert np.array_equal(saved["model"]["features.0"].numpy(), states[1]["features_0"])

    monkeypatch.undo()
    monkeypatch.setattr(runs, "MAX_NONFINITE_IN_A_ROW", 3)
    _poisoned_shader(monkeypatch, {1, 3, 4, 5})
    with pytest.raises(RuntimeError, match="3 training steps in a row up to step 5"):
        ndrf_train.train(ds, tmp_path / "run_b", teacher, preset="tiny", progress=False,
                         train_config=replace(tcfg, iterations=8))


@pytest.mark.slow
def test_patch_covering_the_image_trains_on_full_frames(tmp_path, small_run_inputs):
    # The `cpu` preset's 200x200 patch on the built-in scene's 200x200 frames: the full-frame
    # path, the same run as patch 0, bit for bit; a smaller patch trains otherwise.
    from clrender.ndrf import train as ndrf_train

    teacher, ds = small_run_inputs
    tcfg = replace(ndrf_train.TRAIN_PRESETS["tiny"], iterations=6, n_distill=4,
                   checkpoint_every=6, log_every=1)
    states = {}
    for patch in (0, 24, 8):
        run = ndrf_train.train(ds, tmp_path / str(patch), teacher, preset="tiny",
                               progress=False, train_config=replace(tcfg, patch=patch))
        states[patch] = _features(run)[1]
    assert all(torch.equal(states[0][k], states[24][k]) for k in states[0])
    assert not all(torch.equal(states[0][k], states[8][k]) for k in states[0])


@pytest.mark.slow
def test_disk_backed_training_equals_in_memory(tmp_path, small_run_inputs, monkeypatch):
    """Views forced onto disk (a 1-byte budget) train the same model bit for bit as views in
    memory, also when the disk-backed run is interrupted and resumed; the budget is not in
    the run's config, so a run resumes whatever its budget; no file is left behind."""
    from clrender.ndrf import train as ndrf_train

    teacher, ds = small_run_inputs
    tcfg = replace(ndrf_train.TRAIN_PRESETS["tiny"], iterations=12, n_distill=4,
                   checkpoint_every=6, log_every=1, patch=0)        # full frames: the boxes
    built = []
    build = ViewSet.build.__func__

    def spy(cls, *args, **kwargs):
        built.append(build(cls, *args, **kwargs))
        return built[-1]

    monkeypatch.setattr(ViewSet, "build", classmethod(spy))
    run_a = ndrf_train.train(ds, tmp_path / "a", teacher, preset="tiny", progress=False,
                             train_config=tcfg, view_budget="1T")
    assert [v.disk_backed for v in built] == [False, False]
    _train_stopped_at(monkeypatch, 6, ds, tmp_path / "b", teacher, preset="tiny",
                      progress=False, train_config=tcfg, view_budget=1)
    monkeypatch.setenv(VIEW_BUDGET_ENV, "0")
    run_b = ndrf_train.train(ds, tmp_path / "b", teacher, preset="tiny", progress=False,
                             train_config=tcfg)
    assert [v.disk_backed for v in built[2:]] == [True] * 4
    assert (run_a / "config.json").read_text() == (run_b / "config.json").read_text()
    (step_a, state_a), (step_b, state_b) = _features(run_a), _features(run_b)
    assert step_a == step_b == 12 and state_a.keys() == state_b.keys()
    for name in state_a:
        assert torch.equal(state_a[name], state_b[name]), name
    logs = [[(r["step"], r["phase"], r["view"], r["loss"]) for r in map(
        json.loads, (run / "log.jsonl").read_text().splitlines())] for run in (run_a, run_b)]
    assert logs[0] == logs[1] and {r[1] for r in logs[0]} == {"distill", "train"}
    assert sorted(p.name for p in run_a.iterdir()) == sorted(p.name for p in run_b.iterdir())
    assert not list(tmp_path.rglob(".ndrf-views-*"))


@pytest.mark.slow
def test_tiny_end_to_end(tiny_ndrf_student):
    """The suite's shared `tiny` student (tests/trained_models.py): trained from the shared
    NGP-RT teacher (meshes extracted, views distilled), baked, evaluated."""
    from clrender.data import load_dataset
    from clrender.evaluate import evaluate
    from clrender.metrics import psnr
    from clrender.ndrf.baked import load_baked

    scene, run, baked = (tiny_ndrf_student[k] for k in ("scene", "run", "student"))
    conf = json.loads((run / "config.json").read_text())
    assert conf["method"] == "ndrf"
    assert (run / "meshes" / "report.json").is_file() and (run / "distill.npz").is_file()
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert {e["phase"] for e in log} == {"distill", "train"}
    model = load_baked(baked)
    assert model.config.K == 2
    result = evaluate(baked, scene)
    train_ds, test_ds = load_dataset(scene, "train"), load_dataset(scene, "test")
    mean = train_ds.images.reshape(-1, 3).mean(0)
    constant = np.mean([psnr(np.broadcast_to(mean, gt.shape).astype(np.float32), gt)
                        for gt in test_ds.images])
    assert result["mean"]["psnr"] >= constant + 5.0, (result["mean"]["psnr"], constant)
