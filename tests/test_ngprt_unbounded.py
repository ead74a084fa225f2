"""The unbounded empty-space skip (docs/ngprt.md "skip", render_ref.skip_unbounded): a
closed-form jump through the contraction's projective regions, then a point test.

* Every occupied lattice point is taken: brute force over every lattice point of every
  ray (placed in float32 exactly as the contract places it), on a model that is empty
  but for small occupied boxes in the inner cube and in the contracted shell, with
  negligible density so no ray stops early. Rays: random, near an axis, and from the
  centre along directions whose contracted coordinates sit on cell faces (float32
  rounding makes such points hop between two cells).
* The closed form takes exactly the marching points of a walk point by point (the
  previous contract), with G and without.
* The OpenCL kernel takes the reference's points (exact counts) on camera views inside
  the inner cube and in the shell.

Tolerances: none; lattice points are compared as exact counts.
"""
from __future__ import annotations

import numpy as np
import pytest

from clrender.camera import Camera, generate_rays, look_at
from clrender.ngprt import render_ref
from clrender.ngprt.baked import validate
from clrender.ngprt.config import ModelConfig
from clrender.ngprt.random_model import empty_model_with_occupancy
from clrender.ngprt.render_ref import _cells, _lattice_g, _point_u, march_reference, ray_range
from clrender.ngprt.space import (cell_index, lattice_end, lattice_jumps, lattice_rows, lattice_t,
                                  lattice_table,
                                  to_grid)

F32 = np.float32
L_C, G_RES, GAMMA = 64, 32, 0.5
N_RAYS = 6000


@pytest.fixture(scope="module")
def box_model():
    """Unbounded, L_C = 64: 14 random occupied boxes of 2-6 cells, half of them in the
    contracted shell (u outside [1/4, 3/4]); sigma = e^-30 everywhere."""
    cfg = ModelConfig(L=1, L_C=L_C, log2_T=4, variant="sum", scene="unbounded", G_res=G_RES,
                      coarse_block=8, near=0.0, far=1000.0)
    rng = np.random.default_rng(5)
    occ = np.zeros((L_C,) * 3, np.uint8)
    for i in range(14):
        size = rng.integers(2, 7, 3)
        lo = rng.integers(16, 48 - 6, 3) if i % 2 else rng.integers(0, L_C - 6, 3)
        occ[lo[0]:lo[0] + size[0], lo[1]:lo[1] + size[1], lo[2]:lo[2] + size[2]] = 1
    model = empty_model_with_occupancy(cfg, occ, GAMMA)
    validate(model)
    return model


def _unit(d: np.ndarray) -> np.ndarray:
    d = d.astype(F32)
    return (d / np.sqrt((d * d).sum(axis=1, keepdims=True))).astype(F32)


def _uncontract(c: np.ndarray) -> np.ndarray:
    """World points of (M, 3) contracted points c (|c|_inf < 2), float64."""
    m = np.abs(c).max(axis=1, keepdims=True)
    scale = np.where(m <= 1.0, 1.0, 1.0 / (2.0 - m) / np.maximum(m, 1.0))
    x = c * scale
    outer = (m[:, 0] > 1.0)
    a = np.abs(c).argmax(axis=1)
    rows = np.flatnonzero(outer)
    x[rows, a[rows]] = np.sign(c[rows, a[rows]]) / (2.0 - m[rows, 0])
    return x


def make_rays(model, n: int = N_RAYS, seed: int = 0):
    """(n, 3) float32 origins and unit directions: two thirds pass through random points
    of random occupied cells from 0.2 to 6 world units away, half of them with one
    direction component of 1e-4 .. 1e-2; a third start near the centre along directions
    with small-integer ratios (contracted coordinates on cell faces, where float32
    rounding hops between two cells)."""
    rng = np.random.default_rng(seed)
    m = n // 3
    d = rng.normal(size=(n, 3))
    axis = rng.integers(0, 3, m)
    d[m + np.arange(m), axis] = rng.uniform(1e-4, 1e-2, m) * rng.choice([-1, 1], m)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cells = np.argwhere(model.arrays["occupancy_0"] != 0)
    pick = cells[rng.integers(0, len(cells), n)] + rng.uniform(0.0, 1.0, (n, 3))
    o = _uncontract(pick / L_C * 4.0 - 2.0) - rng.uniform(0.2, 6.0, (n, 1)) * d
    ratios = rng.integers(-8, 9, (n - 2 * m, 3)).astype(np.float64)
    ratios[np.abs(ratios).max(axis=1) == 0] = (8.0, 4.0, 2.0)
    d[2 * m:] = ratios
    o[2 * m:] = rng.uniform(-1e-3, 1e-3, (n - 2 * m, 3))
    return o.astype(F32), _unit(d)


