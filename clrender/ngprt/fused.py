"""The fast engine's fused stages: a C++ extension (``fused_grid.cpp``) behind autograd
Functions with the signatures and results of their :mod:`clrender.ngprt.torch_ops`
specifications (CPU, float32): :func:`grid_lookup` (the fine levels), :func:`aux_values`
(the auxiliary NGP's encoding and MLP in one pass; its hidden layer is never stored, the
backward recomputes it from the stored features), :func:`coarse_corners` (bit for bit),
:func:`corner_gather` (the coarse trilinear sum) and :func:`lattice_samples` (the bounded
step lattice's occupied points, bit for bit).

The extension is compiled with the machine's C++ compiler at first use
(``torch.utils.cpp_extension.load``, cached by torch under ``$TORCH_EXTENSIONS_DIR`` in a
folder named by :func:`build_name`; :func:`build` reports the seconds it took) and runs
on torch's intra-op threads (``torch.set_num_threads``). Values: the reference's float32
operations in its order (the gather's sums may round differently from ``embedding_bag``'s,
bounded in ``tests/test_fused.py``); table gradients: bit-identical to the reference's bincount
(float32 sums in the same order), deterministic for any thread count. The auxiliary
MLP rounds differently from torch's matmuls (fused multiply-adds, its own summation
order; bounded in ``tests/test_fused.py``), deterministic for any thread count (its
weight gradient summed per fixed chunk of corners, the chunks in order).
"""
from __future__ import annotations

import functools
import hashlib
import time
from pathlib import Path

import torch

from . import torch_ops as ops

SOURCE = Path(__file__).resolve().parent / "fused_grid.cpp"
# No FMA contraction: the reference rounds each product (the bit-identical gradients).
CFLAGS = ["-O3", "-march=native", "-ffp-contract=off", "-fopenmp"]


def build_name(source: bytes, cflags=CFLAGS) -> str:
    """The extension's name, from a hash of its source, flags and torch version: checkouts of
    the same code share one build, and one of other code never rebuilds it (nor waits on
    its build's lock)."""
    key = hashlib.sha256(source + " ".join(cflags).encode() + torch.__version__.encode())
    return f"clrender_fused_grid_{key.hexdigest()[:12]}"


@functools.lru_cache(maxsize=None)
def _load(cflags: tuple):
    from torch.utils.cpp_extension import load

    t0 = time.perf_counter()
    ext = load(name=build_name(SOURCE.read_bytes(), cflags), sources=[str(SOURCE)],
               extra_cflags=list(cflags), extra_ldflags=["-fopenmp"], verbose=False)
    return ext, time.perf_counter() - t0


def extension(cflags=CFLAGS):
    """The extension's module, built at first use; ``cflags`` other than the engine's
    :data:`CFLAGS` are another build (a test's of a narrower target)."""
    return _load(tuple(cflags))[0]


def build(cflags=CFLAGS) -> float:
    """Build (or load the cached build of) the extension; seconds it took this process."""
    return _load(tuple(cflags))[1]


class _GridLookup(torch.autograd.Function):
    @staticmethod
    def forward(ctx, tables, u, resolutions, dense, on_vertices):
        ext = extension()
        ctx.save_for_backward(u)
        ctx.args = (tables.shape[1], resolutions, dense, on_vertices)
        return ext.grid_forward(tables, u, resolutions, dense, on_vertices)

    @staticmethod
    def backward(ctx, g):
        (u,) = ctx.saved_tensors
        T, resolutions, dense, on_vertices = ctx.args
        grad = extension().grid_backward(g.contiguous(), u, T, resolutions, dense,
                                         on_vertices)
        return grad, None, None, None, None


def grid_lookup(tables: torch.Tensor, u: torch.Tensor, resolutions, dense=None,
                on_vertices: int = 0) -> torch.Tensor:
    """(N, n_levels, F) :func:`clrender.ngprt.torch_ops.grid_lookup`, fused; tables
    (n_levels, T, F) and u (N, 3) float32 on the CPU; differentiable in ``tables``."""
    n_lev = tables.shape[0]
    dense = [False] * n_lev if dense is None else [bool(d) for d in dense]
    n_dense = sum(dense)
    if dense != [True] * n_dense + [False] * (n_lev - n_dense):
        raise ValueError(f"grid_lookup: dense levels must come first, got {dense}")
    if not 0 <= on_vertices <= n_lev or len(resolutions) != n_lev:
        raise ValueError(f"grid_lookup: need {n_lev} resolutions and on_vertices in "
                         f"[0, {n_lev}], got {list(resolutions)} and {on_vertices}")
    _cpu_float32("grid_lookup", tables=tables, u=u)
    return _GridLookup.apply(tables.contiguous(), u.contiguous(),
                             [int(r) for r in resolutions], dense, int(on_vertices))


