"""clrender: portable real-time neural rendering (NGP-RT, NDRF) with OpenCL kernels.

Examples:
    >>> import clrender
    >>> model = clrender.load("model.npz")                   # any method's baked file
    >>> cam = clrender.Camera.from_fov(0.69, 400, 400, clrender.look_at([0, -3, 1.5]))
    >>> rgb = clrender.render(model, cam)                    # (400, 400, 3) float32
    >>> renderer = clrender.Renderer(model)                  # upload once, render many views
    >>> out = renderer.render(cam, stats=True)               # rgb, ms per stage, statistics

Rendering needs numpy and pyopencl (and embreex for NDRF); training and baking use PyTorch.
"""
from .camera import Camera, generate_rays, look_at
from .methods import load
from .paths import orbit_path, spiral_path
from .renderer import Renderer, render

__version__ = "0.1.0"
__all__ = ["Camera", "generate_rays", "look_at", "orbit_path", "spiral_path", "load", "render",
           "Renderer", "__version__"]
