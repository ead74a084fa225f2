"""The unbounded step lattice, uniform in contracted space (docs/ngprt.md "Step lattice"):
``t_k = S^-1(k * s)``, S the contracted arc length from the ray's start, closed form on
the pieces between breakpoints.

* S and S^-1 round-trip, the lattice is strictly increasing, and consecutive points of
  one piece are ``s`` apart in contracted space, for rays from inside and outside the
  unit cube looking inward and outward; S(far) agrees with a float64 polyline through the
  contracted path.
* torch (training), numpy (reference) and the OpenCL kernel compute the same table and
  the same lattice points, bit for bit; torch's ``lattice_samples`` takes exactly the
  reference's lattice points.
* Bounded scenes keep ``t_k = k * s``.

Tolerances: S(S^-1(g)) within 4 float32 ulps of the largest S (~2e-6 for S < 8);
contracted spacing within 2e-3 relative (float32 contracted points far out, where
``|x|_inf`` is ~1e3, are coarse); S(far) within 2e-4 relative of an 800k-point float64
polyline (it leaves out the few segments across a jump, each ~1e-4 long); agreement
across implementations exact.
"""
from __future__ import annotations

import numpy as np
import pytest
import torch

from clrender import buildlog
from clrender.ngprt import space, torch_ops as ops
from clrender.ngprt.config import preset

F32 = np.float32
NEAR, FAR = F32(0.05), F32(1000.0)


def _unit(d):
    d = np.asarray(d, np.float64)
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(F32)


def ray_sets(n: int = 200, seed: int = 0) -> dict:
    """(origins, dirs) float32: eyes inside the unit cube and in the shell
    (|o|_inf 1.5 .. 20), looking outward (away from the centre) and inward (at a
    random point within 0.5 of it)."""
    rng = np.random.default_rng(seed)
    inside = rng.uniform(-0.9, 0.9, (n, 3))
    out_dir = rng.normal(size=(n, 3))
    out_dir /= np.abs(out_dir).max(axis=1, keepdims=True)
    outside = out_dir * rng.uniform(1.5, 20.0, (n, 1))
    target = rng.uniform(-0.5, 0.5, (n, 3))
    sets = {}
    for name, o in (("inside", inside), ("outside", outside)):
        sets[name + "-outward"] = (o.astype(F32), _unit(o + rng.normal(size=(n, 3)) * 0.3))
        sets[name + "-inward"] = (o.astype(F32), _unit(target - o))
    return sets


def _table(o, d):
    n = len(o)
    return space.lattice_table(o, d, np.full(n, NEAR), np.full(n, FAR))


def _lattice(table, r: int, s: F32):
    """Every lattice point (k, t_k) of ray r of a table."""
    end = space.lattice_end(table)[r]
    k = np.arange(int(np.ceil(end / s)) + 1)
    k = k[k.astype(F32) * s < end]
    rows = np.full(len(k), r)
    return k, space.lattice_t(space.lattice_rows(table, rows), k.astype(F32) * s)


@pytest.mark.parametrize("which", ["inside-outward", "inside-inward", "outside-outward",
                                   "outside-inward"])
def test_lattice_is_uniform_in_contracted_space(which):
    o, d = ray_sets()[which]
    table = _table(o, d)
    s = F32(0.02)
    end = space.lattice_end(table)
    assert np.all(end > 0) and np.all(end < preset("tiny", scene="unbounded").max_ray_length)
    spacing, crossed = [], 0
    for r in range(0, len(o), 4):
        k, t = _lattice(table, r, s)
        assert t[0] == NEAR and np.all(np.diff(t) > 0) and t[-1] < FAR
        rows = np.full(len(k), r)
        back = space.lattice_s(space.lattice_rows(table, rows), t)
        np.testing.assert_allclose(back, k.astype(F32) * s, rtol=0,
                                   atol=4 * np.spacing(F32(max(1.0, end[r]))))
        piece = (table[0][r, None, 1:-1] <= t[:, None]).sum(axis=1)
        same = piece[1:] == piece[:-1]
        crossed += int((~same).sum())
        c = space.contract(o[r] + t[:, None] * d[r]).astype(np.float64)
        step = np.linalg.norm(np.diff(c, axis=0), axis=1)
        spacing.append(step[same] / s)
    spacing = np.concatenate(spacing)
    assert crossed > 0 and len(spacing) > 300
    np.testing.assert_allclose(spacing, 1.0, rtol=0, atol=2e-3)


