"""The NDRF renderer: Embree first hits on the K meshes, then the OpenCL shading passes.

Examples:
    >>> r = Renderer(load_baked("ndrf.npz"))
    >>> out = r.render(camera)          # out["rgb"]: (H, W, 3) float32; ms per stage

References: NDRF (Wan et al., CVPR 2023) §3.4 (hardware rasterisation replaced by Embree
ray casting; the two conv passes as in the supplement §3).
"""
from __future__ import annotations

import time

import numpy as np

from ..methods import Option, Stat
from .hits import HitCaster
from .shader_cl import Shader


class Renderer:
    """Renders a baked NDRF model: Embree scenes and device buffers are built once.

    Args:
        model: a :class:`clrender.ndrf.baked.NDRFModel`, validated by its loader.
        device: OpenCL device spec or :class:`clrender.device.Runtime`.
        hits: where the first hits come from (:data:`RENDER_OPTIONS`).
    """

    SCALAR_STATS = {"Coverage": Stat("coverage", "{:.3f}", "share of pixels a mesh covers")}
    RENDER_OPTIONS = {"hits": Option(str, "embree", "first hits on the meshes: Embree ray "
                                     "casting", choices=("embree",))}
    TIME_NOTE = ("time per frame: ray casting into the meshes (Embree, on the CPU) + the "
                 "OpenCL gather and two conv passes (kernel times)")

    def __init__(self, model, device=None, hits: str = "embree"):
        self.RENDER_OPTIONS["hits"].check("hits", hits)
        self.model, self.config = model, model.config
        self.caster = HitCaster(model)
        self.shader = Shader(model, device=device)
        self.runtime = self.shader.runtime

    def render(self, camera, background=None, stats: bool = False) -> dict:
        """Render one view.

        Args:
            camera: a :class:`clrender.camera.Camera`.
            background: RGB in [0, 1]; None: the background baked with the model.
            stats: also return ``coverage`` (H, W) float32 (1 where a mesh is hit),
                ``n_hits`` (H, W) int32 meshes hit and ``depth`` (H, W) float32, the
                nearest hit in world units along the ray (0 where nothing is hit).
        Returns:
            dict with ``rgb`` (H, W, 3) float32 in [0, 1], ``ms_intersect`` (Embree, wall
            time), ``ms_gather``, ``ms_conv0``, ``ms_conv1`` (kernel times) and ``ms``
            their sum.
        """
        start = time.perf_counter()
        hits = self.caster.cast_camera(camera)
        ms_intersect = (time.perf_counter() - start) * 1e3
        bg = self.model.background if background is None else background
        rgb, times = self.shader.shade(camera, hits.tri, hits.bary, bg)
        out = {"rgb": rgb, "ms_intersect": ms_intersect, **times}
        out["ms"] = float(sum(v for k, v in out.items() if k.startswith("ms_")))
        if stats:
            hit = hits.tri >= 0
            out["coverage"] = hit.any(axis=0).astype(np.float32)
            out["n_hits"] = hit.sum(axis=0).astype(np.int32)
            out["depth"] = np.where(hit.any(axis=0), hits.depth.min(axis=0), 0.0).astype(np.float32)
        return out
