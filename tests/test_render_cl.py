"""OpenCL NGP-RT renderer (kernels/ngprt_*.cl), exact build, against the numpy reference
(render_ref.py); the fast build is held to the exact one in tests/test_render_fast.py.

Random structured baked models (clrender.ngprt.random_model), small sizes, PoCL on the CPU,
with the device's lane widths and with one ray / pixel per work-item (a GPU's layout).
Tolerances (stated, not tuned): rgb max abs 1e-4; opacity abs 1e-4; depth relative 1e-4;
marching and occupied points identical (positions and cells are bit-identical by
construction, docs/ngprt.md). G on vs off: identical occupied points, images within 1e-6,
strictly fewer marching points in total.
"""
from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest

from clrender.camera import generate_rays
from clrender.ngprt.config import VARIANTS, preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt import render_cl
from clrender.ngprt.render_cl import Renderer
from clrender.ngprt.render_ref import march_reference, render_reference
from clrender.paths import path_cameras

SIZE = 32
BACKGROUND = (1.0, 0.5, 0.25)
CORNER_SPHERES = [("sphere", 0.75 * np.array(c, float), np.full(3, 0.12))
                  for c in itertools.product((-1, 1), repeat=3)]


def _model(variant: str, scene: str, L: int = 2, seed: int = 0):
    config = preset("tiny", variant=variant, scene=scene, L=L, L_C=32, log2_T=11, G_res=16)
    return random_baked_model(config, seed, 1.0)


def _camera(scene: str, size: int = SIZE):
    return path_cameras(scene, "orbit", 8, size, size)[1]


