"""clrender: portable real-time neural rendering (NGP-RT) with OpenCL kernels.

Examples:
    >>> import clrender
    >>> model = clrender.load("model.npz")
    >>> cam = clrender.Camera.from_fov(0.69, 400, 400, clrender.look_at([0, -3, 1.5]))
    >>> rgb = clrender.render(model, cam)                    # (400, 400, 3) float32
    >>> rgb, stats = clrender.render(model, cam, stats=True)  # + n_march, n_occ, depth, opacity

Rendering needs numpy and pyopencl only; training and baking use PyTorch.
"""
from .camera import Camera, generate_rays, look_at, orbit_path, spiral_path

__version__ = "0.1.0"
__all__ = ["Camera", "generate_rays", "look_at", "orbit_path", "spiral_path", "load", "render",
           "__version__"]


def load(path):
    """Load and validate a baked NGP-RT model file (``.npz``); see docs/ngprt.md."""
    from .ngprt.baked import load_baked

    return load_baked(path)


def render(model, camera, device=None, background=(1.0, 1.0, 1.0), stats=False, use_G=True):
    """Render ``model`` (a baked model or a path) from ``camera`` with the OpenCL renderer.

    Args:
        model: a :class:`clrender.ngprt.baked.BakedModel` or the path of a baked file.
        camera: a :class:`Camera`.
        device: OpenCL device spec (see :mod:`clrender.device`); default ``$CLRENDER_DEVICE``.
        background: RGB in [0, 1] composited behind the model.
        stats: also return per-pixel statistics.
        use_G: skip empty space with the occupancy distance grid G (paper §4.3).
    Returns:
        rgb: (H, W, 3) float32 in [0, 1]; with ``stats=True`` a tuple ``(rgb, stats)`` where
        stats holds ``n_march``, ``n_occ`` (H, W) int32, ``depth`` (H, W) float32 world units
        along the ray and ``opacity`` (H, W) float32.
    """
    from .ngprt.render_cl import Renderer

    if not hasattr(model, "config"):
        model = load(model)
    out = Renderer(model, device=device, use_G=use_G).render(camera, background=background)
    if stats:
        return out["rgb"], {k: out[k] for k in ("n_march", "n_occ", "depth", "opacity")}
    return out["rgb"]
