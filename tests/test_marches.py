"""The marches of Table 4 (clrender/ngprt/marches.py, docs/ngprt.md "The marches"): the
kernels (exact build) against the numpy reference for each, bounded and unbounded, with
the read counts of the counting build (-D COUNT_READS).

Tolerances (stated, not tuned): marching points, occupied points and reads identical;
rgb, opacity and depth as tests/test_render_cl.py (1e-4). Between marches (reference):
identical samples and images (G changes which empty points are visited, never which
samples are taken). The counting build against the timed build: identical images.
"""
from __future__ import annotations

import numpy as np
import pytest

from clrender.ngprt.config import N_MIP, preset
from clrender.ngprt.marches import READ_KINDS, feature_reads
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer
from clrender.ngprt.render_ref import render_reference
from clrender.paths import path_cameras

MARCHES = [("paper", False), ("paper", True), ("ours", True)]     # Table 4's three
BACKGROUND = (1.0, 0.5, 0.25)


def _model(scene: str, L_C: int = 32, G_res: int = 16, seed: int = 0, **fields):
    config = preset("tiny", variant="separate-v", scene=scene, L_C=L_C, log2_T=11, G_res=G_res,
                    **fields)
    return random_baked_model(config, seed, 1.0)


def _camera(scene: str, size: int = 29):
    return path_cameras(scene, "orbit", 8, size, size)[1]


def _reads(out: dict) -> np.ndarray:
    """(H, W, 3) reads of a kernel render, as the reference returns them."""
    return np.stack([out[f"reads_{kind}"] for kind in READ_KINDS], axis=2)


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
@pytest.mark.parametrize("march,use_G", MARCHES + [("ours", False)])
def test_kernel_matches_reference_with_reads(scene, march, use_G):
    model, camera = _model(scene, seed=2), _camera(scene)
    renderer = Renderer(model, use_G=use_G, march=march, exact=True, count_reads=True)
    out = renderer.render(camera, background=BACKGROUND, stats=True)
    ref = render_reference(model, camera, background=BACKGROUND, use_G=use_G, march=march)
    assert out["n_occ"].sum() > 0 and (out["n_march"] > out["n_occ"]).any()
    assert (ref["reads"][..., 1].sum() > 0) == (use_G and march == "paper")   # G's step taken
    for key in ("n_march", "n_occ"):
        np.testing.assert_array_equal(out[key], ref[key], err_msg=key)
    np.testing.assert_array_equal(_reads(out), ref["reads"])
    np.testing.assert_array_equal(out["n_reads"], ref["reads"].sum(axis=2))
    np.testing.assert_array_equal(out["n_skip_reads"], ref["reads"][..., :2].sum(axis=2))
    np.testing.assert_allclose(out["rgb"], ref["rgb"], rtol=0, atol=1e-4)
    np.testing.assert_allclose(out["opacity"], ref["opacity"], rtol=0, atol=1e-4)
    np.testing.assert_allclose(out["depth"], ref["depth"], rtol=1e-4, atol=1e-6)
    # The timed build (no counters) renders the same image.
    np.testing.assert_array_equal(renderer.render(camera, background=BACKGROUND)["rgb"],
                                  out["rgb"])


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
def test_marches_take_the_same_samples_and_read_what_they_say(scene):
    model, camera = _model(scene, seed=2), _camera(scene, 31)
    outs = {(m, g): render_reference(model, camera, use_G=g, march=m) for m, g in MARCHES}
    base = outs[("paper", False)]
    for key, out in outs.items():
        np.testing.assert_array_equal(out["n_occ"], base["n_occ"], err_msg=str(key))
        np.testing.assert_array_equal(out["rgb"], base["rgb"], err_msg=str(key))
        np.testing.assert_array_equal(out["reads"][..., 2], base["n_occ"] * feature_reads(
            model.config))
    ours_no_G = render_reference(model, camera, use_G=False, march="ours")
    # Without G the paper's march and ours visit the same points; ours reads one code a
    # point, the paper 1..N_MIP bytes (N_MIP at a sample).
    np.testing.assert_array_equal(ours_no_G["n_march"], base["n_march"])
    np.testing.assert_array_equal(ours_no_G["reads"][..., 0], base["n_march"])
    occ = base["reads"][..., 0]
    assert np.all(occ >= N_MIP * base["n_occ"] + (base["n_march"] - base["n_occ"]))
    assert np.all(occ <= N_MIP * base["n_march"]) and (occ > base["n_march"]).any()
    assert base["reads"][..., 1].sum() == 0 and outs[("paper", True)]["reads"][..., 1].sum() > 0
    # Ours carries G in its exit codes (L_C / G_res a power of two): no G read of its own.
    assert outs[("ours", True)]["reads"][..., 1].sum() == 0


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
@pytest.mark.parametrize("march", ["paper", "ours"])
def test_G_read_from_its_grid_is_counted(scene, march):
    # L_C / G_res = 3: ours reads G itself too (render_cl.g_in_codes), one read each.
    model, camera = _model(scene, L_C=48, G_res=16, seed=3), _camera(scene, 27)
    renderer = Renderer(model, use_G=True, march=march, exact=True, count_reads=True, rays=4)
    out = renderer.render(camera, stats=True)
    ref = render_reference(model, camera, use_G=True, march=march)
    for key in ("n_march", "n_occ"):
        np.testing.assert_array_equal(out[key], ref[key], err_msg=key)
    np.testing.assert_array_equal(_reads(out), ref["reads"])
    assert ref["reads"][..., 1].sum() > 0


