"""``clrender export``: a baked model as a static WebGL2 page that renders it as the OpenCL
renderer does (docs/explanation/browser.md).

Examples:
    >>> export("ndrf.npz", "site/", data="data/lego")   # index.html, model.json, *.bin
    >>> url, server = serve("site/")                     # http://127.0.0.1:PORT/
"""
from __future__ import annotations

from pathlib import Path

from .limits import ExportError
from .serve import serve
from .writer import camera_record, dataset_cameras, write_export

__all__ = ["export", "serve", "ExportError"]


def _default_camera() -> dict:
    """A view of the bounded scene box when no dataset gives cameras (the README's)."""
    from ..camera import Camera, look_at

    return camera_record(Camera.from_fov(0.69, 400, 400, look_at([0.0, -3.0, 1.5])), "default")


def export(model_path, out, data=None, downscale: int | None = None) -> Path:
    """Write the page of baked model ``model_path`` to the new folder ``out``.

    Args:
        data: a dataset folder whose test cameras the page lists (optional).
        downscale: of ``data``; None: the model's training downscale.
    Raises:
        BakedFormatError / ExportError (ValueError) naming the file and the problem,
        before anything is written.
    Returns:
        ``out``.
    """
    from .. import bakedfile, methods

    where = str(model_path)
    model = methods.load(model_path)
    if model.method == "ndrf":
        from .ndrf import ndrf_assets
        fields, assets = ndrf_assets(model, where)
    elif model.method == "ngprt":
        from .ngprt import ngprt_assets
        fields, assets = ngprt_assets(model, where)
    else:
        raise ExportError(f"{where}: method {model.method!r} has no page (ndrf, ngprt)")
    if data is not None:
        if downscale is None:
            downscale = bakedfile.trained_downscale(model_path)
        cameras = dataset_cameras(data, downscale)
        if not cameras:
            raise ExportError(f"{data}: the dataset has no test cameras")
    else:
        cameras = [_default_camera()]
    manifest = {"method": model.method, "config": model.config.to_dict(),
                "source": Path(model_path).name, "cameras": cameras, **fields}
    return write_export(out, manifest, assets)
