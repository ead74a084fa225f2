"""Numpy reference renderer: empty scenes, G never changes samples, early stop, and a
brute-force march of single rays without any empty-space skipping.

Tolerances: renders with and without G, and the brute-force march, take the same
samples in the same float32 order, so images, opacity, depth and n_occ must be equal
exactly; we allow 1e-6 absolute where a batched matmul (deferred MLP, ``mlp`` fusion) may
sum in a different order for a different batch size.
"""
import numpy as np
import pytest

from clrender.camera import Camera, generate_rays, look_at
from clrender.ngprt import render_ref
from clrender.ngprt.baked import BakedModel, build_distance_grid, build_mip, sparse_coarse_grid, \
    validate
from clrender.ngprt.config import T_STOP, preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_ref import (deferred_reference, features, march_reference,
                                       render_reference)
from clrender.ngprt.space import cell_index, lattice_end, lattice_t, lattice_table, ray_box, to_grid

F32 = np.float32
# Outside the content; the unbounded eye sits in the contracted shell (|x|_inf = 2.5).
EYES = {"bounded": (2.2, 1.5, 1.2), "unbounded": (2.5, -1.8, 0.9)}
INSIDE = (0.9, 0.9, 0.5)        # an unbounded eye amid the content: every ray hits


def make_model(scene, variant="separate-v", seed=1):
    cfg = preset("tiny", scene=scene, variant=variant, L_C=32, G_res=16, log2_T=12)
    return random_baked_model(cfg, seed=seed)


def camera(scene, size=32, eye=None):
    return Camera.from_fov(1.0, size, size, look_at(eye or EYES[scene]))


@pytest.fixture(scope="module", params=["bounded", "unbounded"])
def scene_model(request):
    return request.param, make_model(request.param)


def empty_model(scene):
    m = make_model(scene)
    a = dict(m.arrays)
    for lev in range(5):
        a[f"occupancy_{lev}"] = np.zeros_like(a[f"occupancy_{lev}"])
    a["G"] = np.full_like(a["G"], 255)
    a["coarse_block_index"] = np.full_like(a["coarse_block_index"], -1)
    a["coarse_blocks"] = a["coarse_blocks"][:0]
    model = BakedModel(m.config, m.gamma, a)
    validate(model)
    return model


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
def test_empty_occupancy_is_background(scene):
    bg = (0.2, 0.4, 0.6)
    out = render_reference(empty_model(scene), camera(scene, 16), background=bg)
    assert np.array_equal(out["rgb"], np.broadcast_to(np.asarray(bg, F32), (16, 16, 3)))
    assert np.all(out["n_occ"] == 0) and np.all(out["opacity"] == 0) and np.all(out["depth"] == 0)
    assert out["n_march"].sum() > 0


def test_G_changes_marching_points_only(scene_model):
    scene, model = scene_model
    cam = camera(scene)
    with_G = render_reference(model, cam, use_G=True)
    without = render_reference(model, cam, use_G=False)
    for name in ("rgb", "n_occ", "opacity", "depth"):
        assert np.array_equal(with_G[name], without[name]), name
    assert with_G["n_occ"].sum() > 50
    assert with_G["n_march"].sum() < without["n_march"].sum()
    assert with_G["n_march"].dtype == np.int32 and with_G["rgb"].dtype == F32


def test_opacity_depth_and_early_stop(scene_model, monkeypatch):
    scene, model = scene_model
    eye = INSIDE if scene == "unbounded" else None
    o, d = (a.reshape(-1, 3) for a in generate_rays(camera(scene, eye=eye)))
    out = march_reference(model, o, d)
    op = out["opacity"]
    assert np.all(op >= 0) and np.all(op <= 1 + 1e-6)
    hit = op > 0
    assert np.all(out["depth"][hit] >= model.config.near) and np.all(out["depth"][~hit] == 0)
    stopped = op > 1 - T_STOP                      # T fell below T_STOP on these rays
    assert stopped.sum() > 20
    # The same march without early termination: more samples, (almost) the same result.
    monkeypatch.setattr(render_ref, "T_STOP", 0.0)
    full = march_reference(model, o, d)
    assert np.all(full["n_occ"] >= out["n_occ"])
    assert full["n_occ"][stopped].sum() > out["n_occ"][stopped].sum()
    assert np.all(out["n_occ"][stopped] <= 12)      # opaque within a few samples
    np.testing.assert_allclose(full["opacity"], op, atol=T_STOP)
    np.testing.assert_allclose(full["acc"], out["acc"], atol=0.05)   # T < 2e-3 times |f| < 25


