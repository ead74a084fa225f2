"""Structured random baked models for tests and kernel benchmarks.

Not noise: a few thin surfaces (sphere and ellipsoid shells, a box surface) in grid
space with empty space around and inside them, so empty-space skipping, the mip, G and
early ray termination all have something to do. Coarse densities are high inside the
occupied band (surfaces turn opaque within a few samples), colours vary smoothly, the
fine tables and MLPs hold small random values. Unbounded models also put content in the
contracted outer shell (|c|_inf in (1, 2)) so the contraction is exercised.

Examples:
    >>> from clrender.ngprt.config import preset
    >>> model = random_baked_model(preset("tiny", variant="sum"), seed=3)
"""
from __future__ import annotations

import numpy as np

from .baked import BakedModel, build_distance_grid, build_mip, expected_arrays, \
    sparse_coarse_grid, upsampled, validate
from .config import FEATURES, ModelConfig

F32 = np.float32


def _shapes(rng: np.random.Generator, unbounded: bool) -> list[tuple]:
    """Surfaces as (kind, centre, radii) in contracted space c."""
    shapes = []
    for _ in range(rng.integers(2, 5)):
        kind = "sphere" if rng.random() < 0.5 else "ellipsoid"
        r = rng.uniform(0.15, 0.35) if kind == "sphere" else None
        radii = np.full(3, r) if r is not None else rng.uniform(0.12, 0.4, 3)
        centre = rng.uniform(-0.85, 0.85, 3) * (1.0 - radii.max())
        shapes.append((kind, centre, radii))
    half = rng.uniform(0.15, 0.3, 3)
    shapes.append(("box", rng.uniform(-0.5, 0.5, 3) * (1.0 - half), half))
    if unbounded:
        # Outer shell: a partial "ground" box surface and a blob beyond |c|_inf = 1.
        shapes.append(("box", np.array([0.0, 0.0, -1.55]), np.array([1.7, 1.7, 0.25])))
        axis = rng.integers(0, 2)
        centre = np.zeros(3)
        centre[axis] = rng.choice([-1.5, 1.5])
        shapes.append(("sphere", centre, np.full(3, 0.3)))
    return shapes


def _distance(c: np.ndarray, shape: tuple) -> np.ndarray:
    """Approximate unsigned distance of (M, 3) points c to a surface."""
    kind, centre, radii = shape
    q = c - centre
    if kind == "box":
        e = np.abs(q) - radii
        outside = np.linalg.norm(np.maximum(e, 0.0), axis=-1)
        return np.abs(outside + np.minimum(e.max(axis=-1), 0.0))
    k = np.linalg.norm(q / radii, axis=-1)
    return np.abs(k - 1.0) * radii.min()


def _surface_distance(c: np.ndarray, shapes: list) -> np.ndarray:
    return np.min([_distance(c, s) for s in shapes], axis=0)


def _corner_function(config: ModelConfig, shapes, thick: float, rng):
    """f(corners (M, 3) int) -> (M, C) float32 coarse channels."""
    E, C = config.extent, config.coarse_channels
    freq = rng.uniform(1.0, 4.0, (C, 3))
    phase = rng.uniform(0, 2 * np.pi, C)
    amp = np.concatenate([[0.5], np.full(3, 1.5), np.full(4, 0.5), np.full(C - FEATURES, 2.5)])

    def f(corners: np.ndarray) -> np.ndarray:
        c = (np.asarray(corners, np.float64) / config.L_C) * (2 * E) - E
        dist = _surface_distance(c, shapes)
        wave = np.sin(c @ freq.T + phase) * amp
        wave[:, 0] += -1.0 + 5.5 * np.exp(-(dist / thick) ** 2)   # sigma logit 1 .. 4.5 in band
        return wave.astype(F32)

    return f


