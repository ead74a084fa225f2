"""Duplex (K-layer) mesh extraction from a teacher's density field.

The teacher's density is sampled at the centres of an N^3 grid of cells over the scene box,
turned into alpha at the teacher's base step, and marching cubes runs at each of the K alpha
thresholds (the paper's duplex pair: 1e-4 gives the outer, over-estimated surface, 1e-2 the
inner one). Small isolated parts are dropped by the diagonal of their bounding box
(supplement §4), meshes are optionally culled to the faces some training camera sees, then
quadric-decimated to a face budget (fast-simplification).

Examples:
    >>> meshes, report = extract_duplex(baked_teacher, "cpu", cameras=train_cameras)
    >>> write_meshes(meshes, report, "out/lego_meshes")     # mesh_0.ply, mesh_1.ply, report.json

References: NDRF (Wan et al., CVPR 2023) §3.1, §4.1 "Optimization Details"; supplement §4.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh
from skimage.measure import marching_cubes
from tqdm import tqdm

from ..atomic import atomic_write, write_atomic
from ..ngprt.render_ref import features
from ..ngprt.space import cell_index, to_grid
from .config import NDRFConfig
from .hits import HitCaster

F32 = np.float32
_CHUNK = 1 << 18            # points per call of the density function
DensityFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ExtractConfig:
    """Sizes of the extraction (a preset changes sizes, never the algorithm).

    Attributes:
        N: cells per axis of the density grid over the scene box.
        face_budget: faces per mesh after quadric decimation; None keeps every face.
        min_component: connected parts whose bounding-box diagonal is below this fraction
            of the scene box's diagonal are dropped.
    """

    N: int
    face_budget: int | None = None
    min_component: float = 0.02

    def __post_init__(self):
        if self.N < 2 or (self.face_budget is not None and self.face_budget < 4) \
                or not 0.0 <= self.min_component < 1.0:
            raise ValueError(f"invalid ExtractConfig {self}: need N >= 2, face_budget None "
                             "or >= 4, min_component in [0, 1)")


PRESETS: dict[str, ExtractConfig] = {
    "paper": ExtractConfig(N=512),
    "cpu": ExtractConfig(N=256, face_budget=200_000),
    "tiny": ExtractConfig(N=64, face_budget=20_000),
}


def extract_preset(name: str, **overrides) -> ExtractConfig:
    """The extraction config of preset ``name`` with field ``overrides``."""
    if name not in PRESETS:
        raise ValueError(f"unknown extraction preset {name!r}; presets: {sorted(PRESETS)}")
    return replace(PRESETS[name], **overrides)


def teacher_density(model, inner_box: bool = False) -> DensityFn:
    """The density field a baked NGP-RT teacher renders (bounded scenes).

    Args:
        model: a :class:`clrender.ngprt.baked.BakedModel` with ``scene == "bounded"``, or
            with ``inner_box`` an unbounded one too: its density inside the inner unit box
            [-1, 1]^3, where the contraction is the identity.
    Returns:
        ``density(xyz)``: world points (M, 3) float32 -> sigma (M,) float32 in 1 / world
        units: ``exp`` of the feature's sigma logit (numpy reference ``features``) where the
        ``occupancy_0`` cell is occupied, 0 in empty cells and outside [-1, 1]^3, where the
        teacher renders nothing.
    """
    cfg = model.config
    unbounded = cfg.scene != "bounded"
    if unbounded and not inner_box:
        raise ValueError(f"teacher scene is {cfg.scene!r}: NDRF covers bounded scenes only; "
                         "mesh extraction in contracted space is not supported")
    occupancy = model.arrays["occupancy_0"]

    def density(xyz: np.ndarray) -> np.ndarray:
        u = to_grid(np.asarray(xyz, F32).reshape(-1, 3), cfg.extent, unbounded)
        inside = np.all((u >= 0) & (u <= 1), axis=1)
        i = cell_index(u, cfg.L_C)
        live = np.flatnonzero(inside & (occupancy[i[:, 0], i[:, 1], i[:, 2]] != 0))
        sigma = np.zeros(len(u), F32)
        for a in range(0, len(live), _CHUNK):
            rows = live[a:a + _CHUNK]
            sigma[rows] = np.exp(features(model, u[rows])[:, 0])
        return sigma

    return density


def cell_centres(N: int, box=(-1.0, 1.0)) -> np.ndarray:
    """(N,) float64 world coordinate of the cell centres along one axis:
    ``box[0] + (i + 0.5) * h`` with ``h = (box[1] - box[0]) / N``."""
    lo, hi = _check_box(box)
    return lo + (np.arange(N) + 0.5) * ((hi - lo) / N)


def sample_alpha(density_fn: DensityFn, N: int, step: float, box=(-1.0, 1.0),
                 progress: bool | None = None) -> np.ndarray:
    """Alpha of the density at the N^3 cell centres of the cube ``box``.

    Args:
        density_fn: world points (M, 3) float32 -> sigma (M,) float32 (1 / world units).
        N: cells per axis; cell (i, j, k) is centred at ``cell_centres(N, box)[[i, j, k]]``.
        step: the teacher's base step in world units (NGP-RT: ``gamma * s0``).
        box: (lo, hi) world bounds of the cube, the same on every axis.
        progress: tqdm bar; None shows it only on a terminal.
    Returns:
        alpha: (N, N, N) float32 ``1 - exp(-sigma * step)``, indexed [x, y, z].
    """
    if N < 2 or step <= 0:
        raise ValueError(f"sample_alpha: need N >= 2 and step > 0, got N={N}, step={step}")
    c = cell_centres(N, box).astype(F32)
    alpha = np.empty((N, N, N), F32)
    slabs = max(1, _CHUNK // (N * N))
    quiet = None if progress is None else not progress      # None: tqdm's "only on a tty"
    for x0 in tqdm(range(0, N, slabs), desc="density", unit="slab", disable=quiet):
        xs = c[x0:x0 + slabs]
        pts = np.stack(np.meshgrid(xs, c, c, indexing="ij"), -1).reshape(-1, 3)
        sigma = np.asarray(density_fn(pts), F32)
        alpha[x0:x0 + slabs] = (-np.expm1(-sigma * F32(step))).reshape(len(xs), N, N)
    return alpha


def extract_mesh(alpha: np.ndarray, threshold: float, box=(-1.0, 1.0),
                 min_component: float = 0.02, face_budget: int | None = None, cameras=None):
    """One mesh: the ``alpha = threshold`` level set; small parts dropped, then unseen faces
    culled (with ``cameras``), then decimation, so the face budget goes to seen faces.

    The grid is padded with one layer of alpha = 0 (the teacher is empty outside the box) so
    every surface is closed; vertices may lie up to half a cell outside the box there.
    Faces are oriented with normals towards decreasing alpha (out of the matter).

    Args:
        alpha: (N, N, N) float32 from :func:`sample_alpha` over the same ``box``.
        threshold: alpha level in (0, 1).
        min_component: drop connected parts whose bounding-box diagonal is below this
            fraction of the box diagonal.
        face_budget: quadric-decimate to at most about this many faces; None: no decimation.
        cameras: training cameras for :func:`cull_unseen`; None: no culling.
    Returns:
        mesh: trimesh.Trimesh in world units; stats: dict of face counts after marching
        (``faces_marched``), ``components_dropped`` and ``faces_culled``.
    """
    lo, hi = _check_box(box)
    if alpha.ndim != 3 or len(set(alpha.shape)) != 1:
        raise ValueError(f"alpha has shape {alpha.shape}, expected a cube (N, N, N)")
    a_max = float(alpha.max())
    if not 0.0 < threshold < a_max:
        raise ValueError(f"alpha never crosses threshold {threshold:g}: alpha range is "
                         f"[{float(alpha.min()):g}, {a_max:g}]")
    h = (hi - lo) / alpha.shape[0]
    verts, faces, _, _ = marching_cubes(np.pad(alpha, 1), level=threshold,
                                        gradient_direction="ascent", allow_degenerate=False)
    verts = lo + (verts - 0.5) * h          # padded index 1 is the centre of cell 0
    mesh = trimesh.Trimesh(verts.astype(F32), faces, process=False)
    n_marched = len(mesh.faces)
    mesh, dropped = drop_small_components(mesh, min_component * np.sqrt(3.0) * (hi - lo))
    n_kept = len(mesh.faces)
    if cameras is not None:
        mesh = cull_unseen(mesh, cameras)
    stats = {"faces_marched": n_marched, "components_dropped": dropped,
             "faces_culled": n_kept - len(mesh.faces)}
    if face_budget is not None and len(mesh.faces) > face_budget:
        mesh = mesh.simplify_quadric_decimation(face_count=face_budget)
    return mesh, stats


def drop_small_components(mesh: trimesh.Trimesh, min_diag: float):
    """Remove connected parts (by shared edges) whose bounding-box diagonal is < ``min_diag``
    world units. Returns the mesh and how many parts were removed."""
    if len(mesh.faces) == 0:
        return mesh, 0
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency,
                                                      node_count=len(mesh.faces))
    n = int(labels.max()) + 1
    tri = mesh.triangles
    lo, hi = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
    np.minimum.at(lo, labels, tri.min(axis=1))
    np.maximum.at(hi, labels, tri.max(axis=1))
    keep = np.linalg.norm(hi - lo, axis=1) >= min_diag
    return _keep_faces(mesh, keep[labels]), int(n - keep.sum())


def cull_unseen(mesh: trimesh.Trimesh, cameras) -> trimesh.Trimesh:
    """Keep the faces that at least one camera sees.

    A face is seen by a camera when its centre projects into the image and the ray from
    the camera centre towards it first hits the face itself (or nothing nearer). Aiming the
    rays at face centres, rather than through pixels, keeps faces smaller than a pixel.

    Args:
        mesh: world-space mesh; cameras: iterable of :class:`clrender.camera.Camera`.
    Returns:
        the mesh with unseen faces and unreferenced vertices removed.
    """
    if len(mesh.faces) == 0:
        return mesh
    caster = HitCaster([(mesh.vertices, mesh.faces)])
    centres = mesh.triangles_center
    seen = np.zeros(len(centres), bool)
    for cam in cameras:
        rows = np.flatnonzero(~seen & _in_view(cam, centres))
        to = centres[rows] - cam.origin
        dist = np.linalg.norm(to, axis=1)
        hits = caster.cast(np.broadcast_to(cam.origin, to.shape).astype(F32),
                           (to / dist[:, None]).astype(F32))
        tri, depth = hits.tri[0], hits.depth[0]
        seen[rows] = (tri == rows) | (tri < 0) | (depth >= dist * (1.0 - 1e-5))
    return _keep_faces(mesh, seen)


def extract_duplex(source, config: ExtractConfig | str = "cpu", thresholds=None,
                   step: float | None = None, box=(-1.0, 1.0), cameras=None,
                   progress: bool | None = None):
    """Sample alpha, then per threshold march, drop small parts, cull, decimate.

    Args:
        source: a baked NGP-RT teacher (bounded) or a density function (then ``step``).
        config: an :class:`ExtractConfig` or a preset name (tiny, cpu, paper).
        thresholds: K increasing alpha levels; default ``NDRFConfig().thresholds``.
        step: base step in world units; default the teacher's ``model.step``.
        box: (lo, hi) world bounds of the sampled cube.
        cameras: training cameras for :func:`cull_unseen`; None: no culling.
    Returns:
        meshes: K trimesh.Trimesh, outer first; report: JSON-ready dict (N, step, box,
        alpha range, seconds; per mesh threshold, vertices, faces, :func:`extract_mesh`'s
        stats and seconds).
    """
    cfg = extract_preset(config) if isinstance(config, str) else config
    thresholds = NDRFConfig(**({} if thresholds is None else {"thresholds": thresholds}))
    density = source if callable(source) else teacher_density(source)
    cameras = None if cameras is None else list(cameras)
    if step is None and callable(source):
        raise ValueError("extract_duplex: a density function needs the base step in world units")
    step = float(source.step if step is None else step)
    t0 = time.perf_counter()
    alpha = sample_alpha(density, cfg.N, step, box, progress)
    report = {"N": cfg.N, "step": step, "box": [float(b) for b in box],
              "alpha_range": [float(alpha.min()), float(alpha.max())],
              "sample_seconds": time.perf_counter() - t0, "meshes": []}
    meshes = []
    for t in thresholds.thresholds:
        t0 = time.perf_counter()
        mesh, stats = extract_mesh(alpha, t, box, cfg.min_component, cfg.face_budget, cameras)
        meshes.append(mesh)
        report["meshes"].append({"threshold": t, "vertices": len(mesh.vertices),
                                 "faces": len(mesh.faces), **stats,
                                 "seconds": time.perf_counter() - t0})
    return meshes, report


def write_meshes(meshes, report: dict, out_dir) -> list[Path]:
    """Write ``mesh_{k}.ply`` (binary PLY) for each mesh and ``report.json``, atomically.
    Returns the paths written, meshes first."""
    out = Path(out_dir)
    paths = [atomic_write(out / f"mesh_{k}.ply",
                          lambda tmp, m=m: m.export(tmp, file_type="ply", encoding="binary"))
             for k, m in enumerate(meshes)]
    paths.append(write_atomic(out / "report.json", json.dumps(report, indent=2) + "\n"))
    return paths


def _check_box(box) -> tuple[float, float]:
    lo, hi = (float(b) for b in box)
    if not lo < hi:
        raise ValueError(f"box {box} must be (lo, hi) with lo < hi")
    return lo, hi


def _keep_faces(mesh: trimesh.Trimesh, mask: np.ndarray) -> trimesh.Trimesh:
    out = mesh.copy()
    out.update_faces(mask)
    out.remove_unreferenced_vertices()
    return out


def _in_view(camera, points: np.ndarray) -> np.ndarray:
    """(M,) bool: world points (M, 3) in front of ``camera`` projecting inside its image."""
    p = (points - camera.origin) @ camera.c2w[:3, :3]       # camera frame, looking down -z
    z = -p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        px = camera.fx * p[:, 0] / z + camera.cx
        py = camera.cy - camera.fy * p[:, 1] / z
    return (z > 0) & (px >= 0) & (px < camera.width) & (py >= 0) & (py < camera.height)
