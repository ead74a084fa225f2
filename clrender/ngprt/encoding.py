"""Feature encodings shared by the renderers and training (numpy, float32).

* Instant-NGP spatial hash of integer grid corners into a table of T = 2**k entries.
* Real spherical harmonics of degree 4 (16 coefficients) for the view direction, with
  the constants and sign conventions of tiny-cuda-nn's ``SphericalHarmonics`` encoding.

References: Instant-NGP (Mueller et al. 2022) Eq. 4; NGP-RT S2.1.
"""
from __future__ import annotations

import numpy as np

HASH_PRIMES = (1, 2654435761, 805459861)
# The distinct magnitudes of the degree-4 SH basis (tiny-cuda-nn's), in order of first use:
# the numpy, torch and OpenCL (-D SH_C0 .. SH_C10, config.kernel_constants) bases read them here.
SH_C = (0.28209479177387814, 0.48860251190291987, 1.0925484305920792, 0.94617469575755997,
        0.31539156525251999, 0.54627421529603959, 0.59004358992664352, 2.8906114426405538,
        0.45704579946446572, 0.3731763325901154, 1.4453057213202769)


def hash_corner(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, T: int) -> np.ndarray:
    """Instant-NGP hash of non-negative integer corners into [0, T); T a power of two."""
    h = (np.asarray(ix).astype(np.uint32) * np.uint32(HASH_PRIMES[0])) \
        ^ (np.asarray(iy).astype(np.uint32) * np.uint32(HASH_PRIMES[1])) \
        ^ (np.asarray(iz).astype(np.uint32) * np.uint32(HASH_PRIMES[2]))
    return (h & np.uint32(T - 1)).astype(np.int64)


def sh4(dirs: np.ndarray) -> np.ndarray:
    """(N, 16) float32 degree-4 real SH of (N, 3) unit directions."""
    d = np.asarray(dirs, np.float32)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    xy, xz, yz = x * y, x * z, y * z
    x2, y2, z2 = x * x, y * y, z * z
    f = np.float32
    out = [
        np.full_like(x, f(SH_C[0])),
        f(-SH_C[1]) * y,
        f(SH_C[1]) * z,
        f(-SH_C[1]) * x,
        f(SH_C[2]) * xy,
        f(-SH_C[2]) * yz,
        f(SH_C[3]) * z2 - f(SH_C[4]),
        f(-SH_C[2]) * xz,
        f(SH_C[5]) * x2 - f(SH_C[5]) * y2,
        f(SH_C[6]) * y * (f(-3.0) * x2 + y2),
        f(SH_C[7]) * xy * z,
        f(SH_C[8]) * y * (f(1.0) - f(5.0) * z2),
        f(SH_C[9]) * z * (f(5.0) * z2 - f(3.0)),
        f(SH_C[8]) * x * (f(1.0) - f(5.0) * z2),
        f(SH_C[10]) * z * (x2 - y2),
        f(SH_C[6]) * x * (-x2 + f(3.0) * y2),
    ]
    return np.stack(out, axis=-1).astype(np.float32)
