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
    >>> paper = Renderer(model, march="paper", use_G=True, count_reads=True)
    >>> paper.render(camera, stats=True)["n_reads"]     # (H, W) global reads per ray

References: NGP-RT (Hu et al., ECCV 2024) §4.3, S2.5.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..camera import CAM_BYTES
from ..device import device_type_name, event_ms, get_runtime, padded, work_group_size
from .config import (DEFERRED_HIDDEN, FEATURES, FUSION_HIDDEN, N_MIP, SH_DIM, VARIANT_CODES,
                     kernel_constants)
from .baked import BakedModel, upsampled
from .encoding import HASH_PRIMES
from .marches import READ_KINDS, check_march, g_in_codes
from .render_ref import BOX_MARGIN, CUBE, K_BACKOFF, K_PAST_END, REGION_SCALE

F32 = np.float32
DEFERRED_PARAMS = ("deferred_w0", "deferred_b0", "deferred_w1", "deferred_b1",
                   "deferred_w2", "deferred_b2")
LANE_WIDTHS = (1, 2, 4, 8, 16)      # vector widths OpenCL C has
# The deferred MLP's [w0, b0, w1, b1, w2, b2]: 7 features + SH_DIM in, 3 colours out.
DEFERRED_SHAPES = ((7 + SH_DIM, DEFERRED_HIDDEN), (DEFERRED_HIDDEN,),
                   (DEFERRED_HIDDEN, DEFERRED_HIDDEN), (DEFERRED_HIDDEN,),
                   (DEFERRED_HIDDEN, 3), (3,))
DEFERRED_BYTES = 4 * sum(int(np.prod(shape)) for shape in DEFERRED_SHAPES)   # float32
DEFERRED_CONSTANT_ARGS = 1          # __constant arguments of ngprt_deferred: its weights
HALF_MAX = 65504.0                  # the largest finite float16


@dataclass(frozen=True)
class Tuning:
    """Kernel variants for GPUs, all off by default (the renderer as the tests and tables
    know it); bench/speed/ngprt_variants.py pairs each against the default.

    Attributes:
        half_tables: the fine hash tables in float16 (``-D HALF_TABLES``): half the bytes
            a corner's gather. Not the default's values: such a build is held to the
            reference of :func:`half_rounded`'s model.
        march_tile: the march's work-group as (work-items in x, rows), e.g. (8, 8) so a
            GPU's warp covers a 2D patch of rays; None: :func:`clrender.device.work_group_size`
            (a run of one row).
        occupancy_image: ours' exit codes read from a 3D image (``-D OCC_IMAGE``: the
            texture path) instead of a buffer; one ray a work-item, not the paper's march.
        deferred_local: the deferred MLP's weights copied into ``__local`` memory by each
            work-group (``-D DEFERRED_LOCAL``).
        deferred_streamed: the MLP's second hidden layer fed straight into the output layer
            (``-D DEFERRED_STREAMED``; the same values, fewer live registers).
    """

    half_tables: bool = False
    march_tile: tuple[int, int] | None = None
    occupancy_image: bool = False
    deferred_local: bool = False
    deferred_streamed: bool = False

    def __post_init__(self):
        if self.march_tile is not None and (len(self.march_tile) != 2 or
                                            min(self.march_tile) < 1):
            raise ValueError(f"march_tile {self.march_tile!r}: expected two positive sizes")

    @property
    def name(self) -> str:
        """A short label: the variants on, joined by '+' ('default' for none)."""
        on = [*(["half-tables"] if self.half_tables else []),
              *([f"tile-{self.march_tile[0]}x{self.march_tile[1]}"] if self.march_tile else []),
              *(["occupancy-image"] if self.occupancy_image else []),
              *(["deferred-local"] if self.deferred_local else []),
              *(["deferred-streamed"] if self.deferred_streamed else [])]
        return "+".join(on) or "default"


def half_rounded(model: BakedModel) -> BakedModel:
    """``model`` with its fine tables rounded to float16 and back: what a
    ``Tuning(half_tables=True)`` build renders, for its reference."""
    tables = np.asarray(model.arrays["fine_tables"], F32)
    return BakedModel(model.config, model.gamma,
                      {**model.arrays, "fine_tables": tables.astype(np.float16).astype(F32)},
                      model.G_metric)