def test_unknown_march_is_refused():
    model = _model("bounded")
    with pytest.raises(ValueError, match=r"march 'walk': expected one of ours, paper"):
        Renderer(model, march="walk")
    with pytest.raises(ValueError, match=r"march 'walk'"):
        render_reference(model, _camera("bounded", 4), march="walk")


def test_reads_are_only_counted_when_asked():
    model, camera = _model("bounded"), _camera("bounded", 8)
    out = Renderer(model, march="paper", exact=True).render(camera, stats=True)
    assert not any(k.startswith("reads_") or k == "n_reads" for k in out)


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
def test_centre_metric_kernel_matches_reference(scene, cl_platform):
    """G of the paper's centre metric (longer steps, which may pass an occupied point): the
    kernel takes the reference's points and reads on PoCL and Intel's runtime."""
    from dataclasses import replace

    from clrender.ngprt.baked import build_distance_grid, validate

    box, camera = _model(scene, seed=2), _camera(scene)
    G = build_distance_grid(box.arrays["occupancy_0"], box.config.G_res, "centre")
    model = replace(box, G_metric="centre", arrays={**box.arrays, "G": G})
    validate(model)
    assert np.any(G > box.arrays["G"])
    out = Renderer(model, march="paper", exact=True, count_reads=True).render(
        camera, background=BACKGROUND, stats=True)
    ref = render_reference(model, camera, background=BACKGROUND, march="paper")
    for key in ("n_march", "n_occ"):
        np.testing.assert_array_equal(out[key], ref[key], err_msg=key)
    np.testing.assert_array_equal(_reads(out), ref["reads"])
    np.testing.assert_allclose(out["rgb"], ref["rgb"], rtol=0, atol=1e-4)
    assert ref["reads"][..., 1].sum() > 0                                 # G's step taken


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
@pytest.mark.parametrize("march,use_G", MARCHES)
def test_occupancy_finer_than_the_coarse_grid_matches_reference(scene, march, use_G,
                                                                 cl_platform):
    """The paper's grids at a small scale: occupancy at 4 L_C (its mip 128^3 .. 8^3) and G
    at 2 L_C, the coarse cell the occupancy cell shifted right by 2: the kernel takes the
    reference's points and reads and renders its image (1e-4) on PoCL and Intel's runtime;
    G's step is taken, and with box G the samples are those of the march without G."""
    model, camera = _model(scene, G_res=64, seed=2, occupancy_res=128), _camera(scene)
    assert model.config.occ_shift == 2
    out = Renderer(model, march=march, use_G=use_G, exact=True, count_reads=True).render(
        camera, background=BACKGROUND, stats=True)
    ref = render_reference(model, camera, background=BACKGROUND, march=march, use_G=use_G)
    assert out["n_occ"].sum() > 0 and (out["n_march"] > out["n_occ"]).any()
    for key in ("n_march", "n_occ"):
        np.testing.assert_array_equal(out[key], ref[key], err_msg=key)
    np.testing.assert_array_equal(_reads(out), ref["reads"])
    np.testing.assert_allclose(out["rgb"], ref["rgb"], rtol=0, atol=1e-4)
    without = render_reference(model, camera, background=BACKGROUND, march="paper",
                               use_G=False)
    np.testing.assert_array_equal(ref["n_occ"], without["n_occ"])
    np.testing.assert_array_equal(ref["rgb"], without["rgb"])
    if march == "paper" and use_G:
        assert ref["reads"][..., 1].sum() > 0                             # G's step taken
