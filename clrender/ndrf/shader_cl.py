"""The OpenCL NDRF shader: 2x2 conv + ReLU over the gathered screen pixels, 2x2 conv +
sigmoid.

Two pixel-parallel passes (``kernels/ndrf_shade.cl``, one per conv layer as in the paper's
WebGL shader) implement docs/ndrf.md; :mod:`clrender.ndrf.shader_ref` is the numpy
reference they are tested against. The first pass computes the conv factored by linearity
(docs/ndrf.md, "How the OpenCL kernel computes layer 0"): per-vertex projections of the
geometry channels (:func:`vertex_projections`) blended by each hit's barycentrics, and the
view channels' weights (exact build) or their table (fast build, :func:`view_weights`),
all made once when the model is loaded; no screen buffer goes through global memory. A
:class:`Shader` uploads them once, builds its program once per (device, ``-D`` defines,
build) and keeps its frame buffers while the image size stays the same. The hits come from
the device (:meth:`Shader.shade_device`, the rasteriser's buffers) or from the host
(:meth:`Shader.shade`, Embree's arrays, uploaded). The passes compute only what a covered
pixel's colour depends on; pixels no mesh covers get the background, as the contract says
they must.

Examples:
    >>> hits = HitCaster(model).cast_camera(camera)
    >>> shader = Shader(model)
    >>> rgb, ms = shader.shade(camera, hits.tri, hits.bary, model.background)
    >>> ms["ms_conv0"], ms["ms_conv1"]

References: NDRF (Wan et al., CVPR 2023) §3.2, §3.4; supplement §3.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..camera import CAM_BYTES
from ..device import (check_allocation, device_type_name, event_ms, get_runtime, padded,
                      work_group_size)
from .baked import validate
from .config import FEATURES, NDRFConfig
from .raster_cl import packed_geometry, vertices_in_morton_order
from .shader_ref import view_weights, vertex_projections

F32, I32 = np.float32, np.int32
KERNELS = ("ndrf_conv0", "ndrf_conv1", "ndrf_screen", "ndrf_zero_padding")
VIEW_NODES = 1025     # nodes of the fast build's view table over [-1, 1]
GPU_LAYOUT = {"H_VEC": 8, "SEG": 1, "ROWS": 1}   # device_layout on GPUs


def _round_up(n: int, m: int) -> int:
    return -(-n // m) * m


def device_layout(device: cl.Device) -> dict:
    """How conv0 is organised on ``device``: ``H_VEC`` floats per vector, and the block of
    outputs a work-item computes, ``SEG`` pixels wide and ``ROWS`` high (it gathers its
    (SEG + 1) x (ROWS + 1) input pixels once).

    CPUs: vectors as wide as the device prefers (16 floats with AVX-512, else 8), blocks of
    8 x 4 pixels (45 input pixels for 32 outputs, instead of 4 a pixel); GPUs: one pixel
    per work-item, parallelism from the work-items themselves.
    """
    if device_type_name(device) == "GPU":
        return dict(GPU_LAYOUT)
    return {"H_VEC": 16 if device.preferred_vector_width_float >= 16 else 8, "SEG": 8,
            "ROWS": 4}


def kernel_defines(config: NDRFConfig, h_vec: int = 8, seg: int = 1, rows: int = 1) -> dict:
    """The ``-D`` defines of ``kernels/ndrf_shade.cl`` for a model config.

    The model constants (K, FEATURES, C_IN, HIDDEN, N_FREQ, KSIZE) come from the config;
    the layout (H_VEC, SEG, ROWS) from :func:`device_layout`; H_STRIDE is the hidden width
    rounded up to whole vectors; VIEW_NODES the fast build's view table nodes.
    """
    return {"K": config.K, "FEATURES": FEATURES, "C_IN": config.c_in,
            "HIDDEN": config.hidden, "N_FREQ": config.n_freq, "KSIZE": config.kernel_size,
            "H_VEC": int(h_vec), "H_STRIDE": _round_up(config.hidden, h_vec),
            "SEG": max(1, int(seg)), "ROWS": max(1, int(rows)), "VIEW_NODES": VIEW_NODES}


def packed_meshes(model) -> dict:
    """The K meshes concatenated for the gather, each mesh's vertices in Morton order
    (:func:`clrender.ndrf.raster_cl.vertices_in_morton_order`: neighbouring pixels' vertex
    rows lie close in memory), faces in their own order: :func:`clrender.ndrf.raster_cl.packed_geometry`
    (``face_start``, ``faces``, ``vertices``), ``features`` (sum V_k, 8) float32 and
    ``vertex_order`` (sum V_k,) int32, the concatenated vertex each row holds."""
    meshes, features, order, offset = [], [], [], 0
    for k in range(model.config.K):
        vertices, faces, perm = vertices_in_morton_order(*model.mesh(k)[:2])
        meshes.append((vertices, faces))
        features.append(np.asarray(model.mesh(k)[2], F32)[perm])
        order.append(perm + offset)
        offset += len(perm)
    return {**packed_geometry(meshes), "features": np.concatenate(features),
            "vertex_order": np.concatenate(order)}


def packed_weights(model, defines: dict, exact: bool) -> dict:
    """The conv weights as the kernels read them (see ``kernels/ndrf_shade.cl``).

    Returns ``proj`` (:func:`vertex_projections`), ``w_view`` (:func:`view_weights`),
    ``b0`` (H_STRIDE,), ``w1`` (S*S, 3, H_STRIDE) (output-major, so a pixel's hidden vector
    meets contiguous weights), ``b1`` (3,), all float32 and zero-padded to H_STRIDE.
    """
    a, cfg = model.arrays, model.config
    S, H = cfg.kernel_size, cfg.hidden
    hs = defines["H_STRIDE"]
    b0 = np.zeros(hs, F32)
    b0[:H] = a["conv0_b"]
    w1 = np.zeros((S * S, 3, hs), F32)
    w1[:, :, :H] = a["conv1_w"].reshape(S * S, H, 3).transpose(0, 2, 1)
    return {"proj": vertex_projections(model, defines),
            "w_view": view_weights(model, defines, exact), "b0": b0, "w1": w1,
            "b1": np.asarray(a["conv1_b"], F32)}


class Shader:
    """Shades NDRF hits with OpenCL.

    Args:
        model: an :class:`clrender.ndrf.baked.NDRFModel` (validated here).
        device: OpenCL device spec or :class:`clrender.device.Runtime` (default
            ``$CLRENDER_DEVICE``).
        exact: the exact build (``Runtime.program(exact=True)``, held to the numpy
            reference in tests); default the fast build (the view table, native exp).
        layout: conv0's organisation (``H_VEC``, ``SEG``, ``ROWS``); None:
            :func:`device_layout` of the device.
    """

    def __init__(self, model, device=None, exact: bool = False, layout: dict | None = None):
        validate(model, "Shader model")
        self.model, self.config = model, model.config
        self.runtime = rt = get_runtime(device)
        self.exact = bool(exact)
        layout = device_layout(rt.device) if layout is None else layout
        self.defines = kernel_defines(self.config, layout["H_VEC"], layout["SEG"],
                                      layout["ROWS"])
        program = rt.program("ndrf_shade.cl", self.defines, self.exact)
        self._kernels = {name: program.kernel(name) for name in KERNELS}
        self._local: dict = {}
        self._n_faces = [len(model.mesh(k)[1]) for k in range(self.config.K)]
        arrays = {**packed_meshes(model), **packed_weights(model, self.defines, self.exact)}
        arrays["proj"] = arrays["proj"][arrays.pop("vertex_order")]
        mf = cl.mem_flags
        self._model_bufs = {name: cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                            hostbuf=np.ascontiguousarray(a))
                            for name, a in arrays.items()}
        self.projection_bytes = arrays["proj"].nbytes   # the table conv0 gathers rows of
        self._size = None
        self._bufs: dict = {}

    def band_rows(self, width: int, height: int) -> int:
        """Image rows shaded a band: all of them where the hidden layer fits the device's
        largest buffer, else as many as fit (at least one; kernels/ndrf_shade.cl)."""
        pad = self.defines["KSIZE"] - 1
        row_bytes = (width + pad) * self.defines["H_STRIDE"] * 4
        fits = self.runtime.device.max_mem_alloc_size // row_bytes - pad
        return int(max(1, min(height, fits)))

    @property
    def kernels(self) -> dict:
        """``{kernel name: cl.Kernel}`` of the program."""
        return dict(self._kernels)

    def launch_sizes(self, width: int, height: int) -> list[tuple[str, tuple[int, int]]]:
        """The kernel launches of a ``width`` x ``height`` frame, in order: the hidden
        band's padding zeroed (once per image size; every frame where the image takes
        several bands), then conv0 and conv1 per band of :meth:`band_rows` rows:
        ``(kernel name, global work-items (x, y) before padding to the work-group size)``."""
        band = self.band_rows(width, height)
        out = [("ndrf_zero_padding", self._padding_size(width, band))]
        for y in range(0, height, band):
            out += list(self._band_sizes(width, y, min(y + band, height)).items())
        return out

    def _padding_size(self, width: int, band: int) -> tuple[int, int]:
        r = self.defines["KSIZE"] - 1
        return (width + r, band + r)

    def _band_sizes(self, width: int, y: int, end: int) -> dict:
        """Work-items of conv0 and conv1 for the band of rows [y, end)."""
        seg, rows, pad = self.defines["SEG"], self.defines["ROWS"], self.defines["KSIZE"] - 1
        return {"ndrf_conv0": (-(-width // seg), -(-(end - max(y - pad, 0)) // rows)),
                "ndrf_conv1": (width, end - y)}

    def _frame_buffers(self, width: int, height: int) -> dict:
        """Per-size buffers, re-allocated only when the image size changes: the camera, one
        band of the hidden layer (its padding columns zeroed here, never written by the
        passes; layout in kernels/ndrf_shade.cl), the image and, once hits are uploaded,
        their buffers."""
        if self._size != (width, height):
            ctx, mf = self.runtime.context, cl.mem_flags
            d, n = self.defines, width * height
            r = d["KSIZE"] - 1
            self._band = self.band_rows(width, height)
            hidden_floats = (self._band + r) * (width + r) * d["H_STRIDE"]
            self._bufs = {"cam": cl.Buffer(ctx, mf.READ_ONLY, CAM_BYTES)}
            self._bufs.update(self._allocate(width, height, {"hidden": hidden_floats * 4,
                                                             "rgb": n * 12}))
            self._zero_padding(width, top_rows=True)
            self._size = (width, height)
        return self._bufs

    def _zero_padding(self, width: int, top_rows: bool) -> cl.Event:
        return self._run("ndrf_zero_padding", *self._padding_size(width, self._band),
                         np.int32(width), np.int32(self._band), np.int32(top_rows),
                         self._bufs["hidden"])

    def _allocate(self, width: int, height: int, sizes: dict) -> dict:
        """``{name: device buffer}`` of ``sizes`` bytes, each checked against the device's
        largest allocation first."""
        for name, nbytes in sizes.items():
            check_allocation(self.runtime.device, f"shader buffer '{name}' for "
                             f"{width}x{height} pixels", nbytes)
        return {name: cl.Buffer(self.runtime.context, cl.mem_flags.READ_WRITE, nbytes)
                for name, nbytes in sizes.items()}

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

    def upload_hits(self, camera, hits_tri, hits_bary) -> tuple[cl.Buffer, cl.Buffer]:
        """Host hits (validated) copied into this shader's frame buffers for ``camera``;
        the copies block (the host-hit path: Embree, tests)."""
        w, h = camera.width, camera.height
        b, q = self._frame_buffers(w, h), self.runtime.queue
        tri, bary = self._check_hits(camera, hits_tri, hits_bary)
        if "tri" not in b:
            b.update(self._allocate(w, h, {"tri": tri.nbytes, "bary": bary.nbytes}))
        cl.enqueue_copy(q, b["tri"], tri)
        cl.enqueue_copy(q, b["bary"], bary)
        return b["tri"], b["bary"]

    def _frame_args(self, camera, tri_buf, bary_buf) -> tuple:
        m = self._model_bufs
        return (self._bufs["cam"], np.int32(camera.width), np.int32(camera.height), tri_buf,
                bary_buf, m["face_start"], m["faces"], m["vertices"], m["features"])

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

    def shade_device(self, camera, tri_buf, bary_buf, background=None):
        """Shade one frame from hits already on the device.

        Args:
            camera: a :class:`clrender.camera.Camera` (rays from ``kernels/camera.h``,
                bit-identical to ``generate_rays``).
            tri_buf: device buffer (K, H, W) int32 hit triangles, -1 for a miss, each a
                face of its mesh (the rasteriser's, or :meth:`upload_hits`).
            bary_buf: device buffer (K, H, W, 2) float32 Embree barycentrics (u, v).
            background: RGB in [0, 1] (default: the model's).
        Returns:
            ``(rgb, ms)``: rgb (H, W, 3) float32 in [0, 1]; ms ``{"ms_conv0", "ms_conv1"}``
            kernel times in milliseconds (OpenCL events; the gather runs inside conv0).
            The read of rgb is the only call that waits for the device; the times are
            read after it.
        """
        w, h = camera.width, camera.height
        b, m, q = self._frame_buffers(w, h), self._model_bufs, self.runtime.queue
        bg = self.model.background if background is None else background
        bg = [F32(c) for c in np.asarray(bg, np.float64).reshape(3)]
        # Not waited for: its event (which keeps the host array alive, and would wait for
        # the copy if dropped) is held until the frame's read.
        upload = cl.enqueue_copy(q, b["cam"], camera.packed(), is_blocking=False)
        frame = self._frame_args(camera, tri_buf, bary_buf)
        events = {"ms_conv0": [], "ms_conv1": []}
        for y in range(0, h, self._band):
            end = min(y + self._band, h)
            if y == 0 and self._band < h:   # the last frame's later bands wrote the top rows
                events["ms_conv0"].append(self._zero_padding(w, top_rows=True))
            band, size = (np.int32(y), np.int32(end)), self._band_sizes(w, y, end)
            events["ms_conv0"].append(self._run(
                "ndrf_conv0", *size["ndrf_conv0"], *frame, m["proj"], m["w_view"], m["b0"],
                *band, b["hidden"]))
            events["ms_conv1"].append(self._run("ndrf_conv1", *size["ndrf_conv1"], *frame,
                                                b["hidden"], m["w1"], m["b1"], *bg, *band,
                                                b["rgb"]))
        rgb = np.empty((h, w, 3), F32)
        cl.enqueue_copy(q, rgb, b["rgb"])
        del upload
        return rgb, {name: sum(map(event_ms, evs), 0.0) for name, evs in events.items()}

    def shade(self, camera, hits_tri, hits_bary, background=None):
        """Shade one frame from host hits: ``hits_tri`` (K, H, W) int32 (-1 for a miss),
        ``hits_bary`` (K, H, W, 2) float32, validated and uploaded; as :meth:`shade_device`."""
        tri_buf, bary_buf = self.upload_hits(camera, hits_tri, hits_bary)
        return self.shade_device(camera, tri_buf, bary_buf, background)

    def screen_buffer(self, camera, hits_tri, hits_bary) -> np.ndarray:
        """The gathered screen pixels, for tests: (H, W, C_in) float32 as
        :func:`clrender.ndrf.shader_ref.screen_buffer` (conv0 gathers the same values)."""
        tri_buf, bary_buf = self.upload_hits(camera, hits_tri, hits_bary)
        w, h, c = camera.width, camera.height, self.config.c_in
        q = self.runtime.queue
        cl.enqueue_copy(q, self._bufs["cam"], camera.packed())
        screen = self._allocate(w, h, {"screen": w * h * c * 4})["screen"]
        self._run("ndrf_screen", w, h, *self._frame_args(camera, tri_buf, bary_buf), screen)
        out = np.empty((h, w, c), F32)
        cl.enqueue_copy(q, out, screen)
        return out
