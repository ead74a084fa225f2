"""Per-vertex colours of a triangle mesh that best reproduce a set of posed images, and the
mesh's own render (first Embree hits, barycentric colours): what a viewer without view
dependence shows of an exported mesh.

A pixel whose ray first hits triangle (a, b, c) at barycentrics (w_a, w_b, w_c) shows
``w_a c_a + w_b c_b + w_c c_c``. The colours minimise, over the hit pixels of every view,

    sum_pixels |w . c - y|^2  +  lam * sum_edges |c_i - c_j|^2

(the smoothness term, ``lam`` relative to the mean pixel weight a vertex gets, fills
vertices no view sees from their neighbours and damps noise); the normal equations, sparse
(V x V, one system for the three channels), are solved by conjugate gradients from the
pixels' weighted mean (scipy).

Examples:
    >>> colours = fit_vertex_colours(vertices, faces, cameras, images)   # (V, 3) in [0, 1]
    >>> rgb = render_mesh(vertices, faces, colours, camera, background)  # (H, W, 3)
"""
from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import laplacian
from scipy.sparse.linalg import cg

SMOOTHNESS = 1e-2          # lam: the edge term's weight against the mean pixel weight a
CG_TOLERANCE = 1e-6        # vertex gets (relative residual of the normal equations)
CG_ITERATIONS = 500


def _hits(caster, camera):
    """(pixel rows, triangle ids, (M, 3) barycentric weights) of a camera's hit pixels."""
    hits = caster.cast_camera(camera)
    tri = hits.tri[0].reshape(-1)
    rows = np.flatnonzero(tri >= 0)
    uv = hits.bary[0].reshape(-1, 2)[rows].astype(np.float64)
    weights = np.column_stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]])
    return rows, tri[rows], weights


def fit_vertex_colours(vertices: np.ndarray, faces: np.ndarray, cameras, images,
                       smoothness: float = SMOOTHNESS) -> np.ndarray:
    """Least-squares vertex colours of the mesh that reproduce ``images`` at ``cameras``.

    Args:
        vertices: (V, 3) float positions; faces: (F, 3) int.
        cameras: the views' :class:`clrender.Camera`; images: matching (H, W, 3) float
            arrays in [0, 1].
        smoothness: the edge term's weight (module doc).
    Returns:
        (V, 3) float32 in [0, 1].
    """
    from ..ndrf.hits import HitCaster

    faces = np.asarray(faces, np.int64)
    V = len(vertices)
    caster = HitCaster([(vertices, faces)])
    gram = sparse.csr_matrix((V, V))
    rhs = np.zeros((V, 3))
    for camera, image in zip(cameras, images):
        rows, tri, w = _hits(caster, camera)
        corners = faces[tri]                                       # (M, 3)
        y = np.asarray(image, np.float64).reshape(-1, 3)[rows]
        i = np.repeat(corners, 3, axis=1).reshape(-1)
        j = np.tile(corners, (1, 3)).reshape(-1)
        gram = gram + sparse.csr_matrix(
            ((w[:, :, None] * w[:, None, :]).reshape(-1), (i, j)), shape=(V, V))
        rhs += _scatter(corners.reshape(-1), (w[:, :, None] * y[:, None, :]).reshape(-1, 3), V)
    weight = np.asarray(gram.sum(axis=1)).ravel()      # each vertex's summed pixel weight
    seen = weight > 0
    if not seen.any():
        raise ValueError("no view sees the mesh: nothing to colour it from")
    lam = smoothness * weight[seen].mean()
    system = (gram + lam * _edge_laplacian(faces, V)).tocsr()
    mean = rhs[seen].sum(0) / weight[seen].sum()
    start = np.where(seen[:, None], rhs / np.maximum(weight, 1e-12)[:, None], mean)
    colours = np.empty((V, 3))
    jacobi = sparse.diags(1.0 / np.maximum(system.diagonal(), 1e-12))
    for c in range(3):
        colours[:, c], _ = cg(system, rhs[:, c], x0=start[:, c], rtol=CG_TOLERANCE,
                              maxiter=CG_ITERATIONS, M=jacobi)
    return np.clip(colours, 0.0, 1.0).astype(np.float32)


def _scatter(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n, C) sums of ``values`` (M, C) by row ``index`` (M,)."""
    return np.stack([np.bincount(index, values[:, c], minlength=n)
                     for c in range(values.shape[1])], axis=1)


def _edge_laplacian(faces: np.ndarray, V: int) -> sparse.csr_matrix:
    """The graph Laplacian of the mesh's unique edges (V x V)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    edges = np.unique(edges, axis=0)
    a = sparse.csr_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(V, V))
    return laplacian(a + a.T).tocsr()


def render_mesh(vertices: np.ndarray, faces: np.ndarray, colours: np.ndarray, camera,
                background, caster=None) -> np.ndarray:
    """(H, W, 3) float32: each pixel's first hit's barycentric colour, ``background`` (3,)
    where its ray misses (``caster``: a HitCaster of this one mesh, to reuse)."""
    from ..ndrf.hits import HitCaster
    from ..ndrf.shader_ref import barycentric

    caster = caster or HitCaster([(vertices, faces)])
    hits = caster.cast_camera(camera)
    rgb = barycentric(np.asarray(colours, np.float32), np.asarray(faces), hits.tri[0],
                      hits.bary[0])
    return np.where((hits.tri[0] >= 0)[..., None], rgb,
                    np.asarray(background, np.float32)).astype(np.float32)
