"""The fast engine's fused stages against their torch_ops specifications, on random
inputs.

Tolerances, stated before tuning:
- grid lookup (hashed, dense and on-vertices levels): features within 1e-6 absolute
  (tables ~N(0, 1), 8 products summed in float32: the gather rounds its sums in its own
  order, embedding_bag in its); table gradients bit for bit (the same float32 products
  summed in bincount's order, sample then corner), for one thread and for two.
- the auxiliary NGP (encoding + MLP): outputs within 1e-5 of their largest magnitude,
  every gradient within 1e-5 of its largest magnitude (fused multiply-adds and another
  summation order than torch's matmuls; float32 sums of up to 3000 terms); bit for bit
  the same for one thread and two (fixed chunks summed in order); the same tolerance for a
  build without AVX (4-float vectors, each product rounded).
- the coarse corners and their de-duplication: bit for bit.
- the bounded step lattice's occupied samples: bit for bit.
"""
import platform

import pytest
import torch

from clrender.ngprt import torch_ops as ops

fused = pytest.importorskip("clrender.ngprt.fused")

CASES = {
    # fine levels: hashed, 8 features
    "hashed": ([64, 128, 256], None, 0, 1 << 12, 8),
    # auxiliary NGP: a dense level first, hashed levels, the last at its vertices
    "dense+vertices": ([4, 8, 16], [True, False, False], 1, 1 << 10, 4),
    "all dense": ([3, 5], [True, True], 0, 1 << 8, 4),
}


def _inputs(case, n=3000, seed=0):
    res, dense, on_vertices, T, F = CASES[case]
    g = torch.Generator().manual_seed(seed)
    tables = torch.randn(len(res), T, F, generator=g)
    if on_vertices:                    # points on the vertices of the last level
        u = torch.randint(0, res[-1] + 1, (n, 3), generator=g).float() / res[-1]
    else:
        u = torch.rand(n, 3, generator=g) * 1.2 - 0.1     # a few outside [0, 1]
    return tables, u, res, dense, on_vertices


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("case", sorted(CASES))
def test_fused_lookup_equals_torch(case, threads):
    tables, u, res, dense, on_vertices = _inputs(case)
    prev = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        outs, grads = [], []
        for lookup in (ops.grid_lookup, fused.grid_lookup):
            t = tables.clone().requires_grad_()
            out = lookup(t, u, res, dense, on_vertices)
            g = torch.randn(out.shape, generator=torch.Generator().manual_seed(1))
            (grad,) = torch.autograd.grad(out, t, g)
            outs.append(out.detach())
            grads.append(grad)
    finally:
        torch.set_num_threads(prev)
    torch.testing.assert_close(outs[1], outs[0], rtol=0, atol=1e-6)
    assert torch.equal(grads[1], grads[0])


def test_fast_corner_gather_equals_torch():
    """The fast engine's coarse trilinear sum (embedding_bag + bincount) against indexing:
    values and gradients within 1e-5 (float32 sums of the same products, in another
    order; values ~N(0, 1), weights in [0, 1])."""
    from clrender.ngprt import engine as engines

    g = torch.Generator().manual_seed(0)
    values = torch.randn(500, 12, generator=g)
    idx, w = torch.randint(0, 500, (3000, 8), generator=g), torch.rand(3000, 8, generator=g)
    grad_out = torch.randn(3000, 12, generator=g)
    res = []
    for e in (engines.TORCH, engines.get("fast", torch.device("cpu"))):
        v = values.clone().requires_grad_()
        out = e.corner_gather(v, idx, w)
        res.append((out.detach(), torch.autograd.grad(out, v, grad_out)[0]))
    torch.testing.assert_close(res[1][0], res[0][0], rtol=0, atol=1e-5)
    torch.testing.assert_close(res[1][1], res[0][1], rtol=0, atol=1e-5)


