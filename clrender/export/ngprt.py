"""NGP-RT to the page: occupancy mip, G and the coarse block index as 3D textures; the
coarse blocks, hash tables and MLP weights as data textures; the kernels' constants as
GLSL defines; every WebGL2 limit the page needs checked first.

The page (web/ngprt.js, web/ngprt_march.frag) marches docs/ngprt.md per pixel in one
fragment shader: the same lattice (bounded: ``k * s``; unbounded: the 13-piece contracted
arc length), the same occupancy test and samples, Eq. 6-8 features for every fusion
variant, compositing and the deferred MLP.

Assets: ``occupancy_0..4`` (R, R, R) uint8, ``G`` (G_res,)*3 uint8, ``coarse_block_index``
(nb,)*3 int32 (3D textures, x slowest as the arrays); ``coarse_blocks`` (rows, TEX_WIDTH,
4) float32, corner ``((b (B+1) + x) (B+1) + y) (B+1) + z`` at CT texels; ``fine_tables``
(rows, TEX_WIDTH, 4), entry ``l T + h`` at texels 2 (l T + h) + 0, 1; ``mlp`` (rows,
TEX_WIDTH, 4): the matrices row by row, 4 outputs a texel, at the offsets ``O_*`` of the
manifest's ``defines``.
"""
from __future__ import annotations

import numpy as np

from ..ngprt.config import (DEFERRED_HIDDEN, FUSION_HIDDEN, N_MIP, T_STOP, VARIANT_CODES,
                            kernel_constants)
from . import limits as L
from .writer import as_texture

F32 = np.float32


def _rows4(w: np.ndarray) -> np.ndarray:
    """(n_in, n_out) -> (n_in * ceil(n_out / 4), 4): each row's outputs, 4 a texel."""
    n_in, n_out = w.shape
    per = -(-n_out // 4)
    out = np.zeros((n_in, per * 4), F32)
    out[:, :n_out] = w
    return out.reshape(-1, 4)


def _mlp_texture(model, where: str) -> tuple[np.ndarray, dict]:
    """All small weights in one data texture; returns it and their texel offsets."""
    a, cfg = model.arrays, model.config
    parts = [("W0", a["deferred_w0"]), ("B0", a["deferred_b0"][None]),
             ("W1", a["deferred_w1"]), ("B1", a["deferred_b1"][None]),
             ("W2", a["deferred_w2"]), ("B2", a["deferred_b2"][None])]
    if cfg.variant == "mlp":
        parts += [("FW0", a["fusion_w0"]), ("FB0", a["fusion_b0"][None]),
                  ("FW1", a["fusion_w1"]), ("FB1", a["fusion_b1"][None])]
    if cfg.n_inv_attention:
        parts += [("INV", a["attention_inv"][None])]
    texels, offsets, n = [], {}, 0
    for name, w in parts:
        t = _rows4(np.asarray(w, F32))
        offsets[f"O_{name}"] = n
        texels.append(t)
        n += len(t)
    return as_texture(where, np.concatenate(texels), 4, "the MLP weights"), offsets


def _glsl_float(x) -> str:
    """A GLSL literal of the float32 value x (9 significant digits: exact round trip)."""
    return f"{float(np.float32(x)):.9e}"


def ngprt_assets(model, where: str) -> tuple[dict, dict]:
    """``(manifest fields, assets)`` of a validated NGP-RT model; :class:`ExportError`
    naming ``where`` and the limit when the page could not render it."""
    cfg, a = model.config, model.arrays
    L.need(where, "MAX_3D_TEXTURE_SIZE", L.MAX_3D_TEXTURE_SIZE, cfg.occ_res,
           f"the occupancy grid ({cfg.occ_res} cells a side, one 3D texture)")
    ct = -(-cfg.coarse_channels // 4)
    blocks = np.asarray(a["coarse_blocks"], F32).reshape(-1, cfg.coarse_channels)
    assets = {f"occupancy_{lev}": np.ascontiguousarray(a[f"occupancy_{lev}"], np.uint8)
              for lev in range(N_MIP)}
    assets["G"] = np.ascontiguousarray(a["G"], np.uint8)
    assets["coarse_block_index"] = np.ascontiguousarray(a["coarse_block_index"], np.int32)
    assets["coarse_blocks"] = as_texture(where, blocks, 4,
                                         f"the coarse grid ({model.n_blocks} blocks)")
    fine = np.asarray(a["fine_tables"], F32).reshape(-1, 8)
    assets["fine_tables"] = as_texture(where, fine, 4,
                                       f"the hash tables ({cfg.L} x 2^{cfg.log2_T} entries)")
    assets["mlp"], offsets = _mlp_texture(model, where)
    consts = kernel_constants()
    defines = {"L_C": cfg.L_C, "OCC_RES": cfg.occ_res, "LEVELS": cfg.L, "T_SIZE": cfg.T, "G_RES": cfg.G_res,
               "CB": cfg.coarse_block, "CC": cfg.coarse_channels, "CT": ct,
               "N_ATT": cfg.n_attention, "VARIANT": VARIANT_CODES[cfg.variant],
               "UNBOUNDED": int(cfg.scene == "unbounded"), "HIDDEN": DEFERRED_HIDDEN,
               "FHIDDEN": FUSION_HIDDEN, "T_STOP": _glsl_float(T_STOP), **offsets}
    defines.update({k: _glsl_float(v) for k, v in consts.items() if k.startswith("SH_C")})
    defines.update({k: v for k, v in consts.items() if k.startswith("VARIANT_")})
    fields = {"defines": defines, "step": model.step, "near": cfg.near, "far": cfg.far,
              "background": [1.0, 1.0, 1.0]}
    return fields, assets
