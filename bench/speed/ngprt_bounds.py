"""The bounds the measured device limits (bench/speed/limits.py) put on the NGP-RT kernels.

    python -m bench.speed.ngprt_bounds                # rates for the `cpu` preset's table sizes
    python -m bench.speed.ngprt_bounds --preset paper

A kernel's bound is the time its own counters need at the measured gather and FLOP rates,
gathers and FLOPs not overlapped (a lower bound for a machine that does one at a time, and
at most 2x below a bound that overlaps them perfectly):

* march: the occupancy and G reads the march counted (the counting build,
  :mod:`clrender.ngprt.marches`: ours one uint16 exit code a point from an ``L_C^3``
  table, G only where the code lacks it; the paper's 1 to ``N_MIP`` mip bytes a point and
  G where the exit level is coarser than G), each at the gather rate of its table's size;
  per occupied sample ``8 * (1 + ceil(n_attention / 8))`` coarse float8 gathers from the
  coarse grid and 8 per fine level from the fine tables, and the FLOPs of the trilinear
  sums and the fusion (:func:`sample_flops`);
* deferred MLP: the MLP's FLOPs per covered pixel (opacity > 0; the kernel writes the
  background elsewhere);
* both: the bytes a pixel streams (:data:`MARCH_PIXEL_BYTES`, :data:`DEFERRED_PIXEL_BYTES`)
  at the measured stream rate.

Never asserts; ``bench.speed.ngprt_kernels`` prints each kernel's time against its bound.
"""
from __future__ import annotations

import argparse
import json
import math

import numpy as np

from bench.speed.limits import F8_BYTES, flop_rate, gather_rate, stream_rate
from clrender.device import get_runtime
from clrender.ngprt.config import (DEFERRED_HIDDEN, FEATURES, FUSION_HIDDEN, N_MIP, SH_DIM,
                                   preset)


# Bytes a pixel streams: the march writes 8 features, depth and two counters; the deferred
# MLP reads the 8 features and writes rgb.
MARCH_PIXEL_BYTES = 4 * (FEATURES + 3)
DEFERRED_PIXEL_BYTES = 4 * (FEATURES + 3)


def table_bytes(model, march: str = "ours") -> dict:
    """Bytes of the tables the march reads: ``occupancy`` (ours: the uint16 exit codes,
    ``2 L_C^3``; the paper's: the ``N_MIP`` mip levels, a byte a cell), ``G``, ``coarse``
    (the sparse coarse grid, corners padded to float8 chunks) and ``fine`` (all L hash
    tables)."""
    cfg = model.config
    corners = int(np.shape(model.arrays["coarse_blocks"])[0]) * (cfg.coarse_block + 1) ** 3
    occupancy = (2 * cfg.L_C ** 3 if march == "ours"
                 else sum((cfg.L_C >> lev) ** 3 for lev in range(N_MIP)))
    return {"occupancy": occupancy, "G": cfg.G_res ** 3,
            "coarse": corners * F8_BYTES * (1 + math.ceil(cfg.n_attention / 8)),
            "fine": cfg.L * cfg.T * F8_BYTES}


# Buffer sizes of two reference gather rates: one inside any device's last-level cache
# (a GPU's L2, a CPU's L3), one far outside it (a GPU's HBM, a CPU's DRAM); a table's own
# rate falls between them as its size does.
REFERENCE_GATHER_BYTES = {"cached (2 MiB)": 2 << 20, "memory (1 GiB)": 1 << 30}


def measure_limits(model, device=None, repeats: int = 5, march: str = "ours") -> dict:
    """Gather rates (per second) for each of the model's table sizes (:func:`table_bytes`
    of ``march``) and at :data:`REFERENCE_GATHER_BYTES`, the FLOP rate and the stream rate
    (bytes per second)."""
    sizes = table_bytes(model, march)
    rates = {name: gather_rate(max(nbytes, F8_BYTES), device, repeats)
             for name, nbytes in sizes.items()}
    reference = {name: gather_rate(nbytes, device, repeats)
                 for name, nbytes in REFERENCE_GATHER_BYTES.items()}
    return {"gathers_per_s": rates, "reference_gathers_per_s": reference,
            "flops_per_s": flop_rate(device, repeats),
            "stream_bytes_per_s": stream_rate(device, repeats),
            "table_bytes": sizes, "march": march, "device": get_runtime(device).name}