def _aux_case(seed=0, n=3000, hidden=64, out=12):
    """Tables, corner coordinates and weights of an auxiliary NGP (a dense level, two
    hashed ones, the last on the corners' vertices), weights ~ a trained model's scale."""
    g = torch.Generator().manual_seed(seed)
    res, dense, on_vertices = [8, 16, 32], [True, False, False], 1
    tables = torch.randn(3, 1 << 12, 4, generator=g)
    u = torch.randint(0, 33, (n, 3), generator=g).float() / 32
    w0 = torch.randn(12, hidden, generator=g) * 0.3
    w1 = torch.randn(hidden, out, generator=g) * 0.2
    b0, b1 = torch.randn(hidden, generator=g) * 0.1, torch.randn(out, generator=g) * 0.1
    return tables, u, res, dense, on_vertices, w0, b0, w1, b1


def _upstream(shape) -> torch.Tensor:
    """The gradient arriving at the auxiliary values in these tests (seeded)."""
    return torch.randn(shape, generator=torch.Generator().manual_seed(2))


def _aux_run(fn, case, threads):
    tables, u, res, dense, on_vertices, *weights = case
    params = [t.clone().requires_grad_() for t in [tables, *weights]]
    prev = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        out = fn(params[0], u, res, dense, on_vertices, *params[1:])
        return out.detach(), torch.autograd.grad(out, params, _upstream(out.shape))
    finally:
        torch.set_num_threads(prev)


@pytest.mark.parametrize("hidden,out", [(64, 12), (32, 16), (64, 9)])
def test_fused_aux_values_equal_torch(hidden, out):
    """Values and the gradients of the tables, w0, b0, w1 and b1; sizes below the padded
    ones (32, 9 outputs) are exact padding."""
    case = _aux_case(hidden=hidden, out=out)
    ref_out, ref_grads = _aux_run(ops.aux_values, case, 2)
    got_out, got_grads = _aux_run(fused.aux_values, case, 2)
    torch.testing.assert_close(got_out, ref_out, rtol=0,
                               atol=1e-5 * float(ref_out.abs().max()))
    for name, a, b in zip(("tables", "w0", "b0", "w1", "b1"), got_grads, ref_grads):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-5 * float(b.abs().max()), msg=name)


def test_fused_aux_values_same_for_any_thread_count():
    case = _aux_case(n=9000)                    # several of the backward's chunks
    one, two = _aux_run(fused.aux_values, case, 1), _aux_run(fused.aux_values, case, 2)
    assert torch.equal(one[0], two[0])
    assert all(torch.equal(a, b) for a, b in zip(one[1], two[1]))


def test_fused_aux_values_refuse_sizes_above_the_padding():
    tables, u, res, dense, on_vertices, w0, b0, w1, b1 = _aux_case(hidden=64, out=12)
    big = torch.zeros(64, 17)
    with pytest.raises(ValueError, match="above the fused sizes"):
        fused.aux_values(tables, u, res, dense, on_vertices, w0, b0, big, torch.zeros(17))


@pytest.mark.parametrize("threads", [1, 2])
def test_fused_coarse_corners_equal_torch(threads):
    g = torch.Generator().manual_seed(0)
    u = torch.rand(5000, 3, generator=g) * 1.2 - 0.1          # a few outside: clamped cells
    prev = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        got, ref = fused.coarse_corners(u, 32), ops.coarse_corners(u, 32)
    finally:
        torch.set_num_threads(prev)
    for a, b in zip(got, ref):
        assert a.dtype == b.dtype and torch.equal(a, b)


@pytest.mark.parametrize("threads", [1, 2])
def test_fused_bounded_lattice_equals_torch(threads):
    """Rays from outside and inside the box, some missing it, some along an axis (zero
    direction components); a random occupancy grid; two steps."""
    g = torch.Generator().manual_seed(0)
    o = torch.randn(700, 3, generator=g) * 1.5
    d = torch.randn(700, 3, generator=g)
    d[:50, 1:] = 0.0                                        # along x
    d = d / d.norm(dim=-1, keepdim=True)
    occ = torch.rand(16, 16, 16, generator=g) < 0.3
    prev = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        for s in (0.0135, 0.1):
            ref = ops.lattice_samples(o, d, occ, s, 0.05, 10.0, 1.0, False)
            got = fused.lattice_samples(o, d, occ, s, 0.05, 10.0, 1.0, False)
            assert len(ref[0]) > 400                  # not a trivial comparison
            for a, b in zip(got, ref):
                assert a.dtype == b.dtype and torch.equal(a, b)
    finally:
        torch.set_num_threads(prev)


