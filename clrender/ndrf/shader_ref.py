"""The NDRF shader in numpy: the readable specification of docs/ndrf.md.

Screen buffer (barycentric feature and position gather per mesh, view encoding), the
convolutional shader (two 2x2 layers with alternated padding, or 1x1) and compositing by
coverage, in float32 throughout. ``kernels/ndrf_shade.cl`` (driven by
:mod:`clrender.ndrf.shader_cl`) is tested against these functions. Its conv0 computes a
factored form, read here function by function: :func:`vertex_projections` and
:func:`view_weights` (what the kernel is given) and :func:`conv0_factored` (what it
computes with them), equal to the layer of :func:`conv_shader` by linearity.

Examples:
    >>> hits = HitCaster(model).cast_camera(camera)
    >>> _, dirs = generate_rays(camera)
    >>> rgb = shade_reference(model, hits.tri, hits.bary, dirs, model.background)

References: NDRF (Wan et al., CVPR 2023) §3.1-3.2, §3.4; supplement §2 (encodings,
Table 1), §3 (the two-pass shader).
"""
from __future__ import annotations

import numpy as np

from .config import FEATURES

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


def barycentric(values: np.ndarray, faces: np.ndarray, tri: np.ndarray,
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
        features.append(barycentric(feats, faces, tri[k], bary[k]))
        positions.append(barycentric(vertices, faces, tri[k], bary[k]))
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


# ---- conv0 factored by linearity, as kernels/ndrf_shade.cl computes it ----------------

def vertex_projections(model, defines: dict) -> np.ndarray:
    """conv0's weights applied to every vertex's geometry channels, per tap.

    Returns (sum V_k, S*S, H_STRIDE) float32: for vertex v of mesh k and tap t,
    W_t[features of k] @ features[v] + W_t[positions of k] @ vertices[v] (float64, then
    rounded), zero-padded; conv0 blends these by a hit's barycentrics (linearity).
    """
    a, cfg = model.arrays, model.config
    S, C, H, K = cfg.kernel_size, cfg.c_in, cfg.hidden, cfg.K
    w = np.asarray(a["conv0_w"], np.float64).reshape(S * S, C, H)
    out = []
    for k in range(K):
        vertices, _, feats = model.mesh(k)
        p = (np.einsum("vc,tch->vth", np.asarray(feats, np.float64),
                       w[:, FEATURES * k:FEATURES * (k + 1)])
             + np.einsum("vc,tch->vth", np.asarray(vertices, np.float64),
                         w[:, FEATURES * K + 3 * k:FEATURES * K + 3 * (k + 1)]))
        out.append(p)
    proj = np.zeros((sum(len(p) for p in out), S * S, defines["H_STRIDE"]), F32)
    proj[..., :H] = np.concatenate(out)
    return proj


def view_weights(model, defines: dict, exact: bool) -> np.ndarray:
    """conv0's view-channel weights as the kernel's build reads them.

    exact: (S*S, VIEW_C, H_STRIDE) float32, the weights of the view encoding's channels.
    Otherwise the table (3, VIEW_NODES, S*S, 2, H_STRIDE) float32: for direction component
    c, node s_n = -1 + 2n / (VIEW_NODES - 1) and tap t, the value f(s_n) of the sum of the
    weights of d_c, sin(2^i d_c) and cos(2^i d_c) times those functions, then the step to
    the next node f(s_{n+1}) - f(s_n) (0 at the last; float64, then rounded): a pixel's view
    contribution is the sum over c of this 1D function at d_c, which the kernel interpolates
    linearly (max error ~ h^2 / 8 * |f''|, h = 2 / (VIEW_NODES - 1)) from one row pair, the
    taps of a node side by side.
    """
    a, cfg = model.arrays, model.config
    S, C, H, N = cfg.kernel_size, cfg.c_in, cfg.hidden, cfg.n_freq
    w = np.asarray(a["conv0_w"], np.float64).reshape(S * S, C, H)[:, C - cfg.view_channels:]
    if exact:
        out = np.zeros((S * S, cfg.view_channels, defines["H_STRIDE"]), F32)
        out[..., :H] = w
        return out
    s = np.linspace(-1.0, 1.0, defines["VIEW_NODES"])
    table = np.zeros((3, len(s), S * S, 2, defines["H_STRIDE"]), F32)
    for c in range(3):
        f = s[:, None, None] * w[None, :, c]
        for i in range(N):
            f = (f + np.sin(2.0 ** i * s)[:, None, None] * w[None, :, 3 + 6 * i + c]
                 + np.cos(2.0 ** i * s)[:, None, None] * w[None, :, 6 + 6 * i + c])
        table[c, :, :, 0, :H] = f
        table[c, :-1, :, 1, :H] = f[1:] - f[:-1]
    return table


def conv0_factored(model, tri: np.ndarray, bary: np.ndarray, dirs: np.ndarray,
                   proj: np.ndarray, w_view: np.ndarray, b0: np.ndarray,
                   exact: bool = True) -> np.ndarray:
    """conv0's output before the ReLU, computed as the kernel does: for each tap t and
    input pixel q (padding bottom/right), the barycentric blend of the hit vertices' rows
    of ``proj`` per mesh, plus the view term: the view encoding at q times ``w_view[t]``
    (exact build), or the sum over direction components c of the table's 1D function at
    d_c, interpolated linearly between its nodes (fast build).

    Args:
        tri, bary, dirs: as :func:`screen_buffer`.
        proj, w_view: :func:`vertex_projections`, :func:`view_weights` (``exact`` picks
            its form); b0: (H_STRIDE,) bias.
    Returns:
        (H, W, H_STRIDE) float32 (float64 sums, then rounded).
    """
    cfg = model.config
    S, h, w = cfg.kernel_size, tri.shape[1], tri.shape[2]
    geo = np.zeros((h, w, S * S, proj.shape[-1]))
    offset = 0
    for k in range(cfg.K):
        vertices, faces, _ = model.mesh(k)
        rows = proj[offset:offset + len(vertices)].astype(np.float64)
        geo += barycentric(rows.reshape(len(rows), -1), faces, tri[k],
                            bary[k]).astype(np.float64).reshape(geo.shape)
        offset += len(vertices)
    if exact:
        view = np.einsum("hwc,tco->hwto", view_encoding(dirs, cfg.n_freq).astype(np.float64),
                         w_view.astype(np.float64))
    else:
        n = w_view.shape[1]
        pos = (np.clip(dirs.astype(np.float64), -1.0, 1.0) + 1.0) * 0.5 * (n - 1)
        node = np.minimum(np.floor(pos).astype(np.int64), n - 1)
        frac = pos - node
        view = sum(w_view[c, node[..., c], :, 0].astype(np.float64)
                   + frac[..., c, None, None] * w_view[c, node[..., c], :, 1]
                   for c in range(3))
    per_tap = geo + view                                    # (H, W, taps, H_STRIDE)
    padded = np.pad(per_tap, ((0, S - 1), (0, S - 1), (0, 0), (0, 0)))
    out = np.broadcast_to(b0.astype(np.float64), (h, w, proj.shape[-1])).copy()
    for dy in range(S):
        for dx in range(S):
            out += padded[dy:dy + h, dx:dx + w, dy * S + dx]
    return out.astype(F32)
