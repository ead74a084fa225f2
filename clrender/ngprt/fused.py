"""The fast engine's fused grid lookup: a C++ extension (``fused_grid.cpp``) behind an
autograd Function with the signature and results of
:func:`clrender.ngprt.torch_ops.grid_lookup` (CPU, float32).

The extension is compiled with the machine's C++ compiler at first use
(``torch.utils.cpp_extension.load``, cached by torch under ``$TORCH_EXTENSIONS_DIR``;
:func:`build` reports the seconds it took) and runs on torch's intra-op threads
(``torch.set_num_threads``). Values: the reference's float32 operations in its order
(the gather's sums may round differently from ``embedding_bag``'s, bounded in
``tests/test_fused.py``); table gradients: bit-identical to the reference's bincount
(float32 sums in the same order), deterministic for any thread count.
"""
from __future__ import annotations

import functools
import time
from pathlib import Path

import torch

SOURCE = Path(__file__).resolve().parent / "fused_grid.cpp"
# No FMA contraction: the reference rounds each product (the bit-identical gradients).
CFLAGS = ["-O3", "-march=native", "-ffp-contract=off", "-fopenmp"]


@functools.lru_cache(maxsize=None)
def _extension():
    from torch.utils.cpp_extension import load

    t0 = time.perf_counter()
    ext = load(name="clrender_fused_grid", sources=[str(SOURCE)], extra_cflags=CFLAGS,
               extra_ldflags=["-fopenmp"], verbose=False)
    return ext, time.perf_counter() - t0


def build() -> float:
    """Build (or load the cached build of) the extension; seconds it took this process."""
    return _extension()[1]


class _GridLookup(torch.autograd.Function):
    @staticmethod
    def forward(ctx, tables, u, resolutions, dense, on_vertices):
        ext = _extension()[0]
        ctx.save_for_backward(u)
        ctx.args = (tables.shape[1], resolutions, dense, on_vertices)
        return ext.grid_forward(tables, u, resolutions, dense, on_vertices)

    @staticmethod
    def backward(ctx, g):
        (u,) = ctx.saved_tensors
        T, resolutions, dense, on_vertices = ctx.args
        grad = _extension()[0].grid_backward(g.contiguous(), u, T, resolutions, dense,
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
    if tables.device.type != "cpu" or tables.dtype != torch.float32 or u.dtype != torch.float32:
        raise ValueError(f"fused grid_lookup: float32 CPU tensors expected, got tables "
                         f"{tables.dtype} on {tables.device}, u {u.dtype}")
    return _GridLookup.apply(tables.contiguous(), u.contiguous(),
                             [int(r) for r in resolutions], dense, int(on_vertices))