def _occupancy(config: ModelConfig, shapes, thick: float, R: int) -> np.ndarray:
    """(R, R, R) uint8: cells whose centre lies within ``thick`` of a surface."""
    E = config.extent
    centres = (np.arange(R) + 0.5) / R * (2 * E) - E
    c = np.stack(np.meshgrid(centres, centres, centres, indexing="ij"), -1).reshape(-1, 3)
    return (_surface_distance(c, shapes) < thick).reshape(R, R, R).astype(np.uint8)


def _weights(config: ModelConfig, rng) -> dict:
    """Fine tables and MLP weights: small random values, N(0, 1/sqrt(fan_in)) weights."""
    out = {"fine_tables": rng.normal(0.0, 0.3, (config.L, config.T, FEATURES))}
    for name, (shape, _) in expected_arrays(config, 0).items():
        if name.startswith(("deferred_", "fusion_")):
            fan_in = shape[0]
            scale = 0.1 if len(shape) == 1 else 1.0 / np.sqrt(fan_in)
            out[name] = rng.normal(0.0, scale, shape)
        elif name == "attention_inv":
            out[name] = rng.normal(0.0, 1.5, shape)
    return {n: a.astype(F32) for n, a in out.items()}


def random_baked_model(config: ModelConfig, seed: int = 0, gamma: float = 1.0,
                       shapes: list | None = None) -> BakedModel:
    """A valid, structured random :class:`BakedModel` of ``config`` (deterministic per seed).

    Args:
        config: any variant, bounded or unbounded, L_C >= 16; with ``occ_res`` above L_C
            the occupancy is the band at that resolution within the coarse cells' band.
        seed: random seed.
        gamma: step scaler of the model.
        shapes: the surfaces, ``(kind, centre (3,), radii (3,))`` in contracted space with
            kind "sphere", "ellipsoid" or "box" (half sizes); None: a few at random.
    """
    rng = np.random.default_rng(seed)
    unbounded = config.scene == "unbounded"
    shapes = _shapes(rng, unbounded) if shapes is None else shapes
    # Band half-width: one coarse cell (at least 0.03) so surfaces are closed at any L_C.
    thick = max(2 * config.extent / config.L_C, 0.03)
    coarse = _occupancy(config, shapes, thick, config.L_C)
    block_index, blocks = sparse_coarse_grid(_corner_function(config, shapes, thick, rng),
                                             coarse, config.coarse_block,
                                             channels=config.coarse_channels)
    occupancy_0 = coarse
    if config.occ_res > config.L_C:
        f = config.occ_res // config.L_C
        inside = upsampled(coarse, f)
        occupancy_0 = _occupancy(config, shapes, thick, config.occ_res) & inside
    arrays = _weights(config, rng)
    arrays["coarse_block_index"], arrays["coarse_blocks"] = block_index, blocks
    for lev, grid in enumerate(build_mip(occupancy_0)):
        arrays[f"occupancy_{lev}"] = grid
    arrays["G"] = build_distance_grid(occupancy_0, config.G_res)
    model = BakedModel(config, float(gamma), arrays)
    validate(model, f"random_baked_model(seed={seed})")
    return model


def empty_model_with_occupancy(config: ModelConfig, occupancy_0: np.ndarray,
                               gamma: float = 1.0) -> BakedModel:
    """A model whose occupied cells are ``occupancy_0`` ((L_C,)*3, nonzero = occupied) and
    whose density is negligible (sigma logit -30) everywhere: for march tests, where what
    matters is which lattice points are taken, not what they show."""
    block_index, blocks = sparse_coarse_grid(
        lambda c: np.tile(np.array([-30.0] + [0.0] * (FEATURES - 1), np.float32), (len(c), 1)),
        occupancy_0, config.coarse_block, channels=FEATURES)
    arrays = {n: np.zeros(shape, dtype) for n, (shape, dtype) in expected_arrays(config, 0).items()}
    arrays["coarse_block_index"], arrays["coarse_blocks"] = block_index, blocks
    for lev, grid in enumerate(build_mip(occupancy_0)):
        arrays[f"occupancy_{lev}"] = grid
    arrays["G"] = build_distance_grid(occupancy_0, config.G_res)
    return BakedModel(config, gamma, arrays)