def test_fused_lookup_refuses_bad_input():
    tables, u, res, dense, _ = _inputs("dense+vertices")
    with pytest.raises(ValueError, match="dense levels must come first"):
        fused.grid_lookup(tables, u, res, [False, True, False])
    with pytest.raises(ValueError, match="float32 CPU tensors expected"):
        fused.grid_lookup(tables.double(), u, res, dense)


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"),
                    reason="-mno-avx is an x86 flag")
def test_the_mlp_in_4_float_vectors_equals_torch():
    """The auxiliary MLP built for an x86-64 CPU without AVX (4-float vectors, the width of
    ARM's NEON; no FMA, so each product rounded) against the torch specification, values
    and gradients within the tolerance above, as this machine's wider build."""
    if fused.extension().AUX_VECTOR == 4:
        pytest.skip("this machine's build is the 4-float one already (no AVX)")
    narrow = fused.extension([*fused.CFLAGS, "-mno-avx"])    # .ci/install builds it ahead
    assert narrow.AUX_VECTOR == 4
    tables, u, res, dense, on_vertices, w0, b0, w1, b1 = case = _aux_case(out=9)
    ref_out, ref_grads = _aux_run(ops.aux_values, case, 2)
    g = _upstream(ref_out.shape)
    out, x = narrow.aux_forward(tables, u, res, dense, on_vertices, w0, b0, w1, b1, True)
    got = [out, *narrow.aux_backward(g, x, tables, u, res, dense, on_vertices, w0, b0, w1, b1)]
    for name, a, b in zip(("out", "tables", "w0", "b0", "w1", "b1"), got,
                          [ref_out, *ref_grads]):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-5 * float(b.abs().max()), msg=name)


def test_the_build_is_named_by_its_source_and_flags():
    """Checkouts of one source share a build; another source or flags get their own."""
    source = fused.SOURCE.read_bytes()
    name = fused.build_name(source)
    assert name.isidentifier() and name == fused.build_name(bytes(source))
    assert fused.build_name(source + b"\n") != name
    assert fused.build_name(source, [*fused.CFLAGS, "-g"]) != name


def test_first_step_loss_and_gradients_agree_across_engines(tmp_path):
    """One batch of a `tiny` model through both engines: the loss within 1e-6 relative
    and every parameter gradient within 1e-5 of its largest magnitude (the lookups' values
    differ by float32 rounding, their table gradients are exact)."""
    import torch.nn.functional as F

    from clrender.data import load_dataset, make_scene
    from clrender.ngprt import engine as engines
    from clrender.ngprt.config import preset
    from clrender.ngprt.model import NGPRT, render_rays
    from clrender.ngprt.train import RaySampler

    ds = load_dataset(make_scene("bounded", tmp_path / "scene", seed=0, n_train=4, n_test=1,
                                 width=24, height=24), split="train")
    sampler = RaySampler(ds, "cpu")
    cfg = preset("tiny", scene=ds.scene)
    results = []
    for name in ("torch", "fast"):
        torch.manual_seed(0)
        model = NGPRT(cfg, engines.get(name, torch.device("cpu")))
        o, d, target, bg = sampler.sample(256, torch.Generator().manual_seed(1))
        occ = torch.ones((cfg.L_C,) * 3, dtype=torch.bool)
        r = render_rays(model, o, d, occ, 1.0, bg)
        lo, hi = ops.distortion_intervals(r["k"], r["t"], r["delta"], cfg.s0, False)
        loss = F.huber_loss(r["rgb"], target) + 0.01 * ops.distortion_loss(
            r["weights"], lo, hi, r["ray_ids"], len(o)).mean()
        loss.backward()
        results.append((loss.detach(), {k: p.grad for k, p in model.named_parameters()}))
    (la, ga), (lb, gb) = results
    torch.testing.assert_close(lb, la, rtol=1e-6, atol=0)
    for k in ga:
        scale = float(ga[k].abs().max())
        torch.testing.assert_close(gb[k], ga[k], rtol=0, atol=1e-5 * scale, msg=k)
