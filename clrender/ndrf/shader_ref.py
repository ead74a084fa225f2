"""The NDRF shader in numpy: the readable specification of docs/ndrf.md.

Screen buffer (barycentric feature and position gather per mesh, view encoding), the
convolutional shader (two 2x2 layers with alternated padding, or 1x1) and compositing by
coverage, in float32 throughout. ``kernels/ndrf_shade.cl`` (driven by
:mod:`clrender.ndrf.shader_cl`) is tested against these functions.

Examples:
    >>> hits = HitCaster(model).cast_camera(camera)
    >>> _, dirs = generate_rays(camera)
    >>> rgb = shade_reference(model, hits.tri, hits.bary, dirs, model.background)

References: NDRF (Wan et al., CVPR 2023) §3.1-3.2, §3.4; supplement §2 (encodings,
Table 1), §3 (the two-pass shader).
"""
from __future__ import annotations

import numpy as np

F32 = np.float32


def view_encoding(dirs: np.ndarray, n_freq: int) -> np.ndarray:
    """Encoding of unit view directions (docs/ndrf.md "The screen buffer", item 3).

    Args:
        dirs: (..., 3) float32 unit directions d.
        n_freq: number of frequencies N (5 in the paper's WebGL version).
    Returns:
        (..., 3 + 6 N) float32: d, then for i = 0..N-1 sin(2^i d) (x, y, z) and
        cos(2^i d) (x, y, z).
    """
    d = np.asarray(dirs, F32)
    parts = [d]
    for i in range(n_freq):
        a = F32(2.0 ** i) * d
        parts += [np.sin(a), np.cos(a)]
    return np.concatenate(parts, axis=-1).astype(F32)


def _barycentric(values: np.ndarray, faces: np.ndarray, tri: np.ndarray,
                 bary: np.ndarray) -> np.ndarray:
    """(1-u-v) values[i0] + u values[i1] + v values[i2] per hit, zeros on a miss.

    values (V, C), faces (F, 3), tri (...) int (-1 = miss), bary (..., 2) -> (..., C).
    """
    hit = tri >= 0
    idx = faces[np.where(hit, tri, 0)]                           # (..., 3)
    u, v = bary[..., 0:1].astype(F32), bary[..., 1:2].astype(F32)
    w = F32(1.0) - u - v
    out = w * values[idx[..., 0]] + u * values[idx[..., 1]] + v * values[idx[..., 2]]
    return np.where(hit[..., None], out, F32(0.0)).astype(F32)


def screen_buffer(model, tri: np.ndarray, bary: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """The shader's input: per pixel, K features, K hit positions, the view encoding.

    Args:
        model: an :class:`clrender.ndrf.baked.NDRFModel`.
        tri: (K, H, W) int32 hit triangles, -1 for a miss (:class:`clrender.ndrf.hits.Hits`).
        bary: (K, H, W, 2) float32 Embree barycentrics (u, v).
        dirs: (H, W, 3) float32 unit ray directions (``clrender.camera.generate_rays``).
    Returns:
        (H, W, C_in) float32, channels [8K features | 3K positions (world units) |
        3 + 6 n_freq view encoding], zeros for the meshes a pixel misses.
    """
    K = model.config.K
    features, positions = [], []
    for k in range(K):
        vertices, faces, feats = model.mesh(k)
        features.append(_barycentric(feats, faces, tri[k], bary[k]))
        positions.append(_barycentric(vertices, faces, tri[k], bary[k]))
    view = view_encoding(dirs, model.config.n_freq)
    return np.concatenate(features + positions + [view], axis=-1).astype(F32)


def _conv(x: np.ndarray, w: np.ndarray, b: np.ndarray, pad_before: int) -> np.ndarray:
    """b[o] + sum_{dy,dx,c} w[dy, dx, c, o] x[y - pad + dy, x - pad + dx, c], zeros outside.

    x (H, W, C), w (S, S, C, O), b (O,) -> (H, W, O) float32; the S-1 rows and columns of
    zero padding go before the image (top/left) when pad_before, else after it.
    """
    S = w.shape[0]
    h, wd = x.shape[:2]
    p = S - 1
    pads = ((p, 0), (p, 0), (0, 0)) if pad_before else ((0, p), (0, p), (0, 0))
    xp = np.pad(x, pads)
    out = np.broadcast_to(b.astype(F32), (h, wd, w.shape[3])).copy()
    for dy in range(S):
        for dx in range(S):
            out += xp[dy:dy + h, dx:dx + wd] @ w[dy, dx]
    return out


def sigmoid(x: np.ndarray) -> np.ndarray:
    """1 / (1 + exp(-x)) in float32 (exp overflows to inf for x << 0, giving 0)."""
    with np.errstate(over="ignore"):
        return (F32(1.0) / (F32(1.0) + np.exp(-x.astype(F32)))).astype(F32)


def conv_shader(model, buf: np.ndarray) -> np.ndarray:
    """The convolutional shader (docs/ndrf.md, supplement Table 1, WebGL version).

    Layer 0: S x S conv C_in -> H padded bottom/right, ReLU; layer 1: S x S conv H -> 3
    padded top/left, sigmoid (S = kernel_size: 2, or 1 for the "MLP" ablation). The
    alternated padding centres the 3x3 receptive field on the pixel.

    Args:
        model: an :class:`clrender.ndrf.baked.NDRFModel`.
        buf: (H, W, C_in) float32 screen buffer (:func:`screen_buffer`).
    Returns:
        (H, W, 3) float32 shader output s in (0, 1), before compositing.
    """
    a = model.arrays
    hidden = np.maximum(_conv(np.asarray(buf, F32), a["conv0_w"], a["conv0_b"], False),
                        F32(0.0))
    return sigmoid(_conv(hidden, a["conv1_w"], a["conv1_b"], True))


def shade_reference(model, tri: np.ndarray, bary: np.ndarray, dirs: np.ndarray,
                    background) -> np.ndarray:
    """One NDRF frame: screen buffer, conv shader, compositing on the background.

    Args:
        model: an :class:`clrender.ndrf.baked.NDRFModel`.
        tri: (K, H, W) int32, -1 for a miss; bary: (K, H, W, 2) float32 (Embree u, v).
        dirs: (H, W, 3) float32 unit ray directions.
        background: RGB in [0, 1].
    Returns:
        rgb: (H, W, 3) float32, ``coverage * s + (1 - coverage) * background`` where
        coverage is 1 for pixels whose ray hits any mesh.
    """
    s = conv_shader(model, screen_buffer(model, tri, bary, dirs))
    coverage = (np.asarray(tri) >= 0).any(axis=0)[..., None].astype(F32)
    bg = np.asarray(background, F32).reshape(3)
    return (coverage * s + (F32(1.0) - coverage) * bg).astype(F32)

