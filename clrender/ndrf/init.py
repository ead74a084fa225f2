"""An untrained NDRF model on given meshes: the state training starts from.

Per-vertex features ~ N(0, 0.1^2); shader weights as PyTorch initialises a conv layer
(uniform in +-1/sqrt(fan_in)), so the first shaded image is a smooth grey.

Examples:
    >>> model = initial_model(NDRFConfig(), [(v0, f0), (v1, f1)], seed=0)
    >>> init_model_from_meshes("meshes/", "untrained.npz")   # from `clrender ndrf extract`
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from .baked import NDRFModel, save_baked
from .config import FEATURES, NDRFConfig

F32 = np.float32
FEATURE_STD = 0.1


def initial_model(config: NDRFConfig, meshes, seed: int = 0,
                  background=(1.0, 1.0, 1.0)) -> NDRFModel:
    """An :class:`NDRFModel` with random features and shader weights.

    Args:
        meshes: K pairs ``(vertices (V, 3), faces (F, 3))``, outer (lowest threshold) first.
        background: RGB in [0, 1] stored with the model.
    """
    if len(meshes) != config.K:
        raise ValueError(f"{len(meshes)} meshes for K={config.K} thresholds {config.thresholds}")
    rng = np.random.default_rng(seed)
    arrays = {}
    for k, (vertices, faces) in enumerate(meshes):
        arrays[f"vertices_{k}"] = np.ascontiguousarray(vertices, F32)
        arrays[f"faces_{k}"] = np.ascontiguousarray(faces, np.int32)
        arrays[f"features_{k}"] = (FEATURE_STD * rng.standard_normal(
            (len(vertices), FEATURES))).astype(F32)
    S, H = config.kernel_size, config.hidden
    for name, (c_in, c_out) in (("conv0", (config.c_in, H)), ("conv1", (H, 3))):
        bound = 1.0 / np.sqrt(S * S * c_in)
        arrays[f"{name}_w"] = rng.uniform(-bound, bound, (S, S, c_in, c_out)).astype(F32)
        arrays[f"{name}_b"] = rng.uniform(-bound, bound, (c_out,)).astype(F32)
    arrays["background"] = np.asarray(background, F32).reshape(3)
    return NDRFModel(config, arrays)


def load_meshes(mesh_dir) -> tuple[tuple[float, ...], list[tuple[np.ndarray, np.ndarray]]]:
    """Thresholds and meshes written by :func:`clrender.ndrf.mesh.write_meshes`."""
    mesh_dir = Path(mesh_dir)
    report_path = mesh_dir / "report.json"
    if not report_path.is_file():
        raise FileNotFoundError(f"{report_path}: no extraction report "
                                "(write meshes with `clrender ndrf extract`)")
    try:
        thresholds = tuple(float(m["threshold"]) for m in json.loads(report_path.read_text())["meshes"])
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise ValueError(f"{report_path}: not an extraction report ({e})") from e
    meshes = []
    for k in range(len(thresholds)):
        path = mesh_dir / f"mesh_{k}.ply"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: mesh {k} of {len(thresholds)} is missing")
        mesh = trimesh.load(path, process=False, force="mesh")
        meshes.append((np.asarray(mesh.vertices, F32), np.asarray(mesh.faces, np.int32)))
    return thresholds, meshes


def init_model_from_meshes(mesh_dir, out, seed: int = 0, config: NDRFConfig | None = None) -> Path:
    """Write an untrained NDRF model on the meshes of ``mesh_dir`` to ``out``."""
    thresholds, meshes = load_meshes(mesh_dir)
    config = config or NDRFConfig(thresholds=thresholds)
    return save_baked(initial_model(config, meshes, seed), out)
