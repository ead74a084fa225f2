"""Random NDRF models for tests and kernel benchmarks.

K nested closed star-shaped meshes (perturbed icospheres, outer mesh first, as the K
thresholds order them) inside [-1, 1]^3, random per-vertex features, and conv weights
scaled by their fan-in so the shader's sigmoid outputs spread over (0, 1) instead of
saturating.

Examples:
    >>> from clrender.ndrf.config import NDRFConfig
    >>> model = random_ndrf_model(NDRFConfig(thresholds=(1e-4, 1e-2)), seed=3)
    >>> model.mesh_sizes()[0]["faces"]
    5120
"""
from __future__ import annotations

import numpy as np
import trimesh

from .baked import NDRFModel, validate
from .config import FEATURES, NDRFConfig

F32 = np.float32
R_OUTER = 0.85       # mean radius of the outer mesh; each inner mesh is RATIO times smaller
RATIO = 0.75
BUMP = 0.1           # relative radial perturbation: 0.75 * 1.1 < 0.9 keeps the meshes nested


def _perturbed_sphere(rng: np.random.Generator, radius: float, centre: np.ndarray,
                      subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed icosphere with its radius modulated by smooth noise within +-BUMP."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    dirs = np.asarray(sphere.vertices, np.float64)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freq = rng.normal(0.0, 2.5, (4, 3))
    phase = rng.uniform(0.0, 2 * np.pi, 4)
    noise = np.sin(dirs @ freq.T + phase).mean(axis=1)          # in [-1, 1]
    r = radius * (1.0 + BUMP * noise)
    return (dirs * r[:, None] + centre).astype(F32), np.asarray(sphere.faces, np.int32)


def random_ndrf_model(config: NDRFConfig, seed: int = 0) -> NDRFModel:
    """A valid random :class:`NDRFModel` of shape ``config``.

    Args:
        config: the model shape (K = len(thresholds), hidden, n_freq, kernel_size).
        seed: seed of the generator; equal seeds give equal models.
    Returns:
        a model that passes :func:`clrender.ndrf.baked.validate`: mesh 0 has 5120 faces,
        inner meshes 1280, all strictly nested inside [-1, 1]^3.
    """
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-0.05, 0.05, 3)
    arrays = {}
    for k in range(config.K):
        vertices, faces = _perturbed_sphere(rng, R_OUTER * RATIO ** k, centre,
                                            4 if k == 0 else 3)
        arrays[f"vertices_{k}"] = vertices
        arrays[f"faces_{k}"] = faces
        arrays[f"features_{k}"] = rng.normal(0.0, 1.0, (len(vertices), FEATURES)).astype(F32)
    S, C, H = config.kernel_size, config.c_in, config.hidden
    arrays["conv0_w"] = (rng.normal(0.0, 1.0, (S, S, C, H)) / np.sqrt(S * S * C)).astype(F32)
    arrays["conv0_b"] = rng.normal(0.0, 0.1, H).astype(F32)
    # ReLU keeps about half the hidden units: sqrt(2) restores unit variance, and the extra
    # factor 1.5 gives sigmoid inputs of standard deviation ~1.5 (outputs spread, rarely
    # saturated).
    arrays["conv1_w"] = (rng.normal(0.0, 1.5 * np.sqrt(2.0 / (S * S * H)), (S, S, H, 3))
                         ).astype(F32)
    arrays["conv1_b"] = rng.normal(0.0, 0.2, 3).astype(F32)
    arrays["background"] = rng.uniform(0.0, 1.0, 3).astype(F32)
    model = NDRFModel(config, arrays)
    validate(model, f"random_ndrf_model(seed={seed})")
    return model
