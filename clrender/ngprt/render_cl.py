"""The OpenCL NGP-RT renderer: ray marching then the deferred MLP, per pixel.

Two kernels (``kernels/ngprt_march.cl``, ``kernels/ngprt_deferred.cl``) implement the
rendering contract of docs/ngprt.md; ``clrender/ngprt/render_ref.py`` is the numpy
reference they are tested against. A :class:`Renderer` uploads a baked model once and
builds its programs once per (device, ``-D`` defines).

Examples:
    >>> from clrender.ngprt.baked import load_baked
    >>> r = Renderer(load_baked("model.npz"))
    >>> out = r.render(camera)           # out["rgb"]: (H, W, 3) float32
    >>> out["ms_march"], out["ms_deferred"]

References: NGP-RT (Hu et al., ECCV 2024) §4.3, S2.5.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..device import device_type_name, event_ms, get_runtime
from .config import DEFERRED_HIDDEN, FEATURES, FUSION_HIDDEN, N_MIP, SH_DIM, VARIANTS

F32 = np.float32
# The integer codes of VARIANT in kernels/ngprt_common.h (VARIANT_SUM ... VARIANT_SEPARATE_V).
VARIANT_CODES = {"sum": 0, "mlp": 1, "shared-inv": 2, "separate-inv": 3, "shared-v": 4,
                 "separate-v": 5}
assert set(VARIANT_CODES) == set(VARIANTS)
MARCH_LOCAL = (8, 8)          # a tile of pixels per work-group: neighbouring rays share cache
# Small deferred work-groups: a CPU driver keeps every work-item's private activations
# (~10 KB at DEFERRED_VEC=16) on one stack, and large groups overflow it. 16 pixels per
# work-item measured fastest on the 2-core Xeon (PoCL): 68 ms vs 116 (8) and 205 (4)
# for 400x400.
DEFERRED_LOCAL = 8
DEFERRED_PARAMS = ("deferred_w0", "deferred_b0", "deferred_w1", "deferred_b1",
                   "deferred_w2", "deferred_b2")


def kernel_defines(config, use_G: bool, deferred_vec: int = 1) -> tuple[dict, dict]:
    """The ``-D`` defines of the march and deferred programs for a model config: the
    shared constants of :func:`clrender.ngprt.config.kernel_constants` (the kernels define
    none of their own) plus the model's sizes, variant and scene."""
    from .config import VARIANT_CODES as codes, kernel_constants   # the one source

    shared = kernel_constants()
    march = {
        **shared, "L": config.L, "L_C": config.L_C, "LOG2_T": config.log2_T,
        "VARIANT": codes[config.variant], "UNBOUNDED": config.scene == "unbounded",
        "USE_G": bool(use_G), "G_RES": config.G_res,
        "COARSE_BLOCK": config.coarse_block, "N_ATT": config.n_attention,
        "N_INV": config.n_inv_attention,
    }
    return march, {**shared, "DEFERRED_VEC": deferred_vec}


def _packed(arrays: dict, names, shapes) -> np.ndarray:
    parts = []
    for name, shape in zip(names, shapes):
        a = np.asarray(arrays[name])
        if a.shape != shape:
            raise ValueError(f"baked model: {name} has shape {a.shape}, expected {shape}")
        parts.append(a.astype(F32).reshape(-1))
    return np.concatenate(parts)


def fusion_params(model) -> np.ndarray:
    """The per-variant fusion parameters packed as the march kernel reads them."""
    cfg, arrays = model.config, model.arrays
    if cfg.variant == "mlp":
        return _packed(arrays, ("fusion_w0", "fusion_b0", "fusion_w1", "fusion_b1"),
                       ((FEATURES * cfg.L, FUSION_HIDDEN), (FUSION_HIDDEN,),
                        (FUSION_HIDDEN, FEATURES), (FEATURES,)))
    if cfg.n_inv_attention:
        return _packed(arrays, ("attention_inv",), ((cfg.n_inv_attention,),))
    return np.zeros(1, F32)


def deferred_params(model) -> np.ndarray:
    """The deferred MLP's weights packed as [w0, b0, w1, b1, w2, b2] (float32)."""
    n_in, h = 7 + SH_DIM, DEFERRED_HIDDEN
    return _packed(model.arrays, DEFERRED_PARAMS,
                   ((n_in, h), (h,), (h, h), (h,), (h, 3), (3,)))