def occupied_lattice_points(model, o: np.ndarray, d: np.ndarray, chunk: int = 1500):
    """(N,) number of lattice points of each ray whose occupancy_0 cell is occupied:
    every k with 0 <= k and k * s < S(t_end), placed as the contract places it."""
    cfg, s = model.config, F32(model.step)
    occ = model.arrays["occupancy_0"]
    t_start, t_end, hit = ray_range(cfg, o, d)
    table = lattice_table(o, d, t_start, t_end)
    g_end = lattice_end(table)
    n_k = int(np.ceil(g_end.max() / s)) + 2
    out = np.zeros(len(o), np.int64)
    for a in range(0, len(o), chunk):
        rows = np.arange(a, min(a + chunk, len(o)))
        k = np.broadcast_to(np.arange(n_k)[None, :], (len(rows), n_k))
        g = _lattice_g(k, s)
        keep = hit[rows, None] & (g < g_end[rows, None])
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            rep_rows = np.repeat(rows, n_k)
            t = lattice_t(lattice_rows(table, rep_rows), g.reshape(-1)).reshape(g.shape)
            p = o[rows, None, :] + t[..., None] * d[rows, None, :]
            u = to_grid(np.where(keep[..., None], p, F32(0.0)), 2.0, True)
        c = cell_index(u, L_C)
        out[rows] = (keep & (occ[c[..., 0], c[..., 1], c[..., 2]] != 0)).sum(axis=1)
    return out


def walk_skip(model, k, o, d, u, exit_lev, g, s, g_end, table):
    """The skip as a walk point by point (the contract before the closed form)."""
    cfg = model.config
    res = cfg.L_C >> exit_lev
    cell = _cells(u, res)
    radius = g.astype(F32) / F32(cfg.G_res)
    k = k + 1
    walking = _lattice_g(k, s) < g_end
    while walking.any():
        w = np.flatnonzero(walking)
        uk = _point_u(cfg, o[w], d[w], lattice_t(lattice_rows(table, w), _lattice_g(k[w], s)))
        du = uk - u[w]
        dist = np.sqrt(du[:, 0] * du[:, 0] + du[:, 1] * du[:, 1] + du[:, 2] * du[:, 2])
        stay = np.all(_cells(uk, res[w]) == cell[w], axis=1) | ((g[w] > 0) & (dist < radius[w]))
        k[w[stay]] += 1
        walking[w] = stay & (_lattice_g(k[w], s) < g_end[w])
    return k


@pytest.mark.parametrize("use_G,march", [(True, "ours"), (False, "ours"), (True, "paper")])
def test_every_occupied_lattice_point_is_taken(box_model, use_G, march):
    o, d = make_rays(box_model, seed=int(use_G))
    want = occupied_lattice_points(box_model, o, d)
    got = march_reference(box_model, o, d, use_G=use_G, march=march)
    assert want.sum() > N_RAYS and np.count_nonzero(want) > N_RAYS // 4
    assert np.all(got["n_march"] >= got["n_occ"])
    missed = np.flatnonzero(got["n_occ"] != want)
    assert len(missed) == 0, (
        f"{len(missed)} of {N_RAYS} rays skip occupied lattice points; first: ray {missed[0]}, "
        f"o={o[missed[0]]}, d={d[missed[0]]}, occupied {want[missed[0]]}, "
        f"sampled {got['n_occ'][missed[0]]}")


