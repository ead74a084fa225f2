"""First ray-mesh hits of every pixel on each of an NDRF model's K meshes (Embree).

Examples:
    >>> caster = HitCaster(model)                 # Embree scenes built once per model
    >>> hits = caster.cast_camera(camera)         # hits.tri: (K, H, W) int32, -1 = miss

References: NDRF (Wan et al., CVPR 2023) §3.1, §3.4 (rasterisation replaced by ray casting).
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..camera import Camera, generate_rays

F32 = np.float32
MIN_CHUNK = 1 << 15          # rays a thread casts at least (smaller batches cost more than they save)


@dataclass
class Hits:
    """First hits of a set of rays on K meshes.

    Attributes:
        tri: (K, ...) int32 triangle index into ``faces_k``, -1 for a miss.
        bary: (K, ..., 2) float32 Embree barycentrics (u, v): the hit point is
            ``(1-u-v) p0 + u p1 + v p2``; zeros on a miss.
        depth: (K, ...) float32 distance along the (unit) ray in world units; inf on a miss.
    """

    tri: np.ndarray
    bary: np.ndarray
    depth: np.ndarray

    @property
    def coverage(self) -> np.ndarray:
        """(...) bool: the ray hits at least one mesh (docs/ndrf.md "Compositing")."""
        return (self.tri >= 0).any(axis=0)


class HitCaster:
    """Embree scenes of a model's meshes, built once, cast into many times.

    Args:
        meshes: ``[(vertices (V, 3), faces (F, 3)), ...]`` or an object with ``.config.K``
            and ``.mesh(k)`` (an :class:`clrender.ndrf.baked.NDRFModel`).
        threads: casting threads (embreex releases the GIL while Embree traverses); default
            the machine's cores.
    """

    def __init__(self, meshes, threads: int | None = None):
        # Embree is imported where it casts: loading or rasterising an NDRF model needs none.
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.threads = max(1, threads or os.cpu_count() or 1)
        if hasattr(meshes, "mesh"):
            meshes = [meshes.mesh(k)[:2] for k in range(meshes.config.K)]
        self._scenes = []
        for vertices, faces in meshes:
            scene = rtcore_scene.EmbreeScene()
            TriangleMesh(scene, np.ascontiguousarray(np.asarray(vertices, F32)[faces], F32))
            self._scenes.append(scene)

    @property
    def K(self) -> int:
        return len(self._scenes)

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> Hits:
        """First hits of rays ``origins``, ``dirs`` (..., 3) float32 (unit directions)."""
        shape = origins.shape[:-1]
        o = np.ascontiguousarray(origins.reshape(-1, 3), F32)
        d = np.ascontiguousarray(dirs.reshape(-1, 3), F32)
        tri = np.full((self.K, len(o)), -1, np.int32)
        bary = np.zeros((self.K, len(o), 2), F32)
        depth = np.full((self.K, len(o)), np.inf, F32)
        n = len(o)
        chunk = max(MIN_CHUNK, -(-n // self.threads))
        jobs = [(k, a, min(a + chunk, n)) for k in range(self.K) for a in range(0, n, chunk)]

        def cast_one(job):
            k, a, b = job
            res = self._scenes[k].run(o[a:b], d[a:b], output=1)
            prim = np.asarray(res["primID"], np.int64)
            hit = np.flatnonzero(prim >= 0) + a
            tri[k, hit] = prim[hit - a]
            bary[k, hit, 0] = np.asarray(res["u"], F32)[hit - a]
            bary[k, hit, 1] = np.asarray(res["v"], F32)[hit - a]
            depth[k, hit] = np.asarray(res["tfar"], F32)[hit - a]

        if len(jobs) > 1 and self.threads > 1:
            with ThreadPoolExecutor(min(self.threads, len(jobs))) as pool:
                list(pool.map(cast_one, jobs))
        else:
            for job in jobs:
                cast_one(job)
        return Hits(tri.reshape((self.K,) + shape), bary.reshape((self.K,) + shape + (2,)),
                    depth.reshape((self.K,) + shape))

    def cast_camera(self, camera: Camera) -> Hits:
        """First hits of the rays through every pixel centre: arrays (K, H, W[, 2])."""
        origins, dirs = generate_rays(camera)
        return self.cast(origins, dirs)
