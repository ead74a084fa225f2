"""Comparing two sets of first hits (the OpenCL rasteriser against Embree), pixel by pixel.

A pixel where the two disagree (another triangle, or a hit against a miss) is *explained*
when the float64 intersection of its float32 ray with a triangle involved puts it on that
triangle's edge (barycentric margin ``edge_tol``; the ray's own float32 rounding moves a
grazing hit by more, so the margin grows with 1 / |cos| of the angle between ray and
triangle), or the ray starts on that triangle (depth below ``depth_rtol``: a camera on the
surface, where Embree reports the hit at t = 0 and the rasteriser, whose triangles through
the eye cover nothing, the next one), or, for two different triangles, at the same depth
within ``depth_rtol``.
"""
from __future__ import annotations

import numpy as np

F64 = np.float64


def ray_triangle64(o, d, p):
    """Float64 barycentrics (N, 3) (b0 of p0, u of p1, v of p2), depth t (N,) and |cos| (N,)
    of the angle between ray and triangle normal, for rays o, d (N, 3), triangles p (N, 3, 3)."""
    o, d, p = (np.asarray(a, F64) for a in (o, d, p))
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    pv = np.cross(d, e2)
    det = (e1 * pv).sum(1)
    tv = o - p[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (tv * pv).sum(1) / det
        qv = np.cross(tv, e1)
        v = (d * qv).sum(1) / det
        t = (e2 * qv).sum(1) / det
        n = np.cross(e1, e2)
        cos = np.abs((n * d).sum(1)) / np.linalg.norm(n, axis=1) / np.linalg.norm(d, axis=1)
    return np.stack([1.0 - u - v, u, v], 1), t, cos


def compare(meshes, origins, dirs, a, b, edge_tol=1e-5, depth_rtol=1e-6) -> dict:
    """Per mesh k, compare hits ``a`` and ``b`` (:class:`clrender.ndrf.hits.Hits`, (K, H, W))
    of rays ``origins``, ``dirs`` (H, W, 3).

    Returns ``{"covered", "agree", "unexplained", "bary_err", "depth_rerr", "depth", "cos",
    "kappa"}``: pixels either covers, pixels with the same triangle, disagreements not
    explained, and for each agreeing hit the larger |a - b| of (u, v), the relative depth
    difference, ``b``'s depth, the |cos| of the hit and its condition number
    |origin - p0| / (h |cos|), h the triangle's smallest height: float32 rounding of the
    ray's origin moves the barycentrics by about eps x that.
    """
    out = {"covered": 0, "agree": 0, "unexplained": 0, "bary_err": [], "depth_rerr": [],
           "depth": [], "cos": [], "kappa": []}
    o, d = origins.reshape(-1, 3), dirs.reshape(-1, 3)
    for k, (vertices, faces) in enumerate(meshes):
        ta, tb = a.tri[k].reshape(-1), b.tri[k].reshape(-1)
        cov = (ta >= 0) | (tb >= 0)
        same = (ta == tb) & (ta >= 0)
        out["covered"] += int(cov.sum())
        out["agree"] += int(((ta == tb) & cov).sum())
        if same.any():
            p = np.asarray(vertices)[np.asarray(faces)[ta[same]]]
            _, _, cos = ray_triangle64(o[same], d[same], p)
            p64 = p.astype(F64)
            edges = np.stack([p64[:, 1] - p64[:, 0], p64[:, 2] - p64[:, 1],
                              p64[:, 0] - p64[:, 2]], 1)
            twice_area = np.linalg.norm(np.cross(edges[:, 0], -edges[:, 2]), axis=1)
            size = twice_area / np.linalg.norm(edges, axis=2).max(1)       # smallest height
            out["kappa"].append(np.linalg.norm(o[same] - p64[:, 0], axis=1)
                                / np.maximum(size * cos, 1e-30))
            out["bary_err"].append(np.abs(a.bary[k].reshape(-1, 2)[same]
                                          - b.bary[k].reshape(-1, 2)[same]).max(1))
            da, db = a.depth[k].reshape(-1)[same], b.depth[k].reshape(-1)[same]
            out["depth_rerr"].append(np.abs(da.astype(F64) / db - 1.0))
            out["depth"].append(db)
            out["cos"].append(cos)
        for i in np.flatnonzero(cov & (ta != tb)):
            out["unexplained"] += not _explained(vertices, faces, o[i], d[i], ta[i], tb[i],
                                                 edge_tol, depth_rtol)
    for key in ("bary_err", "depth_rerr", "depth", "cos", "kappa"):
        out[key] = np.concatenate(out[key]) if out[key] else np.zeros(0)
    return out


def _explained(vertices, faces, o, d, ta, tb, edge_tol, depth_rtol) -> bool:
    tris = [t for t in (ta, tb) if t >= 0]
    p = np.asarray(vertices)[np.asarray(faces)[tris]]
    bary, t, cos = ray_triangle64(np.repeat(o[None], len(tris), 0),
                                  np.repeat(d[None], len(tris), 0), p)
    margin = edge_tol / np.maximum(cos, 1e-3)
    if np.any(np.abs(bary.min(1)) <= margin) or np.any(np.abs(t) <= depth_rtol):
        return True
    return len(tris) == 2 and abs(t[0] - t[1]) <= depth_rtol * max(abs(t[0]), abs(t[1]))
