"""``clrender export MODEL --format glb``: a baked model as coloured triangle meshes in one
glTF 2.0 binary file, which Blender, three.js, Unity and Unreal open directly.

* an NDRF file: its meshes, outer first (``outer``, ``inner``);
* an NGP-RT file: the mesh NDRF's extraction gives of its density at one alpha threshold
  (:func:`clrender.ndrf.mesh.extract_duplex`); an unbounded scene: what lies inside its
  inner unit box, where the contraction is the identity (to within half a cell of the
  extraction's grid).

Each mesh's vertex colours are fitted (:func:`.mesh_colours.fit_vertex_colours`) to views
of the scene: the dataset's training images (``images``), or the model's own renders
(``renders``) at the training cameras, or, without a dataset, at views round the scene.
Without view dependence, the colours are what the views agree on.

Examples:
    >>> export_glb("ndrf.npz", "scene.glb", data="data/lego")        # colours from renders
    >>> export_glb("model.npz", "scene.glb", threshold=0.01, cameras=True, data="data/lego")
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .glb import MeshNode, write_glb
from .mesh_colours import fit_vertex_colours

COLOUR_SOURCES = ("renders", "images")
MAX_VIEWS = 60             # views a fit uses at most (evenly spaced over the training views)
AROUND_VIEWS, AROUND_SIZE = 60, 400      # views round a bounded scene without a dataset
MESH_NAMES = ("outer", "inner")
# NGP-RT's surface: the alpha level where one base step of a ray loses 30% of its light
# (NDRF's inner level, 0.01, lies well outside the visible surface of a soft density).
SURFACE_ALPHA = 0.3


def scene_meshes(model, threshold: float | None = None, extraction: str = "cpu",
                 cameras=None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """[(name, (V, 3) vertices, (F, 3) faces)] of a loaded model, outer first.

    Args:
        threshold: NGP-RT: the alpha level of the surface (default :data:`SURFACE_ALPHA`);
            NDRF files keep their meshes (a threshold is an error).
        extraction: NGP-RT: the extraction preset (density grid, face budget).
        cameras: NGP-RT: training cameras; faces none of them sees are culled.
    """
    if model.method == "ndrf":
        if threshold is not None:
            raise ValueError("--threshold: an NDRF file's meshes are extracted already")
        K = model.config.K
        names = MESH_NAMES if K == 2 else [f"mesh_{k}" for k in range(K)]
        return [(names[k], *model.mesh(k)[:2]) for k in range(K)]
    if model.method != "ngprt":
        raise ValueError(f"method {model.method!r} has no mesh to export (ndrf, ngprt)")
    from ..ndrf.mesh import extract_duplex, teacher_density

    level = SURFACE_ALPHA if threshold is None else float(threshold)
    if not 0.0 < level < 1.0:
        raise ValueError(f"--threshold {level}: an alpha level in (0, 1) is expected")
    meshes, _ = extract_duplex(teacher_density(model, inner_box=True), extraction,
                               thresholds=[level], step=model.step, cameras=cameras,
                               progress=False)
    if len(meshes[0].faces) == 0:
        raise ValueError(f"--threshold {level}: no surface at this alpha level (the "
                         "model's alpha is below it everywhere): try a smaller one")
    return [("surface", np.asarray(meshes[0].vertices), np.asarray(meshes[0].faces))]


def colour_views(model, source: str, data=None, downscale: int = 1, device=None):
    """(cameras, images: (H, W, 3) float32 in [0, 1]) the colours are fitted to (module
    doc)."""
    from ..renderer import Renderer

    if source not in COLOUR_SOURCES:
        raise ValueError(f"--colours {source!r}: expected one of {', '.join(COLOUR_SOURCES)}")
    if data is None:
        if source == "images":
            raise ValueError("--colours images needs the dataset: --data DIR")
        cameras = _around(model.config.scene)
    else:
        from ..data import load_dataset, scan_dataset

        split = (load_dataset if source == "images" else scan_dataset)(data, "train", downscale)
        keep = np.unique(np.linspace(0, len(split.cameras) - 1, MAX_VIEWS).round().astype(int))
        cameras = [split.cameras[i] for i in keep]
        if source == "images":
            return cameras, [split.images[i] for i in keep]
    renderer = Renderer(model, device=device)
    return cameras, [renderer.render(c)["rgb"] for c in cameras]


def _around(scene: str) -> list:
    """Cameras round the scene: a Fibonacci sphere at radius 3 looking at the centre
    (bounded), or the orbit path's circle (unbounded)."""
    from ..camera import Camera, look_at
    from ..paths import path_cameras

    if scene != "bounded":
        return path_cameras(scene, "orbit", AROUND_VIEWS, AROUND_SIZE, AROUND_SIZE)
    i = np.arange(AROUND_VIEWS) + 0.5
    z = 1.0 - 2.0 * i / AROUND_VIEWS
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z * z)
    eyes = 3.0 * np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    return [Camera.from_fov(0.69, AROUND_SIZE, AROUND_SIZE,
                            look_at(e, up=(0.0, 1.0, 0.0) if abs(e[2]) > 2.9 else (0, 0, 1)))
            for e in eyes]


def export_glb(model_path, out, data=None, downscale: int | None = None,
               colours: str = "renders", threshold: float | None = None,
               extraction: str = "cpu", cameras: bool = False, device=None) -> Path:
    """Write the ``.glb`` of baked model ``model_path`` to ``out`` (module doc).

    Args:
        data: a dataset folder: its training cameras (and images) to colour from, its test
            cameras as glTF cameras with ``cameras``.
        downscale: of ``data``; None: the model's training downscale.
        colours: "renders" or "images" (:data:`COLOUR_SOURCES`).
        threshold, extraction: NGP-RT's surface alpha level and extraction preset
            (:func:`scene_meshes`).
    Returns:
        ``out``, written whole or not at all.
    """
    from .. import bakedfile, methods

    model = methods.load(model_path)
    if cameras and data is None:
        raise ValueError("--cameras needs the dataset whose test cameras to write: --data DIR")
    if downscale is None:
        downscale = bakedfile.trained_downscale(model_path)
    train = None
    if data is not None:
        from ..data import scan_dataset

        train = scan_dataset(data, "train", downscale).cameras
    meshes = scene_meshes(model, threshold, extraction,
                          cameras=train if model.method == "ngprt" else None)
    views, images = colour_views(model, colours, data, downscale, device)
    nodes = [MeshNode(name, vertices, faces, fit_vertex_colours(vertices, faces, views, images))
             for name, vertices, faces in meshes]
    test = []
    if cameras:
        from ..data import scan_dataset

        test = [(f"test_{i:03d}", c)
                for i, c in enumerate(scan_dataset(data, "test", downscale).cameras)]
    return write_glb(out, nodes, test)
