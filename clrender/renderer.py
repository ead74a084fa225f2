"""The public renderer: any method's baked model, uploaded once, rendered from many views.

Examples:
    >>> r = Renderer("model.npz")                     # NGP-RT or NDRF, by the file's format
    >>> out = r.render(camera)                        # out["rgb"]: (H, W, 3) float32
    >>> out = r.render(camera, stats=True)            # + the method's per-pixel statistics
"""
from __future__ import annotations

import os

from . import methods
from .contract import check_options


class Renderer:
    """A persistent renderer for a baked model of any registered method.

    Args:
        model: a loaded model (``clrender.load``) or the path of a baked file.
        device: OpenCL device spec (see :mod:`clrender.device`); default ``$CLRENDER_DEVICE``.
        **options: the method's render options (NGP-RT: ``use_G``): its renderer's
            ``RENDER_OPTIONS``.
    """

    def __init__(self, model, device=None, **options):
        if isinstance(model, (str, os.PathLike)):
            model = methods.load(model)
        self.model = model
        self.method = methods.of_model(model)
        check_options(options, self.method.renderer.RENDER_OPTIONS, "render options",
                      model.method)
        self.impl = self.method.renderer(model, device=device, **options)

    @property
    def device_name(self) -> str:
        return self.impl.runtime.name

    @property
    def scalar_stats(self) -> dict:
        """{table column: :class:`clrender.contract.Stat`} this method reports (NGP-RT:
        Marching, the mean of ``n_march``)."""
        return dict(self.impl.SCALAR_STATS)

    @property
    def time_note(self) -> str:
        """What the frame time ``ms`` covers (kernel times, ray casting, ...)."""
        return self.impl.TIME_NOTE

    def render(self, camera, background=None, stats: bool = False) -> dict:
        """Render one view.

        Args:
            camera: a :class:`clrender.camera.Camera`.
            background: RGB in [0, 1] behind the model; None: the method's default
                (NGP-RT: white; NDRF: the background baked with the model).
            stats: also return the method's per-pixel statistics.
        Returns:
            dict with ``rgb`` (H, W, 3) float32 in [0, 1], ``ms`` (the frame's time in
            milliseconds: kernel times, plus ray casting for NDRF) and ``ms_<stage>`` per
            stage; with ``stats`` the method's statistics ((H, W) arrays).
        """
        if background is not None:
            background = tuple(float(c) for c in background)
        return self.impl.render(camera, background=background, stats=stats)


def render(model, camera, device=None, background=None, stats: bool = False, **options):
    """Render ``model`` (a loaded model or a path) from ``camera`` once.

    For many views make one :class:`Renderer` (the model is uploaded once).
    Returns:
        rgb: (H, W, 3) float32 in [0, 1]; with ``stats=True`` a tuple ``(rgb, stats)``,
        stats the method's per-pixel statistics (NGP-RT: ``n_march``, ``n_occ`` (H, W)
        int32, ``depth`` (H, W) float32 world units along the ray, ``opacity``).
    """
    out = Renderer(model, device=device, **options).render(camera, background, stats=stats)
    if stats:
        return out["rgb"], {k: v for k, v in out.items() if k != "rgb" and not k.startswith("ms")}
    return out["rgb"]
