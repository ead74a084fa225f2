"""Holes found in the NGP-RT march and in model validation (docs/ngprt.md).

* The bounded empty-space skip must never pass a lattice point whose ``occupancy_0`` cell
  is occupied, also for rays with a tiny direction component, where the float32 exit
  distance of a cell is off by many ulps. Brute force: >= 100k near-axis rays at L_C 512,
  gamma 0.5, against an independent enumeration of every occupied lattice point per ray;
  the OpenCL kernel must take exactly the reference's points on such rays.
* Validation: configs and gammas that would divide by zero, overflow an int shift or let
  a march run (almost) forever are refused with a message naming the field and value.

Tolerances: none; lattice points are compared as exact counts.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from clrender.camera import Camera, generate_rays, look_at
from clrender.ngprt.baked import BakedFormatError, BakedModel, validate
from clrender.ngprt.config import MAX_LATTICE_POINTS, ModelConfig, preset
from clrender.ngprt.random_model import empty_model_with_occupancy, random_baked_model
from clrender.ngprt.render_ref import march_reference, ray_range
from clrender.ngprt.space import cell_index, to_grid

F32 = np.float32
L_C, GAMMA = 512, 0.5
H = 2.0 / L_C                           # world size of a coarse cell
# Thin occupied patches (one cell thick along `axis`, 8 x 8 cells across), at a multiple
# of 16 (a face of every mip level) and at odd cells: (axis, index along axis, (b, c)).
PATCHES = [(0, 96, (300, 140)), (0, 331, (60, 400)), (1, 208, (410, 90)),
           (1, 149, (120, 250)), (2, 352, (200, 330)), (2, 77, (380, 20))]
P = 8
N_RAYS = 120_000


def _patch_boxes() -> list[tuple[np.ndarray, np.ndarray]]:
    """Cell index boxes [lo, hi) of the patches."""
    boxes = []
    for axis, c, (b0, b1) in PATCHES:
        lo = np.array([b0, b1])
        lo = np.insert(lo, axis, c)
        hi = lo + P
        hi[axis] = c + 1
        boxes.append((lo, hi))
    return boxes


@pytest.fixture(scope="module")
def patch_model():
    """A bounded L_C = 512 model that is empty but for the thin patches; densities are
    negligible (sigma = e^-30) so no ray ever stops early."""
    cfg = ModelConfig(L=1, L_C=L_C, log2_T=4, variant="sum", scene="bounded", G_res=128,
                      coarse_block=8, near=0.0)
    occ = np.zeros((L_C,) * 3, np.uint8)
    for lo, hi in _patch_boxes():
        occ[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = 1
    return empty_model_with_occupancy(cfg, occ, GAMMA)


def near_axis_rays(n: int, seed: int = 0, tiny_range=(2e-4, 4e-3)):
    """(n, 3) float32 origins and unit directions with one component of magnitude in
    [2e-4, 4e-3], each crossing the face of a patch (the one the tiny component points
    into) at a random point of the face, 0.02 to 0.5 world units from its origin."""
    rng = np.random.default_rng(seed)
    boxes = _patch_boxes()
    which = rng.integers(0, len(PATCHES), n)
    axis = np.array([p[0] for p in PATCHES])[which]
    tiny = np.exp(rng.uniform(*np.log(tiny_range), n)) * rng.choice([-1.0, 1.0], n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    rest = np.sqrt(1.0 - tiny ** 2)
    d = np.empty((n, 3))
    lo = np.stack([boxes[j][0] for j in which]) * H - 1.0
    hi = np.stack([boxes[j][1] for j in which]) * H - 1.0
    q = rng.uniform(lo - H, hi + H)            # a little around the face: grazing rays too
    rows = np.arange(n)
    others = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    d[rows, axis] = tiny
    d[rows, others[:, 0]] = rest * np.cos(phi)
    d[rows, others[:, 1]] = rest * np.sin(phi)
    q[rows, axis] = np.where(tiny > 0, lo[rows, axis], hi[rows, axis])
    o = q - rng.uniform(0.02, 0.5, n)[:, None] * d
    d = d.astype(F32)
    d = d / np.sqrt((d * d).sum(axis=1, keepdims=True))
    return o.astype(F32), d.astype(F32)


def occupied_lattice_points(model, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(N,) number of lattice points k of each ray whose ``occupancy_0`` cell is occupied.

    Independent of the march: per patch, the lattice indices near the ray's float64
    passage through the patch's box grown by a quarter cell (with a margin of 6 steps,
    far more than float32 positions can be off for |d_a| >= 2e-4), each tested in
    float32 exactly as the contract places it (t_k = k * s, u = to_grid(o + t_k * d),
    cell_index)."""
    cfg, s = model.config, F32(model.step)
    occ = model.arrays["occupancy_0"]
    t_start, t_end, hit = ray_range(cfg, o, d)
    with np.errstate(invalid="ignore", over="ignore"):
        k0 = np.where(hit, np.ceil(t_start / s), 0).astype(np.int64)
    o64, d64 = o.astype(np.float64), d.astype(np.float64)
    keys = []
    for lo, hi in _patch_boxes():
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = ((lo - 0.25) * H - 1.0 - o64) / d64
            tb = ((hi + 0.25) * H - 1.0 - o64) / d64
        t0 = np.fmax.reduce(np.fmin(ta, tb), axis=1)
        t1 = np.fmin.reduce(np.fmax(ta, tb), axis=1)
        rays = np.flatnonzero(hit & (t0 <= t1))
        first = np.floor(t0[rays] / s).astype(np.int64) - 6
        count = np.ceil(t1[rays] / s).astype(np.int64) + 6 - first + 1
        ray = np.repeat(rays, count)
        k = np.repeat(first, count) + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count,
                                                                         count)
        t = k.astype(F32) * s
        u = to_grid(o[ray] + t[:, None] * d[ray], 1.0, False)
        c = cell_index(u, cfg.L_C)
        keep = (k >= k0[ray]) & (t < t_end[ray]) & (occ[c[:, 0], c[:, 1], c[:, 2]] != 0)
        keys.append(ray[keep] * (1 << 32) + k[keep])
    keys = np.unique(np.concatenate(keys))
    return np.bincount(keys >> 32, minlength=len(o))


