"""Measured limits of the OpenCL device and the bounds they put on the NGP-RT kernels.

    python -m bench.limits                      # rates for the `cpu` preset's table sizes
    python -m bench.limits --preset paper

Two rates, measured on the chosen device with kernels built here (fast build):

* random-gather rate: 32-byte ``float8`` reads at random indices from a buffer of a given
  size (the size of the model table being read: the occupancy mip, the sparse coarse
  grid, the fine hash tables), many independent reads in flight per work-item;
* FLOP rate: independent ``a * b + c`` chains on ``float16`` values (2 FLOPs a lane),
  the better of separate and fused multiply-add.

A kernel's bound is the time its own counters need at those rates, gathers and FLOPs not
overlapped (a lower bound for a machine that does one at a time, and at most 2x below a
bound that overlaps them perfectly):

* march: the occupancy and G reads the march counted (the counting build,
  :mod:`clrender.ngprt.marches`: ours one uint16 exit code a point from an ``L_C^3``
  table, G only where the code lacks it; the paper's 1 to ``N_MIP`` mip bytes a point and
  G where the exit level is coarser than G), each at the gather rate of its table's size;
  per occupied sample ``8 * (1 + ceil(n_attention / 8))`` coarse float8 gathers from the
  coarse grid and 8 per fine level from the fine tables, and the FLOPs of the trilinear
  sums and the fusion (:func:`sample_flops`);
* deferred MLP: the MLP's FLOPs per covered pixel (opacity > 0; the kernel writes the
  background elsewhere).

Never asserts; ``bench.ngprt_kernels`` prints each kernel's time against its bound.
"""
from __future__ import annotations

import argparse
import functools
import json
import math

import numpy as np
import pyopencl as cl

from clrender.device import event_ms, get_runtime, padded, work_group_size
from clrender.ngprt.config import (DEFERRED_HIDDEN, FEATURES, FUSION_HIDDEN, N_MIP, SH_DIM,
                                   preset)

F8_BYTES = 32
# Rate kernels, specialised with -D (GATHER_STREAMS, FLOP_CHAINS) like the renderer's.
SOURCE = r"""
/* GATHER_STREAMS independent random index streams per work-item (an LCG each), n_iter
 * float8 reads per stream from table[0 .. mask]. */
__kernel void gather8(__global const float8 *table, const uint mask, const int n_iter,
                      __global float *out)
{
    const uint gid = get_global_id(0);
    uint h[GATHER_STREAMS];
    float8 acc[GATHER_STREAMS];
    for (int j = 0; j < GATHER_STREAMS; ++j) {
        h[j] = (gid * GATHER_STREAMS + j) * 2654435761u + 0x9e3779b9u;
        acc[j] = (float8)(0.0f);
    }
    for (int i = 0; i < n_iter; ++i)
        for (int j = 0; j < GATHER_STREAMS; ++j) {
            h[j] = h[j] * 1664525u + 1013904223u;
            acc[j] = acc[j] + table[(h[j] >> 6) & mask];
        }
    float8 a = (float8)(0.0f);
    for (int j = 0; j < GATHER_STREAMS; ++j) a = a + acc[j];
    out[gid] = a.s0 + a.s1 + a.s2 + a.s3 + a.s4 + a.s5 + a.s6 + a.s7;
}

/* FLOP_CHAINS independent a * b + c chains of float16 per work-item, contracted into
 * fused multiply-adds or not (CONTRACT). */
#if !CONTRACT
#pragma OPENCL FP_CONTRACT OFF
#endif
__kernel void flops(const int n_iter, const float a, const float b, __global float *out)
{
    const float x = (float)get_global_id(0) * 1e-7f;
    float16 v[FLOP_CHAINS];
    for (int j = 0; j < FLOP_CHAINS; ++j) v[j] = (float16)(x + (float)j);
    for (int i = 0; i < n_iter; ++i)
        for (int j = 0; j < FLOP_CHAINS; ++j) v[j] = v[j] * a + b;
    float16 s = (float16)(0.0f);
    for (int j = 0; j < FLOP_CHAINS; ++j) s = s + v[j];
    out[get_global_id(0)] = s.s0 + s.s1 + s.s2 + s.s3 + s.s4 + s.s5 + s.s6 + s.s7;
}
"""
# Independent streams per work-item: the best rate over these is the device's (few
# streams suit DRAM-sized tables, many cache-resident ones).
GATHER_STREAMS = (1, 4, 16)
# Enough independent chains to hide the add and multiply latencies of a wide SIMD unit.
FLOP_CHAINS = 24


@functools.lru_cache(maxsize=None)
def _program(runtime, streams: int = 1, contract: bool = False):
    opts = ["-cl-mad-enable", f"-DGATHER_STREAMS={streams}", f"-DFLOP_CHAINS={FLOP_CHAINS}",
            f"-DCONTRACT={int(contract)}"]
    prg = cl.Program(runtime.context, SOURCE).build(options=opts)
    return {"gather8": prg.gather8, "flops": prg.flops}