def _assert_matches(out: dict, ref: dict):
    np.testing.assert_array_equal(out["n_occ"], ref["n_occ"])
    np.testing.assert_array_equal(out["n_march"], ref["n_march"])
    np.testing.assert_allclose(out["rgb"], ref["rgb"], rtol=0, atol=1e-4)
    np.testing.assert_allclose(out["opacity"], ref["opacity"], rtol=0, atol=1e-4)
    np.testing.assert_allclose(out["depth"], ref["depth"], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_render_matches_reference(variant, scene, cl_platform):
    model, camera = _model(variant, scene), _camera(scene)
    out = Renderer(model, use_G=True, exact=True).render(camera, background=BACKGROUND,
                                                       stats=True)
    ref = render_reference(model, camera, background=BACKGROUND, use_G=True)
    assert out["rgb"].shape == (SIZE, SIZE, 3) and out["rgb"].dtype == np.float32
    assert out["n_occ"].sum() > 0, "test model has no occupied sample in view"
    _assert_matches(out, {k: np.asarray(v).reshape(out[k].shape) for k, v in ref.items()
                          if k in out})


@pytest.mark.parametrize("rays,deferred_vec", [(1, 1), (4, 2)])
@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
@pytest.mark.parametrize("variant", ["separate-v", "mlp", "shared-inv"])
def test_lane_widths_match_reference(variant, scene, rays, deferred_vec, cl_platform):
    model, camera = _model(variant, scene, seed=4), _camera(scene, 29)
    out = Renderer(model, use_G=True, exact=True, rays=rays,
                   deferred_vec=deferred_vec).render(camera, background=BACKGROUND, stats=True)
    ref = render_reference(model, camera, background=BACKGROUND, use_G=True)
    assert out["n_occ"].sum() > 0, "test model has no occupied sample in view"
    _assert_matches(out, ref)


@pytest.mark.parametrize("in_constant", [True, False])
def test_deferred_weights_in_either_memory_match_reference(in_constant, monkeypatch,
                                                           cl_platform):
    # Both builds of the deferred MLP's weight argument (-D DEFERRED_CONSTANT), whichever
    # the device would choose.
    monkeypatch.setattr(render_cl, "deferred_in_constant", lambda device: in_constant)
    model, camera = _model("separate-v", "bounded"), _camera("bounded")
    renderer = Renderer(model, use_G=True, exact=True)
    assert renderer.deferred_constant is in_constant
    out = renderer.render(camera, background=BACKGROUND, stats=True)
    ref = render_reference(model, camera, background=BACKGROUND, use_G=True)
    _assert_matches(out, {k: np.asarray(v).reshape(out[k].shape) for k, v in ref.items()
                          if k in out})


def test_deferred_weights_in_constant_only_where_they_fit():
    fits = SimpleNamespace(max_constant_buffer_size=64 << 10, max_constant_args=8)
    assert render_cl.deferred_in_constant(fits)
    assert not render_cl.deferred_in_constant(SimpleNamespace(max_constant_buffer_size=16 << 10,
                                                              max_constant_args=8))
    assert not render_cl.deferred_in_constant(SimpleNamespace(max_constant_buffer_size=64 << 10,
                                                              max_constant_args=0))


def test_lane_width_is_a_cpus_native_width_and_a_gpus_preferred_one():
    def device(kind, preferred, native):
        return SimpleNamespace(type=getattr(cl.device_type, kind),
                               preferred_vector_width_float=preferred,
                               native_vector_width_float=native)
    assert render_cl.lane_width(device("CPU", 1, 16)) == 16   # Intel's CPU runtime
    assert render_cl.lane_width(device("CPU", 16, 16)) == 16  # PoCL, AVX-512
    assert render_cl.lane_width(device("CPU", 1, 8)) == 8     # AVX2
    assert render_cl.lane_width(device("CPU", 1, 16), cap=4) == 4
    assert render_cl.lane_width(device("CPU", 1, 6)) == 4     # rounded down to a vector width
    assert render_cl.lane_width(device("GPU", 1, 1)) == 1
    assert render_cl.lane_width(device("GPU", 1, 4)) == 1


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
def test_distance_grid_read_from_G_matches_reference(scene, cl_platform):
    # L_C / G_res = 3 is no power of two: the kernel reads G itself instead of from the
    # exit codes (render_cl.g_in_codes).
    config = preset("tiny", variant="separate-v", scene=scene, L_C=48, log2_T=11, G_res=16)
    model, camera = random_baked_model(config, 3, 1.0), _camera(scene, 27)
    out = Renderer(model, use_G=True, exact=True).render(camera, background=BACKGROUND,
                                                         stats=True)
    ref = render_reference(model, camera, background=BACKGROUND, use_G=True)
    assert out["n_occ"].sum() > 0, "test model has no occupied sample in view"
    _assert_matches(out, ref)


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
def test_three_levels_march_matches_reference(scene, cl_platform):
    model, camera = _model("separate-v", scene, L=3, seed=1), _camera(scene, 24)
    out = Renderer(model, use_G=False, exact=True).march(camera)
    origins, dirs = (a.reshape(-1, 3) for a in generate_rays(camera))
    ref = march_reference(model, origins, dirs, use_G=False)
    np.testing.assert_array_equal(out["n_occ"], ref["n_occ"])
    np.testing.assert_array_equal(out["n_march"], ref["n_march"])
    scale = max(1.0, float(np.abs(ref["acc"]).max()))
    np.testing.assert_allclose(out["acc"], ref["acc"], rtol=0, atol=1e-4 * scale)
    np.testing.assert_allclose(out["opacity"], ref["opacity"], rtol=0, atol=1e-4)
    np.testing.assert_allclose(out["depth"], ref["depth"], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
def test_step_finer_than_the_coarse_grid_matches_reference(scene, cl_platform):
    # step_res = 2 L_C (the cpu preset's ratio): two lattice points per coarse voxel
    # diagonal; the march, G's skips and the lattice are the reference's.
    config = preset("tiny", variant="separate-v", scene=scene, L_C=32, log2_T=11, G_res=16,
                    step_res=64)
    model, camera = random_baked_model(config, 3, 1.0), _camera(scene, 27)
    assert model.step == pytest.approx(np.sqrt(3.0) / 32, rel=1e-6)
    with_g = Renderer(model, use_G=True, exact=True).render(camera, background=BACKGROUND,
                                                            stats=True)
    without = Renderer(model, use_G=False, exact=True).render(camera, background=BACKGROUND,
                                                              stats=True)
    assert with_g["n_occ"].sum() > 0, "test model has no occupied sample in view"
    _assert_matches(with_g, render_reference(model, camera, background=BACKGROUND, use_G=True))
    np.testing.assert_array_equal(with_g["n_occ"], without["n_occ"])
    assert with_g["n_march"].sum() < without["n_march"].sum()


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_distance_grid_skips_only_empty_space(variant, scene, cl_platform):
    # Eight small spheres in the corners of the box leave its centre empty down to mip
    # level 3 (cells coarser than G's), more than a coarse cell from any content: rays
    # across it read G, whose ball reaches past the empty mip cells they are in.
    config = preset("tiny", variant=variant, scene=scene, L=2, L_C=32, log2_T=11, G_res=16)
    model, camera = random_baked_model(config, 0, 1.0, shapes=CORNER_SPHERES), _camera(scene)
    with_g = Renderer(model, use_G=True).render(camera, stats=True)
    without = Renderer(model, use_G=False).render(camera, stats=True)
    np.testing.assert_array_equal(with_g["n_occ"], without["n_occ"])
    np.testing.assert_allclose(with_g["rgb"], without["rgb"], rtol=0, atol=1e-6)
    assert with_g["n_march"].sum() < without["n_march"].sum()


def test_render_video_writes_png_frames(tmp_path):
    from clrender.ngprt.baked import save_baked
    from clrender.video import render_path

    path = tmp_path / "model.npz"
    save_baked(_model("separate-v", "bounded"), path)
    out = render_path(path, tmp_path / "frames", path="orbit", frames=3, width=16, height=12)
    pngs = sorted(p.name for p in out.iterdir())
    assert pngs == ["frame_0000.png", "frame_0001.png", "frame_0002.png"]
    import imageio.v3 as iio

    assert iio.imread(out / pngs[0]).shape == (12, 16, 3)
