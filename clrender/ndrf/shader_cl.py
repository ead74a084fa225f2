"""The OpenCL NDRF shader: screen-buffer gather, 2x2 conv + ReLU, 2x2 conv + sigmoid.

Three pixel-parallel passes (``kernels/ndrf_shade.cl``, one per conv layer as in the
paper's WebGL shader) implement docs/ndrf.md; :mod:`clrender.ndrf.shader_ref` is the numpy
reference they are tested against. A :class:`Shader` uploads the meshes, features and
weights once, builds its program once per (device, ``-D`` defines) and keeps its screen
buffers from call to call while the image size stays the same. The passes compute only
what a covered pixel's colour depends on (the kernel file's header says how); pixels no
mesh covers get the background, as the contract says they must.

Examples:
    >>> hits = HitCaster(model).cast_camera(camera)
    >>> shader = Shader(model)
    >>> rgb, ms = shader.shade(camera, hits.tri, hits.bary, model.background)
    >>> ms["ms_gather"], ms["ms_conv0"], ms["ms_conv1"]

References: NDRF (Wan et al., CVPR 2023) §3.2, §3.4; supplement §3.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..device import device_type_name, event_ms, get_runtime, padded, work_group_size
from .baked import validate
from .config import FEATURES, NDRFConfig

F32, I32 = np.float32, np.int32
KERNELS = ("ndrf_gather", "ndrf_conv0", "ndrf_conv1")
BLOCK_FLOATS = 32     # output channels per conv0 block (H_VEC * H_BLOCK)


def _round_up(n: int, m: int) -> int:
    return -(-n // m) * m


def device_layout(device: cl.Device) -> dict:
    """How conv0 is organised on ``device``: ``H_VEC`` floats per vector and
    ``ACCUMULATORS``, the vectors a work-item may keep accumulating (0: one pixel each).

    CPUs: vectors as wide as the device prefers (16 floats with AVX-512, else 8) and about
    half the vector registers (32 zmm or 16 ymm) as accumulators, so each weight vector,
    loaded once, feeds several pixels. GPUs: one pixel per work-item, parallelism from the
    work-items themselves.
    """
    if device_type_name(device) == "GPU":
        return {"H_VEC": 8, "ACCUMULATORS": 0}
    wide = device.preferred_vector_width_float >= 16
    return {"H_VEC": 16 if wide else 8, "ACCUMULATORS": 16 if wide else 8}


def kernel_defines(config: NDRFConfig, h_vec: int = 8, accumulators: int = 0) -> dict:
    """The ``-D`` defines of ``kernels/ndrf_shade.cl`` for a model config.

    The model constants (K, FEATURES, C_IN, HIDDEN, N_FREQ, KSIZE) come from the config;
    the layout follows from :func:`device_layout`, here and nowhere else: conv0 computes
    blocks of up to BLOCK_FLOATS output channels (H_BLOCK vectors of H_VEC floats) for PIX
    adjacent pixels, PIX * H_BLOCK accumulators; H_STRIDE is the hidden width rounded up
    to whole blocks.
    """
    h_block = max(1, min(BLOCK_FLOATS // h_vec, -(-config.hidden // h_vec)))
    return {"K": config.K, "FEATURES": FEATURES, "C_IN": config.c_in,
            "HIDDEN": config.hidden, "N_FREQ": config.n_freq, "KSIZE": config.kernel_size,
            "H_VEC": int(h_vec), "H_BLOCK": h_block,
            "H_STRIDE": _round_up(config.hidden, h_vec * h_block),
            "PIX": max(1, accumulators // h_block)}


def packed_meshes(model) -> dict:
    """The K meshes concatenated for the gather kernel.

    Returns:
        ``face_start`` (K+1,) int32 first face of each mesh (the last entry is the total);
        ``faces`` (sum F_k, 3) int32 indices into the concatenated vertices;
        ``vertices`` (sum V_k, 3) and ``features`` (sum V_k, 8) float32.
    """
    faces, vertices, features, face_start = [], [], [], [0]
    n_vertices = 0
    for k in range(model.config.K):
        v, f, feat = model.mesh(k)
        faces.append(np.asarray(f, I32) + I32(n_vertices))
        vertices.append(np.asarray(v, F32))
        features.append(np.asarray(feat, F32))
        n_vertices += len(v)
        face_start.append(face_start[-1] + len(f))
    return {"face_start": np.asarray(face_start, I32), "faces": np.concatenate(faces),
            "vertices": np.concatenate(vertices), "features": np.concatenate(features)}


def packed_weights(model, defines: dict) -> dict:
    """The conv weights zero-padded to the kernel's strides (see ``kernels/ndrf_shade.cl``).

    Returns ``w0`` (S*S, C_in, H_STRIDE), ``b0`` (H_STRIDE,), ``w1`` (S*S, 3, H_STRIDE)
    (output-major, so a pixel's hidden vector meets contiguous weights), ``b1`` (3,).
    """
    a, cfg = model.arrays, model.config
    S, C, H = cfg.kernel_size, cfg.c_in, cfg.hidden
    hs = defines["H_STRIDE"]
    w0 = np.zeros((S * S, C, hs), F32)
    w0[..., :H] = a["conv0_w"].reshape(S * S, C, H)
    b0 = np.zeros(hs, F32)
    b0[:H] = a["conv0_b"]
    w1 = np.zeros((S * S, 3, hs), F32)
    w1[:, :, :H] = a["conv1_w"].reshape(S * S, H, 3).transpose(0, 2, 1)
    return {"w0": w0, "b0": b0, "w1": w1, "b1": np.asarray(a["conv1_b"], F32)}


class Shader:
    """Shades NDRF hits with OpenCL.

    Args:
        model: an :class:`clrender.ndrf.baked.NDRFModel` (validated here).
        device: OpenCL device spec or :class:`clrender.device.Runtime` (default
            ``$CLRENDER_DEVICE``).
    """

    def __init__(self, model, device=None):
        validate(model, "Shader model")
        self.model, self.config = model, model.config
        self.runtime = rt = get_runtime(device)
        layout = device_layout(rt.device)
        self.defines = kernel_defines(self.config, layout["H_VEC"], layout["ACCUMULATORS"])
        program = rt.program("ndrf_shade.cl", self.defines)
        self._kernels = {name: program.kernel(name) for name in KERNELS}
        self._local: dict = {}
        self._zero = program.kernel("ndrf_zero")
        self._n_faces = [len(model.mesh(k)[1]) for k in range(self.config.K)]
        arrays = {**packed_meshes(model), **packed_weights(model, self.defines)}
        mf = cl.mem_flags
        self._model_bufs = {name: cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                            hostbuf=np.ascontiguousarray(a))
                            for name, a in arrays.items()}
        self._size = None
        self._bufs: dict = {}

    def _frame_buffers(self, width: int, height: int) -> dict:
        """Per-size buffers, re-allocated only when the image size changes. The screen and
        hidden buffers hold the convs' zero padding (layout in kernels/ndrf_shade.cl):
        zeroed once here, never written by the three passes."""
        if self._size != (width, height):
            ctx, q, mf = self.runtime.context, self.runtime.queue, cl.mem_flags
            d, n, K = self.defines, width * height, self.config.K
            r = d["KSIZE"] - 1
            self.screen_cols = width + d["PIX"] - 1 + r
            screen_floats = (height + r) * self.screen_cols * d["C_IN"]
            hidden_floats = (height + r) * (width + r) * d["H_STRIDE"]
            if max(screen_floats, hidden_floats, K * n * 2) >= 2 ** 31:
                raise ValueError(f"{width}x{height} pixels: the shader's buffers would need "
                                 f"more than 2^31 floats (int32 kernel indices)")
            self._bufs = {
                "cam": cl.Buffer(ctx, mf.READ_ONLY, 16 * 4),
                "tri": cl.Buffer(ctx, mf.READ_ONLY, K * n * 4),
                "bary": cl.Buffer(ctx, mf.READ_ONLY, K * n * 8),
                "screen": cl.Buffer(ctx, mf.READ_WRITE, screen_floats * 4),
                "covered": cl.Buffer(ctx, mf.READ_WRITE, n),
                "hidden": cl.Buffer(ctx, mf.READ_WRITE, hidden_floats * 4),
                "rgb": cl.Buffer(ctx, mf.WRITE_ONLY, n * 12),
            }
            for name, size in (("screen", screen_floats), ("hidden", hidden_floats)):
                self._zero(q, (_round_up(size, 64),), None, self._bufs[name], np.int32(size))
            self._size = (width, height)
        return self._bufs

    def _check_hits(self, camera, tri, bary) -> tuple[np.ndarray, np.ndarray]:
        K, h, w = self.config.K, camera.height, camera.width
        tri, bary = np.asarray(tri), np.asarray(bary)
        if tri.shape != (K, h, w) or bary.shape != (K, h, w, 2):
            raise ValueError(f"hits: tri {tri.shape} and bary {bary.shape}, expected "
                             f"(K={K}, H={h}, W={w}) and (K, H, W, 2) for the camera")
        if tri.dtype.kind not in "iu":
            raise ValueError(f"hits: tri has dtype {tri.dtype}, expected int32")
        for k, n_faces in enumerate(self._n_faces):
            lo, hi = (int(tri[k].min()), int(tri[k].max())) if tri[k].size else (-1, -1)
            if lo < -1 or hi >= n_faces:
                raise ValueError(f"hits: tri[{k}] has values in [{lo}, {hi}], expected "
                                 f"-1 (miss) or a face of mesh {k} in [0, {n_faces})")
        return np.ascontiguousarray(tri, I32), np.ascontiguousarray(bary, F32)

    def _gather(self, camera, tri, bary) -> cl.Event:
        w, h = camera.width, camera.height
        b, m, q = self._frame_buffers(w, h), self._model_bufs, self.runtime.queue
        tri, bary = self._check_hits(camera, tri, bary)
        cl.enqueue_copy(q, b["cam"], camera.packed())
        cl.enqueue_copy(q, b["tri"], tri)
        cl.enqueue_copy(q, b["bary"], bary)
        return self._run("ndrf_gather", w, h, b["cam"], np.int32(w), np.int32(h), b["tri"],
                         b["bary"], m["face_start"], m["faces"], m["vertices"],
                         m["features"], np.int32(self.screen_cols), b["screen"],
                         b["covered"])

    def _run(self, name: str, items_x: int, items_y: int, *args) -> cl.Event:
        """Enqueue kernel ``name`` over ``items_x`` x ``items_y`` work-items; the local size
        comes from the device, once per (kernel, size) (:func:`clrender.device.work_group_size`)."""
        key = (name, items_x, items_y)
        if key not in self._local:
            self._local[key] = work_group_size(self._kernels[name], self.runtime.device,
                                               (items_x, items_y))
        local = self._local[key]
        return self._kernels[name](self.runtime.queue, padded((items_x, items_y), local), local,
                                   *args)

    def shade(self, camera, hits_tri, hits_bary, background=None):
        """Shade one frame.

        Args:
            camera: a :class:`clrender.camera.Camera` (rays from ``kernels/camera.h``,
                bit-identical to ``generate_rays``).
            hits_tri: (K, H, W) int32 hit triangles, -1 for a miss.
            hits_bary: (K, H, W, 2) float32 Embree barycentrics (u, v).
            background: RGB in [0, 1] (default: the model's).
        Returns:
            ``(rgb, ms)``: rgb (H, W, 3) float32 in [0, 1]; ms ``{"ms_gather",
            "ms_conv0", "ms_conv1"}`` kernel times in milliseconds (OpenCL events).
        """
        w, h = camera.width, camera.height
        bg = self.model.background if background is None else background
        bg = [F32(c) for c in np.asarray(bg, np.float64).reshape(3)]
        ev_gather = self._gather(camera, hits_tri, hits_bary)
        b, m = self._bufs, self._model_bufs
        pix = self.defines["PIX"]
        ev_conv0 = self._run("ndrf_conv0", -(-w // pix), h, np.int32(w), np.int32(h),
                             np.int32(self.screen_cols), b["screen"], b["covered"], m["w0"],
                             m["b0"], b["hidden"])
        ev_conv1 = self._run("ndrf_conv1", w, h, np.int32(w), np.int32(h), b["hidden"],
                             b["covered"], m["w1"], m["b1"], *bg, b["rgb"])
        rgb = np.empty((h, w, 3), F32)
        cl.enqueue_copy(self.runtime.queue, rgb, b["rgb"])
        return rgb, {"ms_gather": event_ms(ev_gather), "ms_conv0": event_ms(ev_conv0),
                     "ms_conv1": event_ms(ev_conv1)}

    def screen_buffer(self, camera, hits_tri, hits_bary) -> np.ndarray:
        """The gather pass alone, for tests: (H, W, C_in) float32 as
        :func:`clrender.ndrf.shader_ref.screen_buffer` where a covered pixel lies within
        kernel_size - 1 pixels, features and positions only (view encoding zeros) elsewhere.
        """
        self._gather(camera, hits_tri, hits_bary)
        d, h, w = self.defines, camera.height, camera.width
        out = np.empty((h + d["KSIZE"] - 1, self.screen_cols, d["C_IN"]), F32)
        cl.enqueue_copy(self.runtime.queue, out, self._bufs["screen"])
        return out[:h, :w].copy()