def lane_width(device, cap: int = 16) -> int:
    """Rays (march) or pixels (deferred MLP) per work-item on ``device``, rounded down to an
    OpenCL vector width and capped at ``cap``: on a CPU its native float vector width (8 on
    AVX2, 16 on AVX-512), elsewhere its preferred one (1 on GPUs, where work-items are the
    SIMD lanes). Not a CPU's preferred width: Intel's CPU runtime reports 1 there (it
    vectorises across work-items), yet with the kernels' lanes declared by
    ``vec_type_hint`` it keeps them and marches faster at 16 lanes than at 1
    (docs/explanation/opencl.md, "Each kernel in its own lanes on both")."""
    width = int(device.native_vector_width_float if device_type_name(device) == "CPU"
                else device.preferred_vector_width_float)
    width = max(1, width)
    return max(w for w in LANE_WIDTHS if w <= min(width, cap))


# The exit code's layout (:func:`exit_codes`): its level in the bits below CODE_G_SHIFT,
# G above them (-D CODE_G_SHIFT; kernels/ngprt_model.h's CODE_LEVEL / CODE_G read it).
CODE_G_SHIFT = 8


def march_constants() -> dict:
    """The march's constants shared with the numpy reference, as ``-D`` defines: the hash
    primes (:data:`clrender.ngprt.encoding.HASH_PRIMES`), the exit code's layout
    (:data:`CODE_G_SHIFT`) and the skip's back-off and margins
    (:mod:`clrender.ngprt.render_ref`, ``kernels/ngprt_skip.h``); floats as float32
    literals."""
    out = {f"HASH_PRIME_{axis}": int(p) for axis, p in zip("XYZ", HASH_PRIMES)}
    out["CODE_G_SHIFT"] = CODE_G_SHIFT
    for name, value in (("K_BACKOFF", K_BACKOFF), ("K_PAST_END", K_PAST_END),
                        ("BOX_MARGIN", BOX_MARGIN), ("REGION_SCALE", REGION_SCALE),
                        ("CUBE", CUBE)):
        out[name] = float(value)
    return out


def deferred_in_constant(device) -> bool:
    """Whether the deferred MLP's weights (:data:`DEFERRED_SHAPES`, float32) go to
    ``__constant`` memory on ``device`` (``-D DEFERRED_CONSTANT``): they fit its
    CL_DEVICE_MAX_CONSTANT_BUFFER_SIZE and the kernel's constant arguments its
    CL_DEVICE_MAX_CONSTANT_ARGS."""
    return (DEFERRED_BYTES <= device.max_constant_buffer_size
            and DEFERRED_CONSTANT_ARGS <= device.max_constant_args)


def kernel_defines(config, use_G: bool, deferred_vec: int = 1, rays: int = 1,
                   march: str = "ours", count_reads: bool = False,
                   deferred_constant: bool = False,
                   tuning: Tuning = Tuning()) -> tuple[dict, dict]:
    """The ``-D`` defines of the march and deferred programs for a model config: the
    shared constants of :func:`clrender.ngprt.config.kernel_constants` and
    :func:`march_constants` (the kernels define none of their own) plus the model's
    sizes, variant and scene, the lanes per work-item (``rays`` for the march,
    ``deferred_vec`` for the deferred MLP), the march (:mod:`clrender.ngprt.marches`),
    whether the march counts its reads (``COUNT_READS``, the counting build) and whether
    the deferred MLP reads its weights from ``__constant`` memory
    (``DEFERRED_CONSTANT``: :func:`deferred_in_constant`), and the :class:`Tuning`
    variants."""
    shared = kernel_constants()
    march = {
        **shared, **march_constants(), "L": config.L, "L_C": config.L_C,
        "OCC_RES": config.occ_res, "OCC_SHIFT": config.occ_shift,
        "LOG2_T": config.log2_T, "VARIANT": VARIANT_CODES[config.variant],
        "UNBOUNDED": config.scene == "unbounded", "EXTENT": float(config.extent),
        "USE_G": bool(use_G), "G_RES": config.G_res,
        "COARSE_BLOCK": config.coarse_block, "N_ATT": config.n_attention,
        "N_INV": config.n_inv_attention, "RAYS": rays, "G_IN_CODE": g_in_codes(config),
        "MARCH_PAPER": check_march(march) == "paper", "COUNT_READS": bool(count_reads),
        "HALF_TABLES": tuning.half_tables, "OCC_IMAGE": tuning.occupancy_image,
    }
    return march, {**shared, "DEFERRED_VEC": deferred_vec,
                   "DEFERRED_CONSTANT": bool(deferred_constant),
                   "DEFERRED_LOCAL": tuning.deferred_local,
                   "DEFERRED_STREAMED": tuning.deferred_streamed}


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
    """The deferred MLP's weights packed as [w0, b0, w1, b1, w2, b2] (float32), shapes
    :data:`DEFERRED_SHAPES`."""
    return _packed(model.arrays, DEFERRED_PARAMS, DEFERRED_SHAPES)


