"""NGP-RT training, baking and evaluation: torch twins of the numpy primitives, the lattice
and compositing against straightforward loops over docs/ngprt.md, and (slow) a tiny
model trained on the built-in scene, baked, and rendered by torch and by OpenCL."""
import math

import numpy as np
import pytest
import torch

from clrender.ngprt import encoding, space
from clrender.ngprt import torch_ops as ops
from clrender.ngprt.config import T_STOP, preset
from clrender.ngprt.model import NGPRT

@pytest.fixture
def rng():
    """A generator of its own for each test (seed 7): a test's inputs do not depend on which
    tests ran before it."""
    return np.random.default_rng(7)


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(a))


# -- torch twins == numpy primitives (bit for bit on CPU, same float32 operations) --------

def test_contract_and_lattice_match_numpy(rng):
    x = (rng.normal(size=(20000, 3)) * rng.choice([0.3, 3.0, 300.0], (20000, 1))).astype(np.float32)
    assert np.array_equal(ops.contract(_t(x)).numpy(), space.contract(x))
    o = x[:2000]
    d = rng.normal(size=(2000, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t0, t1 = np.full(2000, np.float32(0.05)), np.full(2000, np.float32(1000.0))
    table = space.lattice_table(o, d, t0, t1)
    table_t = ops.lattice_table(_t(o), _t(d), _t(t0), _t(t1))
    for a, b in zip(table, table_t):
        assert np.array_equal(a, b.numpy())
    g = (rng.uniform(0, 1, 2000) * space.lattice_end(table)).astype(np.float32)
    assert np.array_equal(space.lattice_t(table, g), ops.lattice_t(table_t, _t(g)).numpy())
    for unbounded in (False, True):
        assert np.array_equal(ops.to_grid(_t(x), 2.0, unbounded).numpy(),
                              space.to_grid(x, 2.0, unbounded))
    u = rng.uniform(-0.1, 1.1, (5000, 3)).astype(np.float32)
    assert np.array_equal(ops.cell_index(_t(u), 64).numpy(), space.cell_index(u, 64))


def test_ray_box_matches_numpy(rng):
    o = (rng.normal(size=(5000, 3)) * 3).astype(np.float32)
    d = rng.normal(size=(5000, 3)).astype(np.float32)
    d[:100, 0] = 0.0                                           # axis-parallel rays
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for a, b in zip(ops.ray_box(_t(o), _t(d)), space.ray_box(o, d)):
        assert np.array_equal(a.numpy(), b)


@pytest.mark.parametrize("log2_T", [4, 14, 22])
def test_hash_matches_numpy(log2_T, rng):
    i = rng.integers(-3, 1 << 13, (3, 20000))
    ref = encoding.hash_corner(*i, 1 << log2_T)
    assert np.array_equal(ops.hash_corner(*map(_t, i), 1 << log2_T).numpy(), ref)


def test_sh4_matches_numpy(rng):
    d = rng.normal(size=(5000, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(ops.sh4(_t(d)).numpy(), encoding.sh4(d), rtol=0, atol=1e-6)


def test_fine_lookup_matches_contract(rng):
    """docs/ngprt.md "Fine level l": trilinear over hashed corners of R_l = L_C * 2^(l+1)."""
    cfg = preset("tiny", L=3)
    model = NGPRT(cfg)
    with torch.no_grad():
        model.fine_tables.normal_()
    tables = model.fine_tables.detach().numpy()
    u = rng.uniform(0, 1, (3000, 3)).astype(np.float32)
    got = model.fine(_t(u)).detach().numpy()
    for l, R in enumerate(cfg.fine_resolutions):
        p = u * np.float32(R)
        i = np.floor(p).astype(np.int64)
        w = p - i
        ref = np.zeros((len(u), 8), np.float32)
        for c in range(8):
            o = ((c >> 2) & 1, (c >> 1) & 1, c & 1)
            h = encoding.hash_corner(i[:, 0] + o[0], i[:, 1] + o[1], i[:, 2] + o[2], cfg.T)
            wc = np.prod([w[:, a] if o[a] else 1 - w[:, a] for a in range(3)], axis=0)
            ref += wc[:, None] * tables[l][h]
        np.testing.assert_allclose(got[:, l], ref, rtol=0, atol=1e-5)


def test_grid_lookup_gradient():
    tab = torch.randn(3, 200, 4, dtype=torch.float64, requires_grad=True)
    u = torch.rand(40, 3, dtype=torch.float64)
    assert torch.autograd.gradcheck(
        lambda t: ops.grid_lookup(t, u, [3, 5, 9], [True, False, False]), (tab,))


def test_grid_lookup_on_vertices_is_trilinear_at_vertices():
    """Levels read at their vertices (the auxiliary NGP's L_C level at the L_C corners):
    one row each gives the trilinear features and table gradients exactly."""
    R_c = 16
    tab = torch.randn(4, 1 << 10, 4, requires_grad=True)
    ijk = torch.randint(0, R_c + 1, (300, 3))
    u = ijk.to(torch.float32) / R_c
    res, dense = [4, 8, 16, 32], [True, False, False, False]
    tri = ops.grid_lookup(tab, u, res, dense)
    g = torch.randn_like(tri)
    (grad_tri,) = torch.autograd.grad(tri, tab, g)
    vert = ops.grid_lookup(tab, u, res, dense, on_vertices=2)
    (grad_vert,) = torch.autograd.grad(vert, tab, g)
    assert torch.equal(vert, tri) and torch.equal(grad_vert, grad_tri)
    dense_tab = torch.randn(2, 5 ** 3, 3, dtype=torch.float64, requires_grad=True)
    u4 = torch.randint(0, 5, (20, 3)).double() / 4                 # vertices of level 4
    assert torch.autograd.gradcheck(lambda t: ops.grid_lookup(
        t, u4, [2, 4], [True, True], on_vertices=1), (dense_tab,))
    assert NGPRT(preset("cpu")).aux.on_vertices == 1          # the level at L_C itself


# -- lattice and compositing against loops over the contract ------------------------------

def _lattice_loop(o, d, occ, s, cfg):
    """The march of docs/ngprt.md, one lattice point at a time (no skipping)."""
    unb = cfg.scene == "unbounded"
    if unb:
        t_start, t_end = np.float32(cfg.near), np.float32(cfg.far)
    else:
        t_in, t_out = space.ray_box(o[None], d[None])
        t_start, t_end = max(np.float32(cfg.near), t_in[0]), t_out[0]
    s = np.float32(s)
    if unb:
        table = space.lattice_table(o[None], d[None], np.array([t_start]), np.array([t_end]))
        g_end, k = space.lattice_end(table)[0], 0
    else:
        g_end, k = t_end, int(np.ceil(t_start / s))
    out = []
    while np.float32(k) * s < g_end:
        g = np.float32(k) * s
        t = space.lattice_t(table, np.array([g]))[0] if unb else g
        u = space.to_grid((o + t * d)[None], cfg.extent, unb)
        c = space.cell_index(u, occ.shape[0])[0]
        if occ[tuple(c)]:
            out.append((k, float(t)))
        k += 1
    return out


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
def test_lattice_samples_match_loop(scene, rng):
    cfg = preset("tiny", scene=scene)
    occ = rng.random((cfg.L_C,) * 3) < 0.3
    o = (rng.normal(size=(12, 3)) * 1.5).astype(np.float32)
    d = rng.normal(size=(12, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s = float(np.float32(0.7 * cfg.s0))
    ids, k, t, delta, u = ops.lattice_samples(_t(o), _t(d), _t(occ), s, cfg.near, cfg.far,
                                              cfg.extent, scene == "unbounded")
    for r in range(len(o)):
        ref = _lattice_loop(o[r], d[r], occ, s, cfg)
        got = list(zip(k[ids == r].tolist(), t[ids == r].tolist()))
        assert got == ref


def test_composite_matches_sequential_loop():
    n_rays = 5
    counts = [0, 3, 7, 1, 12]
    ids = torch.repeat_interleave(torch.arange(n_rays), torch.tensor(counts))
    sigma = torch.rand(len(ids)) * 40
    delta = torch.rand(len(ids)) * 0.1
    w = ops.composite_weights(sigma, delta, ids, n_rays, T_STOP)
    for r in range(n_rays):
        T, ref = 1.0, []
        for sg, dl in zip(sigma[ids == r].tolist(), delta[ids == r].tolist()):
            alpha = 1 - math.exp(-sg * dl)
            ref.append(T * alpha if T >= T_STOP else 0.0)
            T *= 1 - alpha
        np.testing.assert_allclose(w[ids == r].numpy(), ref, rtol=1e-5, atol=1e-7)


def test_an_infinite_optical_depth_stops_its_ray_and_no_other():
    """A sample whose density overflows float32 (sigma = inf) is opaque: its ray's weights
    end there and the other rays of the batch keep the weights they have without it (the
    packed running sum would otherwise give inf - inf = NaN to every later ray)."""
    ids = torch.tensor([0, 0, 1, 1, 1, 2, 2])
    sigma = torch.tensor([1.0, 2.0, 3.0, float("inf"), 4.0, 5.0, 6.0])
    delta = torch.full((7,), 0.1)
    w = ops.composite_weights(sigma, delta, ids, 3)
    assert bool(torch.isfinite(w).all())
    T1 = math.exp(-0.3)
    torch.testing.assert_close(w[2:5], torch.tensor([1 - T1, T1, 0.0]), rtol=1e-6, atol=0)
    keep = ids != 1
    torch.testing.assert_close(w[keep], ops.composite_weights(sigma[keep], delta[keep],
                                                              torch.tensor([0, 0, 2, 2]), 3))


@pytest.mark.parametrize("unbounded", [False, True])
def test_distortion_loss_matches_pairwise_sum(unbounded):
    """Eq. S2 summed over all pairs: on lattice intervals [k*s, (k+1)*s] (bounded), on
    [g(t), g(t + delta)] with mip-NeRF 360's g (unbounded)."""
    ids = torch.tensor([0, 0, 0, 2, 2, 2, 2])
    k = torch.tensor([3, 5, 6, 1, 2, 3, 9])
    t = torch.tensor([0.3, 0.9, 1.5, 0.2, 0.6, 2.0, 7.0])
    delta = torch.tensor([0.5, 0.4, 2.0, 0.3, 0.5, 3.0, 20.0])
    w, s = torch.rand(7), 0.1
    lo, hi = ops.distortion_intervals(k, t, delta, s, unbounded)
    got = ops.distortion_loss(w, lo, hi, ids, 3)
    g = lambda x: x if x <= 1 else 2 - 1 / x  # noqa: E731
    for r in range(3):
        sel = (ids == r).nonzero()[:, 0].tolist()
        ww = w[sel].double()
        if unbounded:
            a = torch.tensor([g(float(t[i])) for i in sel], dtype=torch.float64)
            b = torch.tensor([g(float(t[i] + delta[i])) for i in sel], dtype=torch.float64)
        else:
            a = k[sel].double() * s
            b = a + s
        m = (a + b) / 2
        ref = (ww[:, None] * ww[None] * (m[:, None] - m[None]).abs()).sum() \
            + (ww ** 2 * (b - a)).sum() / 3
        assert float(got[r]) == pytest.approx(float(ref), rel=1e-5, abs=1e-7)


def test_tune_gamma_and_schedule():
    from clrender.ngprt.train import TRAIN_PRESETS, schedule, tune_gamma

    tc = TRAIN_PRESETS["paper"]
    assert tune_gamma(1.0, 5.0, tc) == 1.0
    assert tune_gamma(0.5, 5.0, tc) == pytest.approx(0.5005)
    assert tune_gamma(0.5, 2.0, tc) == pytest.approx(0.4995)
    assert tune_gamma(0.2217, 0.0, tc) == 0.2217
    assert schedule(999, tc)[0] == pytest.approx(0.01)            # warm-up ends at 1k
    assert schedule(50_000, tc)[1] == pytest.approx(0.01)         # eta warm over 50k
    assert schedule(99_999, tc)[0] < 1e-6


def test_presets_change_sizes_and_counts_never_the_method():
    from dataclasses import asdict

    from clrender.ngprt.config import PRESETS
    from clrender.ngprt.train import TRAIN_PRESETS

    assert set(PRESETS) == set(TRAIN_PRESETS)
    sizes = {"L_C", "step_res", "log2_T", "G_res", "aux_levels", "aux_log2_T"}
    counts = {"iterations", "max_rays", "target_samples", "occ_every", "occ_warmup",
              "occ_decay", "occ_fraction", "checkpoint_every", "log_every"}
    for name in PRESETS:
        model = {k for k, v in asdict(PRESETS[name]).items() if v != asdict(PRESETS["paper"])[k]}
        train = {k for k, v in asdict(TRAIN_PRESETS[name]).items()
                 if v != asdict(TRAIN_PRESETS["paper"])[k]}
        assert model <= sizes and train <= counts, name
    # The quality preset is the cpu model with larger fine tables, trained longer.
    assert PRESETS["cpu-long"].log2_T > PRESETS["cpu"].log2_T
    assert TRAIN_PRESETS["cpu-long"].iterations > TRAIN_PRESETS["cpu"].iterations


def test_size_options_change_the_table_or_the_batch_alone():
    """``log2_T`` and ``batch`` (training options, for comparing our sizes with the paper's):
    None keeps the preset's configs and cache spec; a value changes its own sizes (the ray
    cap scaled with the batch) and the cache spec; out-of-range values are refused."""
    from dataclasses import asdict

    from bench.train_curve import option_values
    from clrender.ngprt.method import model_spec
    from clrender.ngprt.train import TRAIN_PRESETS, sized

    base_cfg, base_tcfg = sized("cpu-long")
    assert (base_cfg, base_tcfg) == (preset("cpu-long"), TRAIN_PRESETS["cpu-long"])
    cfg, tcfg = sized("cpu-long", log2_T=21)
    assert cfg.log2_T == 21 and tcfg == base_tcfg
    assert {k for k, v in asdict(cfg).items() if v != asdict(base_cfg)[k]} == {"log2_T"}
    cfg, tcfg = sized("cpu-long", batch=1 << 17)
    assert cfg == base_cfg
    assert (tcfg.target_samples, tcfg.max_rays) == (1 << 17, 4 * base_tcfg.max_rays)
    assert {k for k, v in asdict(tcfg).items() if v != asdict(base_tcfg)[k]} == \
        {"target_samples", "max_rays"}
    specs = [model_spec("cpu-long", **o) for o in ({}, {"log2_T": 21}, {"batch": 1 << 17})]
    assert len({repr(s) for s in specs}) == 3
    with pytest.raises(ValueError, match="batch=512"):
        sized("cpu-long", batch=512)
    assert option_values("ngprt", "log2_T=19,21") == ("log2_T", [19, 21])
    with pytest.raises(ValueError, match="batch"):
        option_values("ngprt", "batch=512")


def test_size_options_reach_the_run(tmp_path):
    """A run trained with ``log2_T`` and ``batch`` records them in config.json, its model
    has tables of that size and its batches stay under the scaled ray cap."""
    import json

    from clrender.data import make_scene
    from clrender.ngprt.train import train

    data = make_scene("bounded", tmp_path / "scene", seed=0, n_train=4, n_test=1, width=16,
                      height=16)
    run = train(data, tmp_path / "run", preset="tiny", iterations=3, device="cpu",
                progress=False, log2_T=12, batch=1 << 12)
    conf = json.loads((run / "config.json").read_text())
    assert conf["model"]["log2_T"] == 12
    assert (conf["train"]["target_samples"], conf["train"]["max_rays"]) == (1 << 12, 512)
    state = torch.load(run / "checkpoint.pt", weights_only=True)["model"]
    assert any(v.shape[-2:] == (1 << 12, 8) for v in state.values())
    rays = [json.loads(line)["rays"] for line in (run / "log.jsonl").read_text().splitlines()]
    assert rays and max(rays) <= 512


def test_fused_adam_follows_the_default_adam():
    """make_optimizer's fused CPU Adam against torch's default Adam on the same gradients:
    parameters within 1e-6 after 20 steps (float32 rounding of a reordered update; the
    parameters are ~1e-4 .. 1, the updates ~lr = 1e-2)."""
    from clrender.ngprt.train import TRAIN_PRESETS, make_optimizer

    tcfg = TRAIN_PRESETS["tiny"]
    torch.manual_seed(0)
    models = [NGPRT(preset("tiny")) for _ in range(2)]
    models[1].load_state_dict(models[0].state_dict())
    fused = make_optimizer(models[0], tcfg)
    assert fused.param_groups[0]["fused"]
    plain = torch.optim.Adam(models[1].parameters(), lr=tcfg.lr, betas=tuple(tcfg.betas),
                             eps=tcfg.eps)
    g = torch.Generator().manual_seed(1)
    for _ in range(20):
        for pa, pb in zip(models[0].parameters(), models[1].parameters()):
            pa.grad = torch.randn(pa.shape, generator=g) * 1e-2
            pb.grad = pa.grad.clone()
        fused.step()
        plain.step()
    for pa, pb in zip(models[0].parameters(), models[1].parameters()):
        torch.testing.assert_close(pa, pb, rtol=0, atol=1e-6)


# -- trained tiny model (slow): tiny_run, the suite's shared model (tests/trained_models.py) -

@pytest.mark.slow
def test_baked_file_validates_and_loads(tiny_run):
    from clrender.ngprt.baked import load_baked

    model = load_baked(tiny_run["baked"])
    cfg = model.config
    assert cfg == preset("tiny", scene="bounded")
    assert model.arrays["fine_tables"].shape == (cfg.L, cfg.T, 8)
    occ0 = model.arrays["occupancy_0"]
    assert occ0.shape == (cfg.L_C,) * 3 and 0 < occ0.sum() < occ0.size
    assert 0.2217 <= model.gamma <= 1.0


@pytest.mark.slow
def test_torch_render_matches_opencl(tiny_run):
    """The shared model (trained by the fast engine: fused C++ grid lookups; the engine is
    recorded in config.json) rendered by torch on the baked occupancy and the OpenCL
    render of its baked file: >= 40 dB between them (both float32; they differ by rounding
    only), on the dataset's background and on the default one; its checkpoint evaluates
    on the torch engine."""
    import json

    from clrender.metrics import psnr
    from clrender.ngprt.baked import load_baked
    from clrender.ngprt.model import render_image
    from clrender.ngprt.render_cl import Renderer
    from clrender.ngprt.train import load_run

    try:
        import clrender.ngprt.fused  # noqa: F401
    except ImportError:                              # no fast engine here: torch trained
        pass
    else:
        assert json.loads((tiny_run["run"] / "config.json").read_text())["engine"] == "fast"
    model, _, gamma, _ = load_run(tiny_run["run"], "cpu")
    assert model.engine.name == "torch"
    baked = load_baked(tiny_run["baked"])
    occ0 = torch.from_numpy(baked.arrays["occupancy_0"] != 0)
    renderer = Renderer(baked)
    bg = tuple(float(v) for v in tiny_run["test"].background)
    for cam in tiny_run["test"].cameras:
        ref = render_image(model, cam, occ0, baked.gamma, bg, step=baked.step)["rgb"]
        got = renderer.render(cam, background=bg)["rgb"]
        assert psnr(got, ref) >= 40.0
        ref = render_image(model, cam, occ0, baked.gamma, step=baked.step)["rgb"]
        got = renderer.render(cam)["rgb"]
        assert psnr(got, ref) >= 40.0
        assert ref.std() > 0.01                      # a model that learned something


@pytest.mark.slow
def test_trained_model_beats_constant_colour(tiny_run):
    """Baked model (OpenCL) vs the mean training colour, on the test views. Measured
    figures are in the report of this change; 5 dB is far below the measured gap, and far
    above what a model that learned nothing (a blurred mean) could reach."""
    from clrender.metrics import psnr
    from clrender.evaluate import evaluate

    result = evaluate(tiny_run["baked"], tiny_run["data"])
    mean_colour = tiny_run["train"].images.reshape(-1, 3).mean(0)
    const = np.mean([psnr(np.broadcast_to(mean_colour, im.shape), im)
                     for im in tiny_run["test"].images])
    assert result["mean"]["psnr"] >= const + 5.0


@pytest.mark.slow
@pytest.mark.parametrize("variant,engine", [
    *[(v, "torch") for v in ("sum", "mlp", "shared-inv", "separate-inv", "shared-v",
                             "separate-v")]])
def test_every_variant_bakes_and_renders_like_torch(tiny_run, tmp_path, variant, engine):
    """Briefly trained (the weights only need to be non-trivial) by ``engine``, baked, then
    torch and OpenCL renders of one test view: >= 40 dB apart (separate-v on the fast
    engine: the shared model, test_torch_render_matches_opencl)."""
    from clrender.metrics import psnr
    from clrender.ngprt.bake import bake_run
    from clrender.ngprt.baked import load_baked
    from clrender.ngprt.model import render_image
    from clrender.ngprt.render_cl import Renderer
    from clrender.ngprt.train import load_run, train

    run = train(tiny_run["data"], tmp_path / "run", preset="tiny", variant=variant, L=2,
                iterations=40, device="cpu", progress=False, engine=engine)
    baked = load_baked(bake_run(run, tmp_path / "model.npz", n_rays=4096))
    model, _, _, _ = load_run(run, "cpu")
    cam = tiny_run["test"].cameras[0]
    occ0 = torch.from_numpy(baked.arrays["occupancy_0"] != 0)
    ref = render_image(model, cam, occ0, baked.gamma, step=baked.step)["rgb"]
    got = Renderer(baked).render(cam)["rgb"]
    assert psnr(got, ref) >= 40.0


@pytest.mark.slow
def test_cli_and_api_from_run_to_video(tiny_run, tmp_path, capsys):
    """The user path: `clrender bake`, `clrender eval`, `clrender render --out x.mp4`, and
    `clrender.render(path, camera, stats=True)` on the same trained run."""
    import imageio.v3 as iio

    import clrender
    from clrender import cli

    model = tmp_path / "model.npz"
    assert cli.main(["bake", str(tiny_run["run"]), "--out", str(model)]) == 0
    assert cli.main(["eval", str(model), str(tiny_run["data"])]) == 0
    assert "psnr" in capsys.readouterr().out.lower()
    video = tmp_path / "orbit.mp4"
    assert cli.main(["render", str(model), "--frames", "4", "--width", "32", "--height", "24",
                     "--out", str(video)]) == 0
    frames = iio.imread(video, index=None)
    assert frames.shape[0] == 4 and frames.shape[1:3] == (24, 32) and frames.std() > 1.0
    assert cli.main(["render", str(model), "--frames", "2", "--width", "33", "--height", "24",
                     "--out", str(tmp_path / "odd.mp4")]) == 2
    assert "even width and height, got 33x24" in capsys.readouterr().err
    assert not (tmp_path / "odd.mp4").exists()
    cam = tiny_run["test"].cameras[0]
    rgb, stats = clrender.render(str(model), cam, stats=True)
    assert rgb.shape == (cam.height, cam.width, 3) and rgb.dtype == np.float32
    assert stats["n_occ"].sum() > 0 and np.all(stats["n_march"] >= stats["n_occ"])
    np.testing.assert_array_equal(rgb, clrender.render(clrender.load(model), cam))
    centre = tmp_path / "centre.npz"
    assert cli.main(["bake", str(tiny_run["run"]), "--out", str(centre), "--G-metric",
                     "centre"]) == 0
    box_model, centre_model = clrender.load(model), clrender.load(centre)
    assert (box_model.G_metric, centre_model.G_metric) == ("box", "centre")
    for name, a in box_model.arrays.items():     # the same bake but for G
        assert np.array_equal(a, centre_model.arrays[name]) or name == "G", name
    assert np.all(centre_model.arrays["G"] >= box_model.arrays["G"])
    with pytest.raises(SystemExit):             # argparse: not one of the choices
        cli.main(["bake", str(tiny_run["run"]), "--out", str(tmp_path / "x.npz"),
                  "--G-metric", "chebyshev"])
    # The paper's grids: occupancy 512^3 .. 32^3 and G 256^3 from the same training run,
    # within the preset's occupied cells, the coarse grid and weights as baked before;
    # the same scene rendered (>= 30 dB against the preset grids' image).
    paper = tmp_path / "paper.npz"
    assert cli.main(["bake", str(tiny_run["run"]), "--out", str(paper), "--grids", "paper"]) == 0
    fine = clrender.load(paper)
    assert (fine.config.occ_res, fine.config.G_res, fine.config.L_C) == (512, 256, 32)
    occ = fine.arrays["occupancy_0"].reshape((32, 16) * 3).max(axis=(1, 3, 5))
    assert 0 < fine.arrays["occupancy_0"].sum() and np.all(occ <= box_model.arrays["occupancy_0"])
    for name in ("coarse_blocks", "coarse_block_index", "fine_tables", "deferred_w0"):
        np.testing.assert_array_equal(fine.arrays[name], box_model.arrays[name], err_msg=name)
    from clrender.metrics import psnr
    assert psnr(clrender.render(fine, cam), rgb) >= 30.0


@pytest.mark.slow
def test_on_step_hook_fires_after_every_step_and_changes_nothing(tmp_path, one_torch_thread):
    """``train(on_step=...)``: called after each iteration with the live state; the run's
    checkpoint is bit-identical to one trained without the hook (one torch thread; a hook
    drawing one random number moves every later batch, 2e-2)."""
    from clrender.data import make_scene
    from clrender.ngprt.train import OccupancyGrid, train

    data = make_scene("bounded", tmp_path / "scene", seed=0, n_train=6, n_test=1, width=24,
                      height=24)
    calls = []

    def hook(step, model, occ, gamma):
        assert isinstance(model, NGPRT) and isinstance(occ, OccupancyGrid)
        calls.append((step, gamma))

    runs = [train(data, tmp_path / name, preset="tiny", iterations=12, device="cpu",
                  progress=False, on_step=h) for name, h in (("hook", hook), ("plain", None))]
    assert [s for s, _ in calls] == list(range(12))
    with_hook, plain = (torch.load(r / "checkpoint.pt", weights_only=True) for r in runs)
    assert with_hook["gamma"] == plain["gamma"] == calls[-1][1]
    torch.testing.assert_close(with_hook["occ_ema"], plain["occ_ema"], rtol=0, atol=0)
    torch.testing.assert_close(with_hook["model"], plain["model"], rtol=0, atol=0)


def _poisoned_render(monkeypatch, bad_steps):
    """NGP-RT training whose colours are NaN at the calls ``bad_steps`` (0-based) of its
    render: the loss and every gradient of those steps are not finite."""
    from clrender.ngprt import train as ngprt_train

    render, calls = ngprt_train.render_rays, []

    def poisoned(*args, **kwargs):
        r = render(*args, **kwargs)
        if len(calls) in bad_steps:
            r = {**r, "rgb": r["rgb"] * float("nan")}
        calls.append(1)
        return r

    monkeypatch.setattr(ngprt_train, "render_rays", poisoned)


def test_a_step_with_a_nonfinite_loss_is_skipped_counted_and_saved(tmp_path, monkeypatch):
    """A step whose loss and gradients are NaN leaves the model as it was (no Adam step,
    so no NaN reaches a parameter), is counted in the log and the checkpoint, and its
    batch and model are saved to reproduce it; the steps around it train."""
    import json

    from clrender.data import make_scene
    from clrender.ngprt.train import train

    data = make_scene("bounded", tmp_path / "scene", seed=0, n_train=6, n_test=1, width=24,
                      height=24)
    _poisoned_render(monkeypatch, {2})
    states = {}

    def hook(step, model, occ, gamma):
        states[step] = {k: v.detach().clone() for k, v in model.state_dict().items()}

    run = train(data, tmp_path / "run", preset="tiny", iterations=5, device="cpu",
                progress=False, on_step=hook)
    torch.testing.assert_close(states[2], states[1], rtol=0, atol=0)
    assert any(not torch.equal(states[3][k], states[2][k]) for k in states[2])
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    assert ckpt["skipped"] == 1
    assert all(bool(torch.isfinite(v).all()) for v in ckpt["model"].values())
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert log[-1]["skipped"] == 1
    saved = torch.load(run / "nonfinite-step-2.pt", weights_only=True)
    assert saved["step"] == 2 and saved["origins"].shape == saved["target"].shape
    torch.testing.assert_close(saved["model"], states[1], rtol=0, atol=0)


def test_a_run_of_nonfinite_steps_stops_with_an_error(tmp_path, monkeypatch):
    """MAX_NONFINITE_IN_A_ROW skipped steps in a row stop the run with an error naming it."""
    from clrender import runs
    from clrender.data import make_scene
    from clrender.ngprt import train as ngprt_train

    data = make_scene("bounded", tmp_path / "scene", seed=0, n_train=4, n_test=1, width=16,
                      height=16)
    monkeypatch.setattr(runs, "MAX_NONFINITE_IN_A_ROW", 3)
    _poisoned_render(monkeypatch, {1, 3, 4, 5})
    with pytest.raises(RuntimeError, match="3 training steps in a row up to step 5"):
        ngprt_train.train(data, tmp_path / "run", preset="tiny", iterations=8, device="cpu",
                          progress=False)


def test_run_resumes_under_the_other_engine(tmp_path):
    """A checkpoint written by the torch engine resumes under the fast one (the engine is
    free in the run's config; config.json then names the new engine)."""
    import json
    from dataclasses import replace

    from clrender.data import make_scene
    from clrender.ngprt.train import TRAIN_PRESETS, train

    pytest.importorskip("clrender.ngprt.fused")
    data = make_scene("bounded", tmp_path / "scene", seed=0, n_train=4, n_test=1, width=16,
                      height=16)
    tcfg = replace(TRAIN_PRESETS["tiny"], iterations=4, checkpoint_every=2, log_every=1)

    def stop(step, *_):
        if step == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(data, tmp_path / "run", preset="tiny", device="cpu", progress=False,
              train_config=tcfg, on_step=stop, engine="torch")
    run = train(data, tmp_path / "run", preset="tiny", device="cpu", progress=False,
                train_config=tcfg, engine="fast")
    steps = [json.loads(line)["step"] for line in (run / "log.jsonl").read_text().splitlines()]
    assert steps == [0, 1, 2, 2, 3]                     # resumed from the step-2 checkpoint
    assert json.loads((run / "config.json").read_text())["engine"] == "fast"
    assert torch.load(run / "checkpoint.pt", weights_only=True)["step"] == 4


def test_fast_engine_falls_back_to_torch_where_it_does_not_run(tmp_path, monkeypatch, capsys):
    """`fast` on CUDA or without its C++ extension (no compiler) trains with the torch
    engine, says so in one line, and config.json names the engine that trained."""
    import json

    from clrender.data import make_scene
    from clrender.ngprt import engine as engines
    from clrender.ngprt import fused
    from clrender.ngprt.train import train

    assert engines.get("fast", torch.device("cuda")) is engines.TORCH
    assert "runs on the CPU only" in capsys.readouterr().err

    def no_compiler():
        raise RuntimeError("Error building extension\nninja: g++: not found")

    monkeypatch.setattr(fused, "build", no_compiler)
    assert engines.get("fast", torch.device("cpu")) is engines.TORCH
    err = capsys.readouterr().err
    assert "did not build" in err and "g++: not found" in err and len(err.splitlines()) == 1
    data = make_scene("bounded", tmp_path / "scene", seed=0, n_train=2, n_test=1, width=8,
                      height=8)
    run = train(data, tmp_path / "run", preset="tiny", iterations=1, device="cpu",
                progress=False, engine="fast")
    assert json.loads((run / "config.json").read_text())["engine"] == "torch"
