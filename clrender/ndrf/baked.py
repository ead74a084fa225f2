"""The baked NDRF file (format ``clrender-ndrf``): K meshes, their per-vertex features and
the convolutional shader's weights, validated before anything reaches a renderer.

Arrays (docs/ndrf.md), for k = 0..K-1:
    ``vertices_k`` (V_k, 3) float32 world units, ``faces_k`` (F_k, 3) int32 in [0, V_k),
    ``features_k`` (V_k, 8) float32; and ``conv0_w`` (S, S, C_in, H), ``conv0_b`` (H,),
    ``conv1_w`` (S, S, H, 3), ``conv1_b`` (3,) float32 (S = kernel_size), ``background`` (3,)
    float32 in [0, 1].

Examples:
    >>> model = load_baked("ndrf.npz")          # raises BakedFormatError when invalid
    >>> model.config.K, model.mesh_sizes()
    >>> save_baked(model, "copy.npz")

References: NDRF (Wan et al., CVPR 2023) §3.1-3.4, supplement §2-3.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import bakedfile
from ..bakedfile import F32, I32, BakedFormatError, check_arrays, fail
from .config import FEATURES, NDRFConfig

FORMAT = "clrender-ndrf"
VERSION = 1
MAX_VERTICES = 1 << 26       # per mesh: int32 indices and buffer sizes stay far from overflow


@dataclass
class NDRFModel:
    """A baked NDRF model.

    Attributes:
        config: the model's shape.
        arrays: exactly the arrays of :func:`expected_arrays`.
    """

    config: NDRFConfig
    arrays: dict
    method = "ndrf"           # its entry-point name (clrender.methods, pyproject.toml)

    def mesh(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(vertices (V, 3) float32, faces (F, 3) int32, features (V, 8) float32)`` of mesh k."""
        a = self.arrays
        return a[f"vertices_{k}"], a[f"faces_{k}"], a[f"features_{k}"]

    def mesh_sizes(self) -> list[dict]:
        """Per mesh: ``{"threshold", "vertices", "faces"}``."""
        return [{"threshold": t, "vertices": len(self.arrays[f"vertices_{k}"]),
                 "faces": len(self.arrays[f"faces_{k}"])}
                for k, t in enumerate(self.config.thresholds)]

    @property
    def background(self) -> tuple[float, float, float]:
        return tuple(float(c) for c in self.arrays["background"])


def expected_arrays(config: NDRFConfig, sizes: list[tuple[int, int]]) -> dict:
    """``{name: (shape, dtype)}`` for meshes of ``sizes[k] = (V_k, F_k)``."""
    S, H = config.kernel_size, config.hidden
    out = {}
    for k, (V, n_faces) in enumerate(sizes):
        out[f"vertices_{k}"] = ((V, 3), F32)
        out[f"faces_{k}"] = ((n_faces, 3), I32)
        out[f"features_{k}"] = ((V, FEATURES), F32)
    out["conv0_w"] = ((S, S, config.c_in, H), F32)
    out["conv0_b"] = ((H,), F32)
    out["conv1_w"] = ((S, S, H, 3), F32)
    out["conv1_b"] = ((3,), F32)
    out["background"] = ((3,), F32)
    return out


def _sizes(model: NDRFModel) -> list[tuple[int, int]]:
    a = model.arrays
    sizes = []
    for k in range(model.config.K):
        v, f = a.get(f"vertices_{k}"), a.get(f"faces_{k}")
        sizes.append((int(np.shape(v)[0]) if np.ndim(v) == 2 else 0,
                      int(np.shape(f)[0]) if np.ndim(f) == 2 else 0))
    return sizes


def validate(model: NDRFModel, where: str = "model") -> None:
    """Check an NDRF model against docs/ndrf.md; raises :class:`BakedFormatError`.

    Checks: names, shapes and dtypes, finite floats, at least one face per mesh, face
    indices in [0, V_k), mesh sizes below MAX_VERTICES, background in [0, 1].
    ``where`` (e.g. the file name) starts every message.
    """
    if not isinstance(model.config, NDRFConfig):
        fail(where, f"config is a {type(model.config).__name__}, expected NDRFConfig")
    if not isinstance(model.arrays, dict):
        fail(where, f"arrays is a {type(model.arrays).__name__}, expected a dict")
    sizes = _sizes(model)
    check_arrays(model.arrays, expected_arrays(model.config, sizes), where,
                 f" (K={model.config.K} meshes)")
    for k, (V, n_faces) in enumerate(sizes):
        if V > MAX_VERTICES or n_faces > 2 * MAX_VERTICES:
            fail(where, f"mesh {k} has {V} vertices and {n_faces} faces, more than this "
                        f"renderer takes ({MAX_VERTICES} vertices)")
        if n_faces == 0:
            fail(where, f"faces_{k} is empty: mesh {k} has no triangle")
        faces = model.arrays[f"faces_{k}"]
        lo, hi = int(faces.min()), int(faces.max())
        if lo < 0 or hi >= V:
            fail(where, f"faces_{k} has vertex indices in [{lo}, {hi}], expected [0, {V})")
    bg = model.arrays["background"]
    if bg.min() < 0.0 or bg.max() > 1.0:
        fail(where, f"background {bg.tolist()} must lie in [0, 1]")


def save_baked(model: NDRFModel, path, trained_on: dict | None = None) -> Path:
    """Validate ``model`` and write it to ``path`` atomically. Returns the path."""
    validate(model, str(path))
    manifest = {"format": FORMAT, "version": VERSION, "config": model.config.to_dict()}
    if trained_on is not None:  # {"data": path, "downscale": N}, for evaluation to reuse
        manifest["trained_on"] = trained_on
    return bakedfile.save(path, manifest, model.arrays)


def load_baked(path) -> NDRFModel:
    """Load and validate an NDRF file; raises :class:`BakedFormatError` naming the file."""
    where = str(path)
    manifest, arrays = bakedfile.read(path, FORMAT, VERSION, keys=("config",))
    if not isinstance(manifest["config"], dict):
        fail(where, "config is not a JSON object")
    try:
        config = NDRFConfig.from_dict(manifest["config"], where=f"{where}: config")
    except (TypeError, ValueError) as e:
        raise BakedFormatError(f"{where}: bad config: {e}") from e
    model = NDRFModel(config, arrays)
    validate(model, where)
    return model