def _polyline_length(o, d, n: int = 800_000) -> float:
    """Contracted length of the ray from NEAR to FAR as a float64 polyline (exact within a
    region, where the contracted path is straight), through points uniform in t up to 60
    and in 1/t beyond, leaving out the segments across the contraction's jumps
    (|x_a| = |x_b| outside the cube)."""
    t = np.concatenate([np.linspace(NEAR, 60.0, 3 * n // 4),
                        1.0 / np.linspace(1.0 / 60.0, 1.0 / float(FAR), n // 4)[1:]])
    x = o.astype(np.float64) + t[:, None] * d.astype(np.float64)
    ax = np.abs(x)
    m = ax.max(axis=1, keepdims=True)
    a = ax.argmax(axis=1)
    c = np.where(m <= 1, x, x / m)
    rows = np.flatnonzero(m[:, 0] > 1)
    c[rows, a[rows]] = np.sign(x[rows, a[rows]]) * (2.0 - 1.0 / m[rows, 0])
    region = np.where(m[:, 0] <= 1, -1, a * 2 + (np.take_along_axis(x, a[:, None], 1)[:, 0] > 0))
    seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
    jump = (region[1:] != region[:-1]) & (region[1:] >= 0) & (region[:-1] >= 0)
    return float(seg[~jump].sum())


def test_contracted_length_matches_polyline():
    for which, (o, d) in ray_sets(n=12, seed=1).items():
        end = space.lattice_end(_table(o, d))
        for r in range(len(o)):
            want = _polyline_length(o[r], d[r])
            assert abs(end[r] - want) <= 2e-4 * want, (which, r, end[r], want)


def test_torch_lattice_equals_reference():
    o, d = (np.concatenate(x) for x in zip(*ray_sets(n=64, seed=2).values()))
    n = len(o)
    table = _table(o, d)
    tt = ops.lattice_table(*(torch.from_numpy(x) for x in
                             (o, d, np.full(n, NEAR), np.full(n, FAR))))
    for a, b in zip(table, tt):
        assert np.array_equal(a, b.numpy())
    cfg = preset("tiny", scene="unbounded")
    occ = torch.ones((cfg.L_C,) * 3, dtype=torch.bool)
    s = float(F32(0.7 * cfg.s0))
    ids, k, t, delta, u = ops.lattice_samples(torch.from_numpy(o), torch.from_numpy(d), occ, s,
                                              float(NEAR), float(FAR), cfg.extent, True)
    ids, k, t, delta = ids.numpy(), k.numpy(), t.numpy(), delta.numpy()
    for r in range(0, n, 5):
        k_ref, t_ref = _lattice(table, r, F32(s))
        assert np.array_equal(k[ids == r], k_ref)
        assert np.array_equal(t[ids == r], t_ref)
        t_next = np.append(t_ref[1:], FAR)        # the last interval ends at far
        assert np.array_equal(delta[ids == r], t_next - t_ref)


def test_kernel_lattice_equals_reference(cl_platform):
    """The kernel's lattice_table, lattice_t and lattice_s (exact build, one lane) on the
    same rays; the renders with 1, 4 and 16 lanes hold the march to the reference
    (tests/test_render_cl.py, test_ngprt_unbounded.py)."""
    import pyopencl as cl

    from clrender.device import _kernel_dir, exact_options, get_runtime
    from clrender.ngprt.render_cl import kernel_defines

    cfg = preset("tiny", scene="unbounded", L_C=32, G_res=16, log2_T=11)
    defines, _ = kernel_defines(cfg, True, 1, 1)
    rt = get_runtime()
    opts = list(exact_options(rt.device)) + ["-DFAST_MATH=0", f"-I{_kernel_dir()}"] + [
        f"-D{k}={int(v) if isinstance(v, bool) else v}" for k, v in defines.items()]
    source = """
    #include "ngprt_lattice.h"
    __kernel void lattice(__global const float *od, float near, float far,
                          __global const float *sigma, __global const float *ts, int m,
                          __global float *table, __global float *t_out, __global float *s_out)
    {
        const int i = get_global_id(0);
        const float3 d3 = vload3(2 * i + 1, od);
        Point3 d;
        d.x = d3.x;
        d.y = d3.y;
        d.z = d3.z;
        Lattice lt;
        lattice_table(vload3(2 * i, od), d, near, far, &lt);
        __global float *w = table + i * 67;
        for (int q = 0; q < 14; ++q) { w[q] = lt.brk[q]; w[14 + q] = lt.cum[q]; }
        for (int q = 0; q < 13; ++q) { w[28 + q] = lt.A[q]; w[41 + q] = lt.B[q]; w[54 + q] = lt.K[q]; }
        for (int q = 0; q < m; ++q) {
            t_out[i * m + q] = lattice_t(&lt, sigma[i * m + q]);
            s_out[i * m + q] = lattice_s(&lt, ts[i * m + q]);
        }
    }
    """
    program = buildlog.build(rt.context, source, opts)
    o, d = (np.concatenate(x) for x in zip(*ray_sets(n=64, seed=3).values()))
    n, m = len(o), 64
    table = _table(o, d)
    rng = np.random.default_rng(4)
    sigma = (rng.uniform(0, 1, (n, m)) * space.lattice_end(table)[:, None]).astype(F32)
    ts = np.exp(rng.uniform(np.log(NEAR), np.log(2 * FAR), (n, m))).astype(F32)
    mf = cl.mem_flags
    buf = lambda a: cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR,   # noqa: E731
                              hostbuf=np.ascontiguousarray(a, F32))
    got = {"table": np.zeros((n, 67), F32), "t": np.zeros((n, m), F32),
           "s": np.zeros((n, m), F32)}
    outs = {key: cl.Buffer(rt.context, mf.WRITE_ONLY, v.nbytes) for key, v in got.items()}
    program.lattice(rt.queue, (n,), None, buf(np.concatenate([o, d], 1)), NEAR, FAR,
                    buf(sigma), buf(ts), np.int32(m), outs["table"], outs["t"], outs["s"])
    for key, v in got.items():
        cl.enqueue_copy(rt.queue, v, outs[key])
    assert np.array_equal(got["table"], np.concatenate(table, axis=1))
    rows = np.repeat(np.arange(n), m)
    want_t = space.lattice_t(space.lattice_rows(table, rows), sigma.reshape(-1))
    want_s = space.lattice_s(space.lattice_rows(table, rows), ts.reshape(-1))
    assert np.array_equal(got["t"].reshape(-1), want_t)
    assert np.array_equal(got["s"].reshape(-1), want_s)


def test_bounded_lattice_is_k_times_s():
    cfg = preset("tiny", scene="bounded")
    rng = np.random.default_rng(5)
    o = (rng.normal(size=(300, 3)) * 1.5).astype(F32)
    d = _unit(rng.normal(size=(300, 3)))
    s = float(F32(0.7 * cfg.s0))
    occ = torch.ones((cfg.L_C,) * 3, dtype=torch.bool)
    ids, k, t, delta, u = ops.lattice_samples(torch.from_numpy(o), torch.from_numpy(d), occ, s,
                                              cfg.near, cfg.far, cfg.extent, False)
    assert len(k) > 1000
    g = k.to(torch.float32) * F32(s)
    assert torch.equal(t, g)
    assert torch.equal(delta, (k + 1).to(torch.float32) * F32(s) - t)
    t_in, t_out = space.ray_box(o, d)
    k0 = np.ceil(np.fmax(F32(cfg.near), t_in) / F32(s))
    first = np.unique(ids.numpy(), return_index=True)
    assert np.array_equal(k.numpy()[first[1]], k0[first[0]].astype(np.int64))