def exit_codes(model, use_G: bool = True) -> np.ndarray:
    """The occupancy mip (and G) as the march reads them: one uint16 per finest cell
    (``occ_res^3``, C order). Low byte (bits below :data:`CODE_G_SHIFT`): 0 where ``occupancy_0`` is occupied (a sample), else
    ``1 + exit level``, the coarsest empty level (docs/ngprt.md "The march"); the mip is
    a max-pool (validated), so the empty levels of a point are 0 .. exit level, all
    decided by its finest cell: one read per lattice point instead of up to five. High
    byte: the G value of the cell's G voxel where the march reads G (``use_G``, exit
    level coarser than G, :func:`g_in_codes`), else 0.
    """
    cfg = model.config
    code = np.zeros((cfg.occ_res,) * 3, np.uint16)
    for lev in range(N_MIP):
        r = cfg.occ_res >> lev
        a = np.asarray(model.arrays[f"occupancy_{lev}"])
        if a.shape != (r, r, r):
            raise ValueError(f"baked model: occupancy_{lev} has shape {a.shape}, "
                             f"expected ({r}, {r}, {r})")
        code += upsampled((a == 0).astype(np.uint16), 1 << lev)
    if use_G and g_in_codes(cfg):
        G = upsampled(np.asarray(model.arrays["G"], np.uint16), cfg.occ_res // cfg.G_res)
        exit_res = cfg.occ_res >> np.maximum(code.astype(np.int64) - 1, 0)
        code |= np.where((code > 0) & (exit_res < cfg.G_res), G << CODE_G_SHIFT,
                         0).astype(np.uint16)
    return code.reshape(-1)


def mip_levels(model) -> np.ndarray:
    """The occupancy mip as the paper's march reads it (``kernels/ngprt_paper.h``): the
    ``N_MIP`` levels as uint8, finest first, each ``(occ_res >> lev)^3`` cells in C order."""
    cfg = model.config
    levels = [np.asarray(model.arrays[f"occupancy_{lev}"], np.uint8) for lev in range(N_MIP)]
    for lev, a in enumerate(levels):
        r = cfg.occ_res >> lev
        if a.shape != (r, r, r):
            raise ValueError(f"baked model: occupancy_{lev} has shape {a.shape}, "
                             f"expected ({r}, {r}, {r})")
    return np.concatenate([a.reshape(-1) for a in levels])


class Renderer:
    """Renders a baked NGP-RT model with OpenCL; the model is uploaded once, per-frame
    buffers are kept while the image size stays the same.

    Args:
        model: a :class:`clrender.ngprt.baked.BakedModel` (``.config``, ``.step``,
            ``.arrays``), validated by its loader.
        device: OpenCL device spec or :class:`clrender.device.Runtime` (default
            ``$CLRENDER_DEVICE``).
        use_G: skip empty space with the occupancy distance grid G (paper §4.3).
        march: ``"ours"`` (one exit code a point, the larger skip) or ``"paper"`` (the
            levels read coarse to fine, G's step replacing the mip's: Eq. 9), see
            :mod:`clrender.ngprt.marches`.
        count_reads: ``render(stats=True)`` marches with the counting build
            (``-D COUNT_READS=1``, built on first use) and returns the reads per ray;
            renders without stats always take the timed build, which counts nothing.
        exact: build the kernels exactly (``Runtime.program(exact=True)``: what the tests
            compare with the numpy reference); default the fast build, which takes the
            same samples and differs in exp-based values by a few ulps.
        rays, deferred_vec: lanes per work-item of the march and the deferred MLP
            (default :func:`lane_width` of the device).
        kernel_dir: build the kernels from this folder instead of the installed
            ``kernels/`` (``bench.speed.ngprt_kernels --baseline``: another version of them).
        tuning: the GPU variants (:class:`Tuning`; default none).
    """

    def __init__(self, model, device=None, use_G: bool = True, exact: bool = False,
                 rays: int | None = None, deferred_vec: int | None = None,
                 kernel_dir: str | None = None, march: str = "ours", count_reads: bool = False,
                 tuning: Tuning = Tuning()):
        self.model, self.config, self.use_G = model, model.config, bool(use_G)
        self.tuning = tuning
        self.march_kind, self.count_reads = check_march(march), bool(count_reads)
        self.exact, self._kernel_dir = bool(exact), kernel_dir
        self.runtime = rt = get_runtime(device)
        self.rays = rays or lane_width(rt.device)
        self.deferred_vec = deferred_vec or lane_width(rt.device)
        self.deferred_constant = deferred_in_constant(rt.device)
        if tuning.occupancy_image and (self.march_kind != "ours" or self.rays != 1):
            raise ValueError("occupancy_image: ours' march with one ray a work-item (rays=1), "
                             f"not march={self.march_kind!r} with rays={self.rays}")
        if tuning.deferred_local and DEFERRED_BYTES > rt.device.local_mem_size:
            raise ValueError(f"deferred_local: the MLP's {DEFERRED_BYTES} bytes of weights "
                             f"exceed {rt.device.name}'s {rt.device.local_mem_size} bytes of "
                             f"local memory")
        march_defs, deferred_defs = kernel_defines(self.config, self.use_G, self.deferred_vec,
                                                   self.rays, self.march_kind,
                                                   deferred_constant=self.deferred_constant,
                                                   tuning=tuning)
        self._march = rt.program("ngprt_march.cl", march_defs, exact,
                                 kernel_dir).kernel("ngprt_march")
        self._counting = None
        self._deferred = rt.program("ngprt_deferred.cl", deferred_defs, exact,
                                    kernel_dir).kernel("ngprt_deferred")
        self.step = F32(model.step)
        self._local = {}
        self._cam_upload = None
        self._upload()

    @property
    def kernels(self) -> dict:
        """``{kernel name: cl.Kernel}`` of the timed builds."""
        return {"ngprt_march": self._march, "ngprt_deferred": self._deferred}

    def launch_sizes(self, width: int, height: int) -> list[tuple[str, tuple[int, ...]]]:
        """The kernel launches of a ``width`` x ``height`` frame, in order: ``(kernel
        name, global work-items per axis before padding to the work-group size)``."""
        return [("ngprt_march", (-(-width // self.rays), height)),
                ("ngprt_deferred", (-(-width * height // self.deferred_vec),))]

    def _launch(self, name: str, kernel, global_size: tuple[int, ...]):
        """(padded global size, local size) of a kernel launch, derived from the device
        once per kernel (:func:`clrender.device.work_group_size`)."""
        key = (name, global_size)
        if key not in self._local:
            tile = self.tuning.march_tile if name in ("march", "count") else None
            self._local[key] = (self._checked_tile(kernel, tile) if tile else
                                work_group_size(kernel, self.runtime.device, global_size))
        local = self._local[key]
        return padded(global_size, local), local

    def _checked_tile(self, kernel, tile: tuple[int, int]) -> tuple[int, int]:
        limit = kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE,
                                           self.runtime.device)
        if tile[0] * tile[1] > limit:
            raise ValueError(f"march_tile {tile}: {tile[0] * tile[1]} work-items, more than "
                             f"the march kernel's {limit} on {self.runtime.device.name}")
        return tuple(tile)

    def _image(self, grid: np.ndarray) -> cl.Image:
        """A read-only 3D image of a uint16 (res, res, res) grid, image x = its last axis."""
        dev = self.runtime.device
        if not dev.image_support or max(grid.shape) > min(
                dev.image3d_max_width, dev.image3d_max_height, dev.image3d_max_depth):
            raise ValueError(f"occupancy_image: {dev.name} has no 3D image of "
                             f"{grid.shape[0]}^3 (image support {bool(dev.image_support)})")
        return cl.image_from_array(self.runtime.context, np.ascontiguousarray(grid, np.uint16),
                                   num_channels=1, mode="r")

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
        if self.tuning.half_tables:
            if np.abs(tables).max(initial=0.0) > HALF_MAX:
                raise ValueError(f"baked model: fine_tables hold values beyond float16's "
                                 f"range ({HALF_MAX:g}); render without half_tables")
            tables = tables.astype(np.float16)
        for name, res in (("G", cfg.G_res), ("coarse_block_index", cfg.L_C // cfg.coarse_block)):
            if np.shape(arrays[name]) != (res,) * 3:
                raise ValueError(f"baked model: {name} has shape {np.shape(arrays[name])}, "
                                 f"expected ({res}, {res}, {res})")
        self.n_blocks = np.int32(blocks.shape[0])
        # Each corner padded to a multiple of 8 floats: aligned float8 reads (S2.5, 4).
        stride = FEATURES * (1 + -(-cfg.n_attention // FEATURES))
        padded = np.zeros(blocks.shape[:4] + (stride,), F32)
        padded[..., :blocks.shape[4]] = blocks
        occ = (exit_codes(self.model, self.use_G) if self.march_kind == "ours"
               else mip_levels(self.model))
        self._bufs = {
            "occ": (self._image(occ.reshape((cfg.occ_res,) * 3)) if self.tuning.occupancy_image
                    else self._buffer(occ)),
            "G": self._buffer(np.asarray(arrays["G"], np.uint8)),
            "block_index": self._buffer(np.asarray(arrays["coarse_block_index"], np.int32)),
            # No block: one zero corner, so no read of a kernel is out of range.
            "blocks": self._buffer(padded if padded.size else np.zeros(stride, F32)),
            "tables": self._buffer(tables),
            "fusion": self._buffer(fusion_params(self.model)),
            "deferred": self._buffer(deferred_params(self.model)),
        }

    def _outputs(self, camera) -> dict:
        """Per-frame buffers, kept across frames of the same size (re-allocated otherwise),
        and the camera's upload enqueued: not waited for, its event (which keeps the host
        array alive, and would wait for the copy if dropped) held until the frame's read."""
        n = camera.width * camera.height
        if getattr(self, "_frame_n", None) != n:
            ctx, mf = self.runtime.context, cl.mem_flags
            self._frame = {"cam": cl.Buffer(ctx, mf.READ_ONLY, CAM_BYTES),
                           "feat": cl.Buffer(ctx, mf.READ_WRITE, 32 * n),
                           "depth": cl.Buffer(ctx, mf.WRITE_ONLY, 4 * n),
                           "n_march": cl.Buffer(ctx, mf.WRITE_ONLY, 4 * n),
                           "n_occ": cl.Buffer(ctx, mf.WRITE_ONLY, 4 * n),
                           "rgb": cl.Buffer(ctx, mf.WRITE_ONLY, 12 * n),
                           "reads": cl.Buffer(ctx, mf.WRITE_ONLY, 4 * len(READ_KINDS) * n)
                           if self.count_reads else None}
            self._frame_n = n
        self._cam_upload = cl.enqueue_copy(self.runtime.queue, self._frame["cam"],
                                           camera.packed(), is_blocking=False)
        return self._frame

    def _counting_kernel(self):
        """The counting build's march (``COUNT_READS``), built on first use."""
        if self._counting is None:
            defs, _ = kernel_defines(self.config, self.use_G, self.deferred_vec, self.rays,
                                     self.march_kind, count_reads=True, tuning=self.tuning)
            self._counting = self.runtime.program("ngprt_march.cl", defs, self.exact,
                                                  self._kernel_dir).kernel("ngprt_march")
        return self._counting

    def _enqueue_march(self, camera, out, counted: bool = False) -> cl.Event:
        cfg, b = self.config, self._bufs
        kernel = self._counting_kernel() if counted else self._march
        size = dict(self.launch_sizes(camera.width, camera.height))["ngprt_march"]
        gsize, local = self._launch("count" if counted else "march", kernel, size)
        return kernel(
            self.runtime.queue, gsize, local, out["cam"], np.int32(camera.width),
            np.int32(camera.height), self.step, F32(cfg.near), F32(cfg.far), b["occ"], b["G"],
            b["block_index"], b["blocks"], self.n_blocks, b["tables"], b["fusion"],
            out["feat"], out["depth"], out["n_march"], out["n_occ"],
            *((out["reads"],) if counted else ()))

    def _read(self, buf: cl.Buffer, shape, dtype) -> np.ndarray:
        host = np.empty(shape, dtype)
        cl.enqueue_copy(self.runtime.queue, host, buf)
        return host

    def march(self, camera) -> dict:
        """The march alone, for tests: ``acc`` (H*W, 7), ``opacity``, ``depth`` (H*W,)
        float32, ``n_march``, ``n_occ`` (H*W,) int32, ``ms_march``; with ``count_reads``
        (the counting build) ``reads`` (H*W, 3) int32 (:data:`marches.READ_KINDS`)."""
        n = camera.width * camera.height
        out = self._outputs(camera)
        event = self._enqueue_march(camera, out, self.count_reads)
        feat = self._read(out["feat"], (n, 8), F32)
        result = {"acc": feat[:, :7].copy(), "opacity": feat[:, 7].copy(),
                  "depth": self._read(out["depth"], (n,), F32),
                  "n_march": self._read(out["n_march"], (n,), np.int32),
                  "n_occ": self._read(out["n_occ"], (n,), np.int32)}
        if self.count_reads:
            result["reads"] = self._read(out["reads"], (n, len(READ_KINDS)), np.int32)
        result["ms_march"] = event_ms(event)
        self._cam_upload = None
        return result

    def render(self, camera, background=(1.0, 1.0, 1.0), stats: bool = False) -> dict:
        """Render one view; only ``rgb`` is read back unless ``stats`` is asked for.

        Args:
            camera: a :class:`clrender.camera.Camera`.
            background: RGB in [0, 1] composited behind the model (None: white).
            stats: also read back the per-pixel statistics.
        Returns:
            dict with ``rgb`` (H, W, 3) float32 in [0, 1]; ``ms_march``, ``ms_deferred``:
            kernel times in milliseconds (read after the outputs: the reads are the only
            calls that wait for the device) and ``ms`` their sum. With ``stats``: ``n_march``,
            ``n_occ`` (H, W) int32 marching points and occupied samples per ray, ``n_empty``
            their difference (empty points, where the march skips); ``depth``
            (H, W) float32 world units along the ray (0 where nothing was hit); ``opacity``
            (H, W) float32; with ``count_reads`` (the counting build's times)
            ``reads_<kind>`` per :data:`marches.READ_KINDS`, ``n_reads`` their sum and
            ``n_skip_reads`` the occupancy and G reads, (H, W) int32 reads per ray.
        """
        h, w, n = camera.height, camera.width, camera.width * camera.height
        out = self._outputs(camera)
        counted = stats and self.count_reads
        ev_march = self._enqueue_march(camera, out, counted)
        bg = [F32(c) for c in (background if background is not None else (1.0, 1.0, 1.0))]
        size = dict(self.launch_sizes(w, h))["ngprt_deferred"]
        gsize, local = self._launch("deferred", self._deferred, size)
        staged = (cl.LocalMemory(self._bufs["deferred"].size),) if self.tuning.deferred_local \
            else ()
        ev_deferred = self._deferred(self.runtime.queue, gsize, local,
                                     out["cam"], np.int32(w), np.int32(n), out["feat"],
                                     self._bufs["deferred"], *bg, out["rgb"], *staged)
        result = {"rgb": self._read(out["rgb"], (h, w, 3), F32)}
        if stats:
            result.update(
                n_march=self._read(out["n_march"], (h, w), np.int32),
                n_occ=self._read(out["n_occ"], (h, w), np.int32),
                depth=self._read(out["depth"], (h, w), F32),
                opacity=self._read(out["feat"], (n, 8), F32)[:, 7].reshape(h, w).copy())
            result["n_empty"] = result["n_march"] - result["n_occ"]
        if counted:
            reads = self._read(out["reads"], (h, w, len(READ_KINDS)), np.int32)
            result.update({f"reads_{kind}": reads[..., i].copy()
                           for i, kind in enumerate(READ_KINDS)})
            result.update(n_reads=reads.sum(axis=2, dtype=np.int32),
                          n_skip_reads=reads[..., :2].sum(axis=2, dtype=np.int32))
        result.update(ms_march=event_ms(ev_march), ms_deferred=event_ms(ev_deferred))
        result["ms"] = result["ms_march"] + result["ms_deferred"]
        self._cam_upload = None
        return result