@pytest.mark.parametrize("use_G,march", [(False, "ours"), (True, "ours"), (True, "paper")])
def test_bounded_skip_never_passes_an_occupied_lattice_point(patch_model, use_G, march):
    o, d = near_axis_rays(N_RAYS, seed=int(use_G))
    want = occupied_lattice_points(patch_model, o, d)
    got = march_reference(patch_model, o, d, use_G=use_G, march=march)["n_occ"]
    assert want.sum() > 3 * N_RAYS and np.count_nonzero(want) > 0.6 * N_RAYS
    # Every sample is an occupied lattice point; so equal counts mean none was skipped.
    missed = np.flatnonzero(got != want)
    assert len(missed) == 0, (
        f"{len(missed)} of {N_RAYS} near-axis rays skip lattice points in occupied cells "
        f"({int((want - got)[missed].sum())} points); first: ray {missed[0]}, o={o[missed[0]]}, "
        f"d={d[missed[0]]}, occupied points {want[missed[0]]}, sampled {got[missed[0]]}")


def patch_cameras(size: int = 32) -> list[Camera]:
    """One camera per patch whose rays all have a component of ~1e-3 along the patch's
    thin axis: the eye sits 3e-4 below the face the rays rise into, 0.3 away across it,
    and the rows' tiny slopes make the rays cross the face over the whole patch."""
    rng = np.random.default_rng(7)
    cams = []
    for (axis, _, _), (lo, hi) in zip(PATCHES, _patch_boxes()):
        up = np.zeros(3)
        up[axis] = 1.0
        centre = (lo + hi) / 2 * H - 1.0
        centre[axis] = lo[axis] * H - 1.0 - 3e-4
        away = np.cross(up, rng.normal(size=3))
        eye = centre + 0.3 * away / np.linalg.norm(away)
        b_min, b_max = 3e-4 / 0.33, 3e-4 / 0.27       # slopes crossing the face at 0.27..0.33
        fy = (size - 1) / (b_max - b_min)
        cams.append(Camera(size / 0.1, fy, size / 2, b_min * fy + size - 0.5, size, size,
                           look_at(eye, centre, up)))
    return cams


