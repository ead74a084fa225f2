"""clrender: portable real-time neural rendering (NGP-RT, NDRF) with OpenCL kernels.

Examples:
    >>> import clrender
    >>> model = clrender.load("model.npz")                   # any method's baked file
    >>> cam = clrender.Camera.from_fov(0.69, 400, 400, clrender.look_at([0, -3, 1.5]))
    >>> rgb = clrender.render(model, cam)                    # (400, 400, 3) float32
    >>> renderer = clrender.Renderer(model)                  # upload once, render many views
    >>> out = renderer.render(cam, stats=True)               # rgb, ms per stage, statistics

Loading and rendering a baked file of either method need the core install alone (numpy,
scipy, pyopencl); training, baking, capture, the viewer and the benchmarks are extras
(:mod:`clrender.extras`).
"""
from importlib import metadata as _metadata

from .camera import Camera, generate_rays, look_at
from .methods import load
from .paths import orbit_path, spiral_path
from .renderer import Renderer, render

try:
    __version__ = _metadata.version("clrender")      # one source: pyproject.toml
except _metadata.PackageNotFoundError:                # a source tree that is not installed
    __version__ = "0+unknown"
__all__ = ["Camera", "generate_rays", "look_at", "orbit_path", "spiral_path", "load", "render",
           "Renderer", "__version__"]
