"""Measured limits of the OpenCL device: what any method's kernel bounds are computed at
(bench/speed/ngprt_bounds.py, bench/speed/ndrf_kernels.py).

Two rates, measured on the chosen device with kernels built here (fast build):

* random-gather rate: 32-byte ``float8`` reads at random indices from a buffer of a given
  size (the size of the model table being read: the occupancy mip, the sparse coarse
  grid, the fine hash tables), many independent reads in flight per work-item;
* FLOP rate: independent ``a * b + c`` chains on ``float16`` values (2 FLOPs a lane),
  the better of separate and fused multiply-add;
* stream rate: bytes read plus bytes written per second by a ``float8`` copy of a buffer
  far larger than the device's caches (what a kernel's per-pixel inputs and outputs cost).

Never asserts.
"""
from __future__ import annotations

import functools

import numpy as np
import pyopencl as cl

from clrender import buildlog
from clrender.device import event_ms, get_runtime, padded, work_group_size

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

/* dst = src, one float8 a work-item and pass: 32 bytes read and 32 written. */
__kernel void copy8(__global const float8 *src, __global float8 *dst)
{
    dst[get_global_id(0)] = src[get_global_id(0)];
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
    prg = buildlog.build(runtime.context, SOURCE, opts)
    return {"gather8": prg.gather8, "flops": prg.flops, "copy8": prg.copy8}


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


def stream_rate(device=None, repeats: int = 5, nbytes: int = 256 << 20) -> float:
    """Bytes per second read and written by a ``float8`` copy of ``nbytes`` (read + write
    counted: 2 * nbytes a pass), at most a quarter of the device's largest allocation."""
    rt = get_runtime(device)
    nbytes = min(nbytes, rt.device.max_mem_alloc_size // 4)
    n = nbytes // F8_BYTES
    mf = cl.mem_flags
    src = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                    hostbuf=np.ones(n * 8, np.float32))
    dst = cl.Buffer(rt.context, mf.WRITE_ONLY, n * F8_BYTES)
    kernel = _program(rt)["copy8"]
    local = work_group_size(kernel, rt.device, (n,))
    if n % local[0]:
        n -= n % local[0]              # whole work-groups: no item reads past the buffers
    ms = _median_ms(lambda: kernel(rt.queue, (n,), local, src, dst), repeats)
    return 2 * n * F8_BYTES / (ms * 1e-3)