def test_kernel_takes_every_occupied_point_like_the_reference(patch_model, cl_platform):
    from clrender.ngprt.render_cl import Renderer

    renderer = Renderer(patch_model, use_G=True)
    total = 0
    for cam in patch_cameras():
        o, d = (a.reshape(-1, 3) for a in generate_rays(cam))
        assert np.abs(d).min(axis=1).max() < 2e-3
        out = renderer.march(cam)
        ref = march_reference(patch_model, o, d, use_G=True)
        np.testing.assert_array_equal(out["n_occ"], ref["n_occ"])
        np.testing.assert_array_equal(out["n_march"], ref["n_march"])
        np.testing.assert_array_equal(out["n_occ"], occupied_lattice_points(patch_model, o, d))
        total += int(ref["n_occ"].sum())
    assert total > 20_000


# ---- validation ---------------------------------------------------------------------

@pytest.mark.parametrize("field,value", [
    ("L_C", 0), ("L_C", 32.0), ("L_C", -16), ("L_C", 2048), ("L", 0), ("L", 30), pytest.param("L", 10**30, id="L-10**30"),
    ("L", True), ("log2_T", 12.5), ("log2_T", 25), ("coarse_block", 0), ("G_res", 0),
    ("aux_levels", 0), ("aux_hidden", 2**40), ("aux_min_res", 64), ("near", math.nan),
    ("near", -1.0), ("far", math.inf), ("far", math.nan), ("far", 1e7), ("far", "1000"),
    ("variant", None), ("scene", "Bounded"), ("step_res", 0), ("step_res", 1.5),
    ("step_res", True)])
def test_config_refuses_with_field_and_value(field, value):
    with pytest.raises(ValueError, match="invalid ModelConfig") as err:
        preset("tiny", **{field: value})
    assert field in str(err.value) and str(value) in str(err.value), str(err.value)


@pytest.fixture(scope="module")
def tiny_model():
    return random_baked_model(preset("tiny", L_C=16, G_res=8, log2_T=8), seed=1)


@pytest.mark.parametrize("gamma,fragment", [
    (1e-9, "gamma=1e-09 is too small"), (1e-300, "too small"), (5e-324, "too small"),
    (0.0, "gamma must be finite and > 0"), (-2.0, "> 0"), (math.nan, "> 0"), (math.inf, "> 0"),
    (1e300, "gamma=1e+300 is too large"), pytest.param(10**400, "401 digits", id="10**400"), ("1.0", "not a number"),
    (True, "not a number"), (None, "not a number")])
def test_validate_refuses_gamma(tiny_model, gamma, fragment):
    with pytest.raises(BakedFormatError, match="^m.npz: ") as err:
        validate(BakedModel(tiny_model.config, gamma, tiny_model.arrays), "m.npz")
    assert fragment in str(err.value), str(err.value)


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
def test_lattice_bound_is_the_documented_maximum(tiny_model, scene):
    cfg = preset("tiny", L_C=16, G_res=8, log2_T=8, scene=scene)
    validate(BakedModel(cfg, cfg.min_gamma * 1.001, tiny_model.arrays))
    with pytest.raises(BakedFormatError, match=f"more than {MAX_LATTICE_POINTS}"):
        validate(BakedModel(cfg, cfg.min_gamma * 0.999, tiny_model.arrays))
    assert MAX_LATTICE_POINTS * 4 < 2**31        # k, k + 1 and the skip's k + 2 fit int32
