"""Training engines: who computes the grid and coarse stages of a training step.

* ``torch``: the :mod:`clrender.ngprt.torch_ops` functions under torch autograd (the
  specification; CPU and CUDA).
* ``fast``: their fused twins in :mod:`clrender.ngprt.fused`, a C++ extension (built with
  the machine's compiler at first use): the fine levels' lookup, the auxiliary NGP
  (encoding + MLP) at the batch's L_C corners, the corners' de-duplication, the coarse
  trilinear sum and the bounded scenes' ray sampling (CPU only).

Both engines train the same model with the same math; ``tests/test_fused.py`` compares
their values and gradients.

Examples:
    >>> model = NGPRT(cfg, engine=get("fast", torch.device("cpu")))
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Callable

from . import torch_ops as ops
from .config import ENGINES


@dataclass(frozen=True)
class Engine:
    """Named implementations of the :mod:`clrender.ngprt.torch_ops` functions of the
    same names (same signatures and results)."""

    name: str
    grid_lookup: Callable
    corner_gather: Callable
    aux_values: Callable
    coarse_corners: Callable
    lattice_samples: Callable


TORCH = Engine("torch", ops.grid_lookup, ops.corner_gather, ops.aux_values, ops.coarse_corners,
               ops.lattice_samples)


def get(name: str, device) -> Engine:
    """The engine ``name`` for a torch ``device``; ``fast`` where it does not run (CUDA,
    MPS; its C++ extension not built: no compiler) is the torch engine, with a one-line
    note on stderr."""
    if name not in ENGINES:
        raise ValueError(f"unknown training engine {name!r}; engines: {', '.join(ENGINES)}")
    if name == "torch":
        return TORCH
    if getattr(device, "type", str(device)) != "cpu":
        print(f"clrender: the fast engine runs on the CPU only; training on {device} with "
              f"the torch engine", file=sys.stderr)
        return TORCH
    from . import fused

    try:
        fused.build()
    except Exception as e:          # the compiler's or ninja's own message, with ours
        first = (str(e).strip().splitlines() or [type(e).__name__])[-1]
        print(f"clrender: the fast engine's C++ extension ({fused.SOURCE.name}) did not build "
              f"(it needs g++ and ninja): {first}; training with the torch engine",
              file=sys.stderr)
        return TORCH
    return Engine("fast", fused.grid_lookup, fused.corner_gather, fused.aux_values,
                  fused.coarse_corners, fused.lattice_samples)
