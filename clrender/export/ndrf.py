"""NDRF to the page: meshes and features as data textures, the conv shader's weights laid
out as the page's uniform blocks, every WebGL2 limit the page needs checked first.

The page (web/ndrf.js) renders docs/ndrf.md: per mesh, the exact ray-triangle hit of the
OpenCL rasteriser on a dilated hardware rasterisation (float targets: features, position),
then conv0 as full-screen passes of up to 4 float targets (16 hidden channels) each, then
conv1 with the sigmoid and compositing.

Assets (``k`` = mesh): ``faces_k`` (rows, TEX_WIDTH, 4) int32 (i0, i1, i2, 0);
``vertices_k`` (rows, TEX_WIDTH, 4) float32 (x, y, z, 0); ``features_k`` (rows, TEX_WIDTH,
4) float32, vertex v at texels 2v, 2v + 1; ``conv0_w`` (passes, taps, C_in, NV, 4) and
``conv0_b`` (passes, NV, 4); ``conv1_w`` (taps, H4, 4, 4): hidden channel 4g + i of tap t
at [t, g, i, :3]; all float32, zero-padded past H.
"""
from __future__ import annotations

import numpy as np

from . import limits as L
from .writer import as_texture

F32 = np.float32


def conv0_outputs_per_pass(where: str, taps: int, c_in: int) -> int:
    """Float targets (4 hidden channels each) a conv0 pass writes: its weights
    (taps * C_in vec4 a target) must fit one uniform block, and at most MAX_DRAW_BUFFERS."""
    per_target = 16 * taps * c_in
    L.need(where, "MAX_UNIFORM_BLOCK_SIZE", L.MAX_UNIFORM_BLOCK_SIZE, per_target,
           f"conv0 ({taps} taps x {c_in} input channels, one float target)")
    return min(L.MAX_DRAW_BUFFERS, L.MAX_UNIFORM_BLOCK_SIZE // per_target)


def _conv0(model, nv: int) -> tuple[np.ndarray, np.ndarray]:
    cfg, a = model.config, model.arrays
    S, C, H = cfg.kernel_size, cfg.c_in, cfg.hidden
    h4 = -(-H // 4)
    passes = -(-h4 // nv)
    w = np.zeros((S * S, C, passes * nv * 4), F32)
    w[..., :H] = np.asarray(a["conv0_w"], F32).reshape(S * S, C, H)
    b = np.zeros(passes * nv * 4, F32)
    b[:H] = a["conv0_b"]
    w = w.reshape(S * S, C, passes, nv, 4).transpose(2, 0, 1, 3, 4)
    return np.ascontiguousarray(w), b.reshape(passes, nv, 4)


def _conv1(model) -> np.ndarray:
    cfg, a = model.config, model.arrays
    S, H = cfg.kernel_size, cfg.hidden
    h4 = -(-H // 4)
    w = np.zeros((S * S, h4 * 4, 4), F32)
    w[:, :H, :3] = np.asarray(a["conv1_w"], F32).reshape(S * S, H, 3)
    return w.reshape(S * S, h4, 4, 4)


def ndrf_assets(model, where: str) -> tuple[dict, dict]:
    """``(manifest fields, assets)`` of a validated NDRF model; :class:`ExportError`
    naming ``where`` and the limit when the page could not render it."""
    cfg = model.config
    taps, h4 = cfg.kernel_size ** 2, -(-cfg.hidden // 4)
    L.need(where, "MAX_ARRAY_TEXTURE_LAYERS", L.MAX_ARRAY_TEXTURE_LAYERS, 3 * cfg.K,
           f"the screen buffer ({cfg.K} meshes x 3 float targets)")
    L.need(where, "MAX_ARRAY_TEXTURE_LAYERS", L.MAX_ARRAY_TEXTURE_LAYERS, h4,
           f"conv0's output ({cfg.hidden} hidden channels, 4 a layer)")
    L.need(where, "MAX_UNIFORM_BLOCK_SIZE", L.MAX_UNIFORM_BLOCK_SIZE, 64 * taps * h4,
           f"conv1 ({taps} taps x {cfg.hidden} hidden channels)")
    nv = conv0_outputs_per_pass(where, taps, cfg.c_in)
    assets = {}
    for k in range(cfg.K):
        vertices, faces, feats = model.mesh(k)
        assets[f"faces_{k}"] = as_texture(where, faces, 4, f"mesh {k}'s {len(faces)} faces")
        assets[f"vertices_{k}"] = as_texture(where, vertices, 4,
                                             f"mesh {k}'s {len(vertices)} vertices")
        assets[f"features_{k}"] = as_texture(where, feats, 4,
                                             f"mesh {k}'s features (2 texels a vertex)")
    assets["conv0_w"], assets["conv0_b"] = _conv0(model, nv)
    assets["conv1_w"] = _conv1(model)
    fields = {"meshes": [{"vertices": int(s["vertices"]), "faces": int(s["faces"])}
                         for s in model.mesh_sizes()],
              "conv0_targets": nv, "conv1_b": [float(x) for x in model.arrays["conv1_b"]],
              "background": list(model.background)}
    return fields, assets