def _median_ms(run, repeats: int) -> float:
    run()                                                    # warm-up: first touch, build
    return float(np.median([event_ms(run()) for _ in range(repeats)]))


def gather_rate(nbytes: int, device=None, repeats: int = 5, reads: int = 1 << 23) -> float:
    """Random 32-byte gathers per second from a buffer of ``nbytes`` (rounded down to a
    power of two, at least 32 bytes): the best over :data:`GATHER_STREAMS`."""
    rt = get_runtime(device)
    n = 1 << max(0, (max(nbytes, F8_BYTES) // F8_BYTES).bit_length() - 1)
    table = cl.Buffer(rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                      hostbuf=np.random.default_rng(0).random(n * 8, np.float32))
    items = 16 * rt.device.max_compute_units * 256
    best = 0.0
    for streams in GATHER_STREAMS:
        kernel = _program(rt, streams)["gather8"]
        n_iter = max(1, reads // (items * streams))
        local = work_group_size(kernel, rt.device, (items,))
        gsize = padded((items,), local)
        out = cl.Buffer(rt.context, cl.mem_flags.WRITE_ONLY, 4 * gsize[0])
        ms = _median_ms(lambda: kernel(rt.queue, gsize, local, table, np.uint32(n - 1),
                                       np.int32(n_iter), out), repeats)
        best = max(best, gsize[0] * streams * n_iter / (ms * 1e-3))
    return best


def flop_rate(device=None, repeats: int = 5, flops: float = 4e9) -> float:
    """``a * b + c`` FLOPs per second (2 per lane and step) over independent chains: the
    better of separate multiply and add (the kernels' FP_CONTRACT OFF) and fused."""
    rt = get_runtime(device)
    items = 16 * rt.device.max_compute_units * 256
    n_iter = max(1, int(flops // (items * FLOP_CHAINS * 32)))
    best = 0.0
    for contract in (False, True):
        kernel = _program(rt, contract=contract)["flops"]
        local = work_group_size(kernel, rt.device, (items,))
        gsize = padded((items,), local)
        out = cl.Buffer(rt.context, cl.mem_flags.WRITE_ONLY, 4 * gsize[0])
        ms = _median_ms(lambda: kernel(rt.queue, gsize, local, np.int32(n_iter),
                                       np.float32(0.999), np.float32(1e-3), out), repeats)
        best = max(best, gsize[0] * FLOP_CHAINS * 32 * n_iter / (ms * 1e-3))
    return best


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


def measure_limits(model, device=None, repeats: int = 5, march: str = "ours") -> dict:
    """Gather rates (per second) for each of the model's table sizes (:func:`table_bytes`
    of ``march``) and the FLOP rate."""
    sizes = table_bytes(model, march)
    rates = {name: gather_rate(max(nbytes, F8_BYTES), device, repeats)
             for name, nbytes in sizes.items()}
    return {"gathers_per_s": rates, "flops_per_s": flop_rate(device, repeats),
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


def march_bound(config, reads: dict, n_occ: float, limits: dict) -> dict:
    """Bound (ms) of the march from its counters, totals over the frame: ``reads``
    {``occupancy``, ``G``: reads the march counted (:mod:`clrender.ngprt.marches`)} and
    ``n_occ`` samples; ``limits`` of :func:`measure_limits` for the same march."""
    g = limits["gathers_per_s"]
    coarse_chunks = 1 + math.ceil(config.n_attention / 8)
    gather_s = (reads["occupancy"] / g["occupancy"] + reads["G"] / g["G"]
                + n_occ * 8 * coarse_chunks / g["coarse"] + n_occ * 8 * config.L / g["fine"])
    flop_s = n_occ * sample_flops(config) / limits["flops_per_s"]
    return {"ms": 1e3 * (gather_s + flop_s), "gather_ms": 1e3 * gather_s,
            "flop_ms": 1e3 * flop_s}


def deferred_flops() -> int:
    """FLOPs of the deferred MLP for one pixel (Eq. 5): three dense layers and sigmoid."""
    n_in, h = FEATURES - 1 + SH_DIM, DEFERRED_HIDDEN
    return 2 * (n_in * h + h * h + h * 3) + 2 * h + 10


def deferred_bound(covered: float, limits: dict) -> dict:
    """Bound (ms) of the deferred MLP over ``covered`` pixels (opacity > 0)."""
    flop_s = covered * deferred_flops() / limits["flops_per_s"]
    return {"ms": 1e3 * flop_s, "gather_ms": 0.0, "flop_ms": 1e3 * flop_s}


def main(argv=None) -> int:
    from clrender.ngprt.random_model import random_baked_model

    p = argparse.ArgumentParser(prog="python -m bench.limits", description=__doc__,
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