def occupancy_mip(model) -> np.ndarray:
    """``occupancy_0 .. occupancy_4`` concatenated (uint8), finest level first."""
    cfg = model.config
    parts = []
    for lev in range(N_MIP):
        r = cfg.L_C >> lev
        a = np.asarray(model.arrays[f"occupancy_{lev}"])
        if a.shape != (r, r, r):
            raise ValueError(f"baked model: occupancy_{lev} has shape {a.shape}, "
                             f"expected ({r}, {r}, {r})")
        parts.append((a != 0).astype(np.uint8).reshape(-1))
    return np.concatenate(parts)


class Renderer:
    """Renders a baked NGP-RT model with OpenCL; the model is uploaded once, per-frame
    buffers are kept while the image size stays the same.

    Args:
        model: a :class:`clrender.ngprt.baked.BakedModel` (``.config``, ``.step``,
            ``.arrays``), validated by its loader.
        device: OpenCL device spec or :class:`clrender.device.Runtime` (default
            ``$CLRENDER_DEVICE``).
        use_G: skip empty space with the occupancy distance grid G (paper §4.3).
    """

    SCALAR_STATS = {"Marching": "n_march", "Occupied": "n_occ"}
    RENDER_OPTIONS = {"use_G": bool}
    TIME_NOTE = "OpenCL kernel time per frame (ray marching + deferred MLP)"

    def __init__(self, model, device=None, use_G: bool = True):
        self.model, self.config, self.use_G = model, model.config, bool(use_G)
        self.runtime = rt = get_runtime(device)
        self.deferred_vec = 16 if device_type_name(rt.device) == "CPU" else 1
        march_defs, deferred_defs = kernel_defines(self.config, self.use_G, self.deferred_vec)
        self._march = rt.program("ngprt_march.cl", march_defs).kernel("ngprt_march")
        self._deferred = rt.program("ngprt_deferred.cl", deferred_defs).kernel("ngprt_deferred")
        self.step = F32(model.step)
        self._upload()

    def _buffer(self, array: np.ndarray) -> cl.Buffer:
        mf = cl.mem_flags
        a = np.ascontiguousarray(array)
        return cl.Buffer(self.runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)

    def _upload(self):
        cfg, arrays = self.config, self.model.arrays
        blocks = np.asarray(arrays["coarse_blocks"], F32)
        expected = (cfg.coarse_block + 1,) * 3 + (cfg.coarse_channels,)
        if blocks.ndim != 5 or blocks.shape[1:] != expected:
            raise ValueError(f"baked model: coarse_blocks has shape {blocks.shape}, "
                             f"expected (n_blocks, {', '.join(map(str, expected))})")
        tables = np.asarray(arrays["fine_tables"], F32)
        if tables.shape != (cfg.L, cfg.T, FEATURES):
            raise ValueError(f"baked model: fine_tables has shape {tables.shape}, "
                             f"expected (L={cfg.L}, T={cfg.T}, {FEATURES})")
        for name, res in (("G", cfg.G_res), ("coarse_block_index", cfg.L_C // cfg.coarse_block)):
            if np.shape(arrays[name]) != (res,) * 3:
                raise ValueError(f"baked model: {name} has shape {np.shape(arrays[name])}, "
                                 f"expected ({res}, {res}, {res})")
        self.n_blocks = np.int32(blocks.shape[0])
        # Each corner padded to a multiple of 8 floats: aligned float8 reads (S2.5, 4).
        stride = FEATURES * (1 + -(-cfg.n_attention // FEATURES))
        padded = np.zeros(blocks.shape[:4] + (stride,), F32)
        padded[..., :blocks.shape[4]] = blocks
        self._bufs = {
            "occ": self._buffer(occupancy_mip(self.model)),
            "G": self._buffer(np.asarray(arrays["G"], np.uint8)),
            "block_index": self._buffer(np.asarray(arrays["coarse_block_index"], np.int32)),
            "blocks": self._buffer(padded if padded.size else np.zeros(FEATURES, F32)),
            "tables": self._buffer(tables),
            "fusion": self._buffer(fusion_params(self.model)),
            "deferred": self._buffer(deferred_params(self.model)),
        }

    def _outputs(self, camera) -> dict:
        """Per-frame buffers, kept across frames of the same size (re-allocated otherwise)."""
        n = camera.width * camera.height
        if getattr(self, "_frame_n", None) != n:
            ctx, mf = self.runtime.context, cl.mem_flags
            self._frame = {"cam": cl.Buffer(ctx, mf.READ_ONLY, 16 * 4),
                           "feat": cl.Buffer(ctx, mf.READ_WRITE, 32 * n),
                           "depth": cl.Buffer(ctx, mf.WRITE_ONLY, 4 * n),
                           "n_march": cl.Buffer(ctx, mf.WRITE_ONLY, 4 * n),
                           "n_occ": cl.Buffer(ctx, mf.WRITE_ONLY, 4 * n),
                           "rgb": cl.Buffer(ctx, mf.WRITE_ONLY, 12 * n)}
            self._frame_n = n
        cl.enqueue_copy(self.runtime.queue, self._frame["cam"], camera.packed())
        return self._frame

    def _enqueue_march(self, camera, out) -> cl.Event:
        cfg, b = self.config, self._bufs
        lx, ly = MARCH_LOCAL
        gsize = (-(-camera.width // lx) * lx, -(-camera.height // ly) * ly)
        return self._march(
            self.runtime.queue, gsize, MARCH_LOCAL, out["cam"], np.int32(camera.width),
            np.int32(camera.height), self.step, F32(cfg.near), F32(cfg.far), b["occ"], b["G"],
            b["block_index"], b["blocks"], self.n_blocks, b["tables"], b["fusion"],
            out["feat"], out["depth"], out["n_march"], out["n_occ"])

    def _read(self, buf: cl.Buffer, shape, dtype) -> np.ndarray:
        host = np.empty(shape, dtype)
        cl.enqueue_copy(self.runtime.queue, host, buf)
        return host

    def march(self, camera) -> dict:
        """The march alone, for tests: ``acc`` (H*W, 7), ``opacity``, ``depth`` (H*W,)
        float32, ``n_march``, ``n_occ`` (H*W,) int32, ``ms_march``."""
        n = camera.width * camera.height
        out = self._outputs(camera)
        event = self._enqueue_march(camera, out)
        feat = self._read(out["feat"], (n, 8), F32)
        return {"acc": feat[:, :7].copy(), "opacity": feat[:, 7].copy(),
                "depth": self._read(out["depth"], (n,), F32),
                "n_march": self._read(out["n_march"], (n,), np.int32),
                "n_occ": self._read(out["n_occ"], (n,), np.int32), "ms_march": event_ms(event)}

    def render(self, camera, background=(1.0, 1.0, 1.0), stats: bool = False) -> dict:
        """Render one view; only ``rgb`` is read back unless ``stats`` is asked for.

        Args:
            camera: a :class:`clrender.camera.Camera`.
            background: RGB in [0, 1] composited behind the model (None: white).
            stats: also read back the per-pixel statistics.
        Returns:
            dict with ``rgb`` (H, W, 3) float32 in [0, 1]; ``ms_march``, ``ms_deferred``:
            kernel times in milliseconds and ``ms`` their sum. With ``stats``: ``n_march``,
            ``n_occ`` (H, W) int32 marching points and occupied samples per ray; ``depth``
            (H, W) float32 world units along the ray (0 where nothing was hit); ``opacity``
            (H, W) float32.
        """
        h, w, n = camera.height, camera.width, camera.width * camera.height
        out = self._outputs(camera)
        ev_march = self._enqueue_march(camera, out)
        bg = [F32(c) for c in (background if background is not None else (1.0, 1.0, 1.0))]
        n_items = -(-n // (self.deferred_vec * DEFERRED_LOCAL)) * DEFERRED_LOCAL
        ev_deferred = self._deferred(self.runtime.queue, (n_items,), (DEFERRED_LOCAL,),
                                     out["cam"], np.int32(w), np.int32(n), out["feat"],
                                     self._bufs["deferred"], *bg, out["rgb"])
        result = {"rgb": self._read(out["rgb"], (h, w, 3), F32),
                  "ms_march": event_ms(ev_march), "ms_deferred": event_ms(ev_deferred)}
        result["ms"] = result["ms_march"] + result["ms_deferred"]
        if stats:
            result.update(
                n_march=self._read(out["n_march"], (h, w), np.int32),
                n_occ=self._read(out["n_occ"], (h, w), np.int32),
                depth=self._read(out["depth"], (h, w), F32),
                opacity=self._read(out["feat"], (n, 8), F32)[:, 7].reshape(h, w).copy())
        return result