def test_lattice_jumps_are_the_outer_regions_changes():
    # From inside the cube along (0.6, -0.9, -0.1): the split where |y| = |z| inside the
    # cube, the cube's face x = 1 and the split of the x+ region where y = -1 keep the
    # contracted path continuous; |x| = |y| outside the cube (x+ region to y- region)
    # makes it jump.
    o = np.array([[0.5, 0.0, 0.3]], F32)
    d = _unit(np.array([[0.6, -0.9, -0.1]]))
    brk, cum, *_ = lattice_table(o, d, np.zeros(1, F32), np.full(1, 40.0, F32))
    jumps = lattice_jumps(o, d, brk)[0]
    x = (o[0] + brk[0][:, None] * d[0])[1:-1]
    inside_split = np.isclose(np.abs(x[:, 1]), np.abs(x[:, 2]), atol=1e-5) & \
        (np.abs(x).max(axis=1) < 1)
    face = np.isclose(x[:, 0], 1.0, atol=1e-5)
    outer_split = np.isclose(x[:, 1], -1.0, atol=1e-5) & (x[:, 0] > 1)
    outer_tie = np.isclose(np.abs(x[:, 0]), np.abs(x[:, 1]), atol=1e-4) & (x[:, 0] > 1)
    for kind in (inside_split, face, outer_split, outer_tie):
        assert kind.sum() == 1
    assert not jumps[1:-1][inside_split | face | outer_split].any()
    assert jumps[1:-1][outer_tie].all() and jumps.sum() == 1
    assert not jumps[0] and not jumps[-1]


def test_paper_g_step_passes_continuous_breaks_and_stops_at_jumps(box_model):
    # A ray's contracted path is continuous across the cube's face and across splits of a
    # region, so G's step passes them; across a jump arc length bounds nothing, so the
    # step stops at the first lattice point at or past it, and from that point (it may lie
    # on the jump itself, off the next piece's segment) takes one point (bonsai, when every
    # piece's first point was not held: one ray in 4 views skipped 3 occupied points).
    from clrender.ngprt.marches import paper_g_step_unbounded

    cfg, s = box_model.config, F32(box_model.step)
    o = np.array([[0.5, 0.0, 0.3]], F32)
    d = _unit(np.array([[0.6, -0.9, -0.1]]))
    t_start, t_end, _ = ray_range(cfg, o, d)
    table = lattice_table(o, d, t_start, t_end)
    jumps = lattice_jumps(o, d, table[0])
    cum = table[1][0]
    (q,) = np.flatnonzero(jumps[0])[:1]
    assert np.any(~jumps[0][1:q]), "no continuous break before the jump to pass"

    def first_at_or_past(c: float) -> int:
        k = int(np.ceil(c / s))
        return k - int(F32(k - 1) * s >= c)

    def step(k: int) -> int:
        return int(paper_g_step_unbounded(cfg, np.array([k]), np.array([255]), s, table,
                                          jumps)[0])

    at_jump = first_at_or_past(cum[q])
    assert step(0) == at_jump                       # passes the face, stops at the jump
    assert step(at_jump) == at_jump + 1             # one point from the jump's first
    assert step(at_jump + 1) > at_jump + 2          # then G's full step again


@pytest.mark.parametrize("use_G", [True, False])
def test_closed_form_takes_the_walks_marching_points(box_model, use_G, monkeypatch):
    o, d = make_rays(box_model, seed=2 + int(use_G))
    closed = march_reference(box_model, o, d, use_G=use_G)
    monkeypatch.setattr(render_ref, "skip_unbounded", walk_skip)
    walked = march_reference(box_model, o, d, use_G=use_G)
    np.testing.assert_array_equal(closed["n_march"], walked["n_march"])
    np.testing.assert_array_equal(closed["n_occ"], walked["n_occ"])


def _cameras(size: int = 24) -> list[Camera]:
    eyes = [(0.3, -0.4, 0.2), (2.5, -1.8, 0.9), (-6.0, 3.0, 1.5), (0.001, 0.0005, 0.0)]
    targets = [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.5, 0.25)]
    return [Camera.from_fov(1.2, size, size, look_at(e, t)) for e, t in zip(eyes, targets)]


def test_kernel_takes_the_references_points(box_model, cl_platform):
    from clrender.ngprt.render_cl import Renderer

    total = 0
    for use_G, march in ((True, "ours"), (False, "ours"), (True, "paper")):
        renderer = Renderer(box_model, use_G=use_G, exact=True, march=march)
        for cam in _cameras():
            o, d = (a.reshape(-1, 3) for a in generate_rays(cam))
            out = renderer.march(cam)
            ref = march_reference(box_model, o, d, use_G=use_G, march=march)
            np.testing.assert_array_equal(out["n_occ"], ref["n_occ"])
            np.testing.assert_array_equal(out["n_march"], ref["n_march"])
            np.testing.assert_array_equal(ref["n_occ"], occupied_lattice_points(box_model, o, d))
            total += int(ref["n_occ"].sum())
    assert total > 1000