def brute_force_ray(model, o, d):
    """Scalar march visiting every lattice point, checking occupancy_0 only."""
    cfg = model.config
    unbounded = cfg.scene == "unbounded"
    s = F32(model.step)
    o, d = o[None].astype(F32), d[None].astype(F32)
    if unbounded:
        t_start, t_end = F32(cfg.near), F32(cfg.far)
    else:
        t_in, t_out = ray_box(o, d, 1.0)
        t_start, t_end = np.fmax(F32(cfg.near), t_in[0]), t_out[0]
    acc, T, opacity, n_occ = np.zeros(7, F32), F32(1), F32(0), 0
    if not t_start <= t_end:
        return acc, opacity, n_occ
    if unbounded:   # t_k = S^-1(k * s), S the contracted arc length from t_start
        table = lattice_table(o, d, np.array([t_start], F32), np.array([t_end], F32))
        g_end, k = lattice_end(table)[0], 0
        place = lambda g: lattice_t(table, np.array([g], F32))[0]   # noqa: E731
    else:
        g_end, k = t_end, int(np.ceil(t_start / s))
        place = lambda g: g   # noqa: E731
    while F32(k) * s < g_end and T >= F32(T_STOP):
        t = place(F32(k) * s)
        u = to_grid(o + t * d, cfg.extent, unbounded)
        if model.arrays["occupancy_0"][tuple(cell_index(u, cfg.L_C)[0])]:
            f = features(model, u)[0]
            g_next = F32(k + 1) * s
            t_next = (place(g_next) if g_next < g_end else t_end) if unbounded else g_next
            delta = t_next - t
            alpha = F32(1) - np.exp(-np.exp(f[0]) * delta)
            w = T * alpha
            acc, opacity, T = acc + w * f[1:8], opacity + w, T * (F32(1) - alpha)
            n_occ += 1
        k += 1
    return acc, opacity, n_occ


@pytest.mark.parametrize("scene,variant,eye,gamma", [
    ("bounded", "separate-v", None, 1.0), ("unbounded", "mlp", INSIDE, 1.9),
    ("unbounded", "shared-inv", None, 1.0), ("bounded", "sum", (0.3, -2.0, 1.6), 0.6)])
def test_skipping_matches_brute_force(scene, variant, eye, gamma):
    model = random_baked_model(make_model(scene, variant).config, seed=2, gamma=gamma)
    o, d = (a.reshape(-1, 3) for a in generate_rays(camera(scene, 24, eye)))
    out = march_reference(model, o, d)
    rng = np.random.default_rng(0)
    hits, misses = np.flatnonzero(out["n_occ"] > 0), np.flatnonzero(out["n_occ"] == 0)
    rays = np.concatenate([rng.choice(hits, 12, replace=False),
                           rng.choice(misses, min(3, len(misses)), replace=False)])
    brute = [brute_force_ray(model, o[i], d[i]) for i in rays]
    assert [b[2] for b in brute] == out["n_occ"][rays].tolist()
    acc = np.stack([b[0] for b in brute])
    opacity = np.array([b[1] for b in brute], F32)
    np.testing.assert_allclose(acc, out["acc"][rays], rtol=0, atol=1e-6)
    np.testing.assert_allclose(opacity, out["opacity"][rays], rtol=0, atol=1e-6)
    rgb_ref = deferred_reference(model, out["acc"][rays], d[rays])
    rgb_brute = deferred_reference(model, acc, d[rays])
    np.testing.assert_allclose(rgb_brute, rgb_ref, rtol=0, atol=1e-6)
    assert np.all(out["n_march"][rays] >= out["n_occ"][rays])


def test_unbounded_last_interval_ends_at_far():
    """Occupied up to the edge of the contracted cube: the last interval ends at ``far``
    (the lattice's last point is short of S(far)), so everything stays finite."""
    m = make_model("unbounded")
    cfg, a = m.config, dict(m.arrays)
    occ = np.ones((cfg.L_C,) * 3, np.uint8)
    a["coarse_block_index"], a["coarse_blocks"] = sparse_coarse_grid(
        lambda c: np.full((len(c), cfg.coarse_channels), -4.0, F32), occ, cfg.coarse_block)
    for lev, grid in enumerate(build_mip(occ)):
        a[f"occupancy_{lev}"] = grid
    a["G"] = build_distance_grid(occ, cfg.G_res)
    model = BakedModel(cfg, 1.9, a)
    validate(model)
    out = render_reference(model, camera("unbounded", 8, INSIDE))
    assert all(np.all(np.isfinite(v)) for v in out.values())
    assert np.all(out["opacity"] > 0.99) and np.all(out["opacity"] <= 1 + 1e-6)
    assert np.all(out["depth"] < cfg.far)


def test_deferred_reference_is_the_documented_mlp(scene_model):
    """docs/ngprt.md "Deferred MLP", one pixel at a time in float64: within 1e-5 of the
    batched float32 reference (rgb in (0, 1); the float32 rounding of 23 -> 64 -> 64 -> 3
    products is ~1e-6)."""
    from clrender.ngprt.encoding import sh4

    scene, model = scene_model
    rng = np.random.default_rng(1)
    d = rng.normal(size=(50, 3)).astype(F32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    acc = rng.normal(size=(50, 7)).astype(F32)
    rgb = deferred_reference(model, acc, d)
    a = {k: v.astype(np.float64) for k, v in model.arrays.items() if k.startswith("deferred_")}
    for i in range(50):
        x = np.concatenate([acc[i, 0:3], acc[i, 3:7], sh4(d[i:i + 1])[0]]).astype(np.float64)
        h1 = np.maximum(x @ a["deferred_w0"] + a["deferred_b0"], 0.0)
        h2 = np.maximum(h1 @ a["deferred_w1"] + a["deferred_b1"], 0.0)
        logit = acc[i, 0:3] + h2 @ a["deferred_w2"] + a["deferred_b2"]
        np.testing.assert_allclose(rgb[i], 1.0 / (1.0 + np.exp(-logit)), rtol=0, atol=1e-5)
    assert rgb.shape == (50, 3) and rgb.dtype == F32