def _cpu_float32(name: str, **tensors) -> None:
    bad = {k: f"{t.dtype} on {t.device}" for k, t in tensors.items()
           if t.device.type != "cpu" or t.dtype != torch.float32}
    if bad:
        raise ValueError(f"fused {name}: float32 CPU tensors expected, got {bad}")


class _AuxValues(torch.autograd.Function):
    @staticmethod
    def forward(ctx, tables, u, resolutions, dense, on_vertices, w0, b0, w1, b1):
        out, x = extension().aux_forward(tables, u, resolutions, dense, on_vertices,
                                         w0, b0, w1, b1, any(ctx.needs_input_grad))
        ctx.save_for_backward(x, tables, u, w0, b0, w1, b1)    # x: the (N, I) features
        ctx.args = (resolutions, dense, on_vertices)
        return out

    @staticmethod
    def backward(ctx, g):
        x, tables, u, w0, b0, w1, b1 = ctx.saved_tensors
        res, dense, on_vertices = ctx.args
        gt, gw0, gb0, gw1, gb1 = extension().aux_backward(
            g.contiguous(), x, tables, u, res, dense, on_vertices, w0, b0, w1, b1)
        return gt, None, None, None, None, gw0, gb0, gw1, gb1


def aux_values(tables, u, resolutions, dense, on_vertices, w0, b0, w1, b1) -> torch.Tensor:
    """(N, O) :func:`clrender.ngprt.torch_ops.aux_values`, fused; differentiable in the
    tables and the MLP's weights."""
    _cpu_float32("aux_values", tables=tables, u=u, w0=w0, b0=b0, w1=w1, b1=b1)
    dense = [bool(d) for d in dense]
    if dense != sorted(dense, reverse=True):
        raise ValueError(f"aux_values: dense levels must come first, got {dense}")
    sizes, most = (w0.shape[0], w0.shape[1], w1.shape[1]), extension().AUX_MAX
    if any(n > m for n, m in zip(sizes, most)):
        raise ValueError(f"fused aux_values: the MLP {'->'.join(map(str, sizes))} is above "
                         f"the fused sizes {'->'.join(map(str, most))} (train it with "
                         f"--engine torch)")
    return _AuxValues.apply(tables.contiguous(), u.contiguous(), [int(r) for r in resolutions],
                            dense, int(on_vertices), w0.contiguous(), b0.contiguous(),
                            w1.contiguous(), b1.contiguous())


def coarse_corners(u: torch.Tensor, res: int):
    """:func:`clrender.ngprt.torch_ops.coarse_corners`, fused (the same results, bit for
    bit: corners, idx, w)."""
    _cpu_float32("coarse_corners", u=u)
    corners, idx, w = extension().coarse_corners(u.contiguous(), int(res))
    return corners, idx, w


class _CornerGather(torch.autograd.Function):
    @staticmethod
    def forward(ctx, values, idx, w):
        ctx.save_for_backward(idx, w)
        ctx.rows = values.shape[0]
        return extension().corner_forward(values, idx, w)

    @staticmethod
    def backward(ctx, g):
        idx, w = ctx.saved_tensors
        return extension().corner_backward(g.contiguous(), idx, w, ctx.rows), None, None


def corner_gather(values: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(N, C) :func:`clrender.ngprt.torch_ops.corner_gather`, fused; differentiable in
    ``values`` (gradient rows summed in sample then corner order, any thread count)."""
    _cpu_float32("corner_gather", values=values, w=w)
    if idx.dtype != torch.int64:
        raise ValueError(f"fused corner_gather: int64 idx expected, got {idx.dtype}")
    return _CornerGather.apply(values.contiguous(), idx.contiguous(), w.contiguous())


def lattice_samples(origins, dirs, occupancy, s: float, near: float, far: float, extent: float,
                    unbounded: bool):
    """:func:`clrender.ngprt.torch_ops.lattice_samples`, fused for bounded scenes (one pass
    a ray, writing only the occupied points: the same samples bit for bit); unbounded
    scenes, whose contracted lattice is not fused, take the torch function itself."""
    if unbounded:
        return ops.lattice_samples(origins, dirs, occupancy, s, near, far, extent, unbounded)
    _cpu_float32("lattice_samples", origins=origins, dirs=dirs)
    if occupancy.dtype != torch.bool:
        raise ValueError(f"fused lattice_samples: bool occupancy expected, got {occupancy.dtype}")
    return tuple(extension().lattice_bounded(origins.contiguous(), dirs.contiguous(),
                                             occupancy.contiguous(), float(s), float(near),
                                             float(extent)))
