"""The NDRF renderer: first hits on the K meshes (the OpenCL rasteriser, or Embree), then
the OpenCL shading passes.

Examples:
    >>> r = Renderer(load_baked("ndrf.npz"))              # hits="raster": all on the device
    >>> out = r.render(camera)          # out["rgb"]: (H, W, 3) float32; ms per stage
    >>> Renderer(model, hits="embree").render(camera)     # the reference hits (host)

References: NDRF (Wan et al., CVPR 2023) §3.4 (rasterisation, then the two conv passes as
in the supplement §3).
"""
from __future__ import annotations

import time

import numpy as np

from ..contract import Option, Stat
from .hits import HitCaster
from .raster_cl import Rasteriser
from .shader_cl import Shader

HIT_SOURCES = ("raster", "embree")


class Renderer:
    """Renders a baked NDRF model: device buffers (and Embree scenes) are built once.

    Args:
        model: a :class:`clrender.ndrf.baked.NDRFModel`, validated by its loader.
        device: OpenCL device spec or :class:`clrender.device.Runtime`.
        hits: where the first hits come from (:data:`RENDER_OPTIONS`): "raster" (the OpenCL
            rasteriser; hits stay on the device) or "embree" (ray casting on the host,
            uploaded each frame: the reference).
        exact: the shader's exact build (held to the numpy reference in tests); default the
            fast one.
    """

    SCALAR_STATS = {"Coverage": Stat("coverage", "{:.3f}", "share of pixels a mesh covers")}
    RENDER_OPTIONS = {"hits": Option(str, "raster", "first hits on the meshes: the OpenCL "
                                     "rasteriser (on the device) or Embree ray casting (host)",
                                     choices=HIT_SOURCES)}
    TIME_NOTE = ("time per frame: the hits (OpenCL rasteriser kernels, or Embree ray casting "
                 "on the host plus the upload) + the two OpenCL conv passes (kernel times)")

    def __init__(self, model, device=None, hits: str = "raster", exact: bool = False):
        self.RENDER_OPTIONS["hits"].check("hits", hits)
        self.model, self.config, self.hits = model, model.config, hits
        self.shader = Shader(model, device=device, exact=exact)
        self.runtime = self.shader.runtime
        if hits == "raster":
            self.rasteriser = Rasteriser(model, device=self.runtime)
        else:
            self.caster = HitCaster(model)

    @property
    def hit_source(self) -> str:
        """How hits are made, e.g. "raster (16x16 tiles, 16 rows a work-item, 16 triangles a
        setup work-item)" or "embree (host)"."""
        return f"raster ({self.rasteriser.mode})" if self.hits == "raster" else "embree (host)"

    def _rasterised(self, camera, bg) -> tuple:
        """(rgb, shader times, ms_intersect) from the rasteriser's hits. The frame waits for
        the device only in the shader's read of rgb: if the rasteriser's tile list
        overflowed, the hits are redone and the frame shaded again (rare: the list grows)."""
        bufs = self.rasteriser.rasterise(camera)
        rgb, times = self.shader.shade_device(camera, bufs["tri"], bufs["bary"], bg)
        if self.rasteriser.settle():
            rgb, times = self.shader.shade_device(camera, bufs["tri"], bufs["bary"], bg)
        return rgb, times, self.rasteriser.frame_ms()

    def _cast(self, camera, bg) -> tuple:
        """(rgb, shader times, ms_intersect, host Hits) from Embree's hits. The reference
        path blocks: the upload is timed with the casting by waiting for the queue."""
        start = time.perf_counter()
        hits = self.caster.cast_camera(camera)
        tri, bary = self.shader.upload_hits(camera, hits.tri, hits.bary)
        self.runtime.queue.finish()
        ms_intersect = (time.perf_counter() - start) * 1e3
        return (*self.shader.shade_device(camera, tri, bary, bg), ms_intersect, hits)

    def render(self, camera, background=None, stats: bool = False) -> dict:
        """Render one view.

        Args:
            camera: a :class:`clrender.camera.Camera`.
            background: RGB in [0, 1]; None: the background baked with the model.
            stats: also return ``coverage`` (H, W) float32 (1 where a mesh is hit),
                ``n_hits`` (H, W) int32 meshes hit and ``depth`` (H, W) float32, the
                nearest hit in world units along the ray (0 where nothing is hit).
        Returns:
            dict with ``rgb`` (H, W, 3) float32 in [0, 1], ``ms_intersect`` (the hits:
            rasteriser kernel times, or Embree wall time with the upload), ``ms_conv0``
            (with the gather), ``ms_conv1`` (kernel times) and ``ms`` their sum.
        """
        bg = self.model.background if background is None else background
        if self.hits == "raster":
            rgb, times, ms_intersect = self._rasterised(camera, bg)
            hits = None
        else:
            rgb, times, ms_intersect, hits = self._cast(camera, bg)
        out = {"rgb": rgb, "ms_intersect": ms_intersect, **times}
        out["ms"] = float(sum(v for k, v in out.items() if k.startswith("ms_")))
        if stats:
            hits = hits or self.rasteriser.read_hits(camera)
            hit = hits.tri >= 0
            out["coverage"] = hit.any(axis=0).astype(np.float32)
            out["n_hits"] = hit.sum(axis=0).astype(np.int32)
            out["depth"] = np.where(hit.any(axis=0), hits.depth.min(axis=0), 0.0).astype(np.float32)
        return out