def sample_flops(config) -> int:
    """FLOPs of the features of one occupied sample: trilinear weights and sums of the
    coarse corners and of the fine corners of every level, and the fusion."""
    coarse_chunks = 1 + math.ceil(config.n_attention / 8)
    per_corner = 16 * coarse_chunks                  # w * v + acc over the float8 chunks
    weights = 8 * 2 + 6                              # wx * wy * wz per corner, 1 - w
    trilinear = 8 * per_corner + weights + config.L * (8 * 16 + weights)
    L = config.L
    fusion = {"sum": 8 * L, "shared-v": 16 * L + 4 * L, "separate-v": 16 * L + 8 * L,
              "shared-inv": 16 * L, "separate-inv": 16 * L,
              "mlp": 2 * (FEATURES * L * FUSION_HIDDEN + FUSION_HIDDEN * FEATURES)}
    compositing = 30                                 # sigma, alpha, weights, accumulators
    return trilinear + fusion[config.variant] + compositing


def _stream_s(pixels: float, per_pixel: int, limits: dict) -> float:
    """Seconds to stream ``per_pixel`` bytes of ``pixels`` (0 where ``limits`` has no
    stream rate: older result files)."""
    rate = limits.get("stream_bytes_per_s")
    return pixels * per_pixel / rate if rate else 0.0


def march_bound(config, reads: dict, n_occ: float, limits: dict, pixels: float = 0.0) -> dict:
    """Bound (ms) of the march from its counters, totals over the frame: ``reads``
    {``occupancy``, ``G``: reads the march counted (:mod:`clrender.ngprt.marches`)},
    ``n_occ`` samples and the frame's ``pixels`` (their outputs streamed); ``limits`` of
    :func:`measure_limits` for the same march."""
    g = limits["gathers_per_s"]
    coarse_chunks = 1 + math.ceil(config.n_attention / 8)
    gather_s = (reads["occupancy"] / g["occupancy"] + reads["G"] / g["G"]
                + n_occ * 8 * coarse_chunks / g["coarse"] + n_occ * 8 * config.L / g["fine"])
    flop_s = n_occ * sample_flops(config) / limits["flops_per_s"]
    stream_s = _stream_s(pixels, MARCH_PIXEL_BYTES, limits)
    return {"ms": 1e3 * (gather_s + flop_s + stream_s), "gather_ms": 1e3 * gather_s,
            "flop_ms": 1e3 * flop_s, "stream_ms": 1e3 * stream_s}


def deferred_flops() -> int:
    """FLOPs of the deferred MLP for one pixel (Eq. 5): three dense layers and sigmoid."""
    n_in, h = FEATURES - 1 + SH_DIM, DEFERRED_HIDDEN
    return 2 * (n_in * h + h * h + h * 3) + 2 * h + 10


def deferred_bound(covered: float, limits: dict, pixels: float = 0.0) -> dict:
    """Bound (ms) of the deferred MLP over ``covered`` pixels (opacity > 0) of a frame of
    ``pixels`` (each streams its features in and its rgb out)."""
    flop_s = covered * deferred_flops() / limits["flops_per_s"]
    stream_s = _stream_s(pixels, DEFERRED_PIXEL_BYTES, limits)
    return {"ms": 1e3 * (flop_s + stream_s), "gather_ms": 0.0, "flop_ms": 1e3 * flop_s,
            "stream_ms": 1e3 * stream_s}


def main(argv=None) -> int:
    from clrender.ngprt.random_model import random_baked_model

    p = argparse.ArgumentParser(prog="python -m bench.speed.ngprt_bounds", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="cpu")
    p.add_argument("--device", default=None)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)
    model = random_baked_model(preset(args.preset), 0)
    limits = measure_limits(model, args.device, args.repeats)
    print(json.dumps(limits, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
