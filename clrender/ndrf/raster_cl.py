"""The OpenCL visibility-buffer rasteriser of NDRF's K meshes (``kernels/ndrf_raster.cl``).

Per frame, on the device: clear, cover each triangle's pixels with a depth test (a 64-bit
atomic min of depth | id per pixel and mesh, or a two-pass 32-bit fallback on devices
without ``cl_khr_int64_extended_atomics``), then resolve each pixel's nearest triangle into
the hits the shader reads: triangle id, Embree's barycentrics (u, v) and the depth along the
unit ray, recomputed from the pixel ray. The hit buffers stay on the device for
:class:`clrender.ndrf.shader_cl.Shader`; :meth:`Rasteriser.hits` reads them back (tests,
statistics). :class:`clrender.ndrf.hits.HitCaster` (Embree) is the reference.

A triangle whose screen box holds at most TILE^2 pixels is covered by its own work-item, row
by row over the span its edges allow; a larger one is binned into (triangle, tile) pairs and
covered by a second pass, parallel over the pairs, so no work-item loops over more than
TILE^2 pixels, however close the camera. (An area bound, not a side bound: the slivers of a
decimated mesh have long thin boxes, and binning those cost more than covering them.)

Examples:
    >>> raster = Rasteriser(model)
    >>> bufs, ms = raster.rasterise(camera)      # device buffers "tri", "bary", "depth"
    >>> hits = raster.hits(camera)               # Hits, as HitCaster.cast_camera

References: NDRF (Wan et al., CVPR 2023) §3.4 (hardware rasterisation); M. Olano and
T. Greer, "Triangle scan conversion using 2D homogeneous coordinates", 1997.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..device import check_allocation, event_ms, get_runtime, padded, work_group_size
from .hits import Hits

F32, I32 = np.float32, np.int32
TILE = 32                   # pixels a side of a binning tile (TILE^2 pixels a work-item)
INITIAL_PAIRS = 1 << 14     # (triangle, tile) pairs first allocated; grown on demand


def has_int64_atomics(device: cl.Device) -> bool:
    """Whether ``device`` offers the 64-bit atomic min the one-pass depth test uses."""
    return "cl_khr_int64_extended_atomics" in device.extensions.split()


def packed_geometry(meshes) -> dict:
    """The K meshes concatenated: ``face_start`` (K+1,) int32 first face of each mesh,
    ``faces`` (sum F_k, 3) int32 into the concatenated ``vertices`` (sum V_k, 3) float32."""
    faces, vertices, face_start, n_vertices = [], [], [0], 0
    for v, f in meshes:
        faces.append(np.asarray(f, I32).reshape(-1, 3) + I32(n_vertices))
        vertices.append(np.asarray(v, F32).reshape(-1, 3))
        n_vertices += len(vertices[-1])
        face_start.append(face_start[-1] + len(faces[-1]))
    return {"face_start": np.asarray(face_start, I32), "faces": np.concatenate(faces),
            "vertices": np.concatenate(vertices)}


def pixel_ray_ab(camera) -> np.ndarray:
    """(W + H,) float32: a = (x + 0.5 - cx) / fx per column, then b = -((y + 0.5 - cy) / fy)
    per row, the camera-space pixel ray (a, b, -1) with the float32 operations of
    ``kernels/camera.h`` (and :func:`clrender.camera.generate_rays`), bit for bit."""
    p = camera.packed()
    x = np.arange(camera.width, dtype=F32) + F32(0.5)
    y = np.arange(camera.height, dtype=F32) + F32(0.5)
    return np.concatenate([(x - p[2]) / p[0], -((y - p[3]) / p[1])]).astype(F32)


class Rasteriser:
    """First hits of every pixel on K meshes, computed on an OpenCL device.

    Args:
        meshes: an :class:`clrender.ndrf.baked.NDRFModel` (validated by its loader) or
            ``[(vertices (V, 3), faces (F, 3)), ...]``; a mesh may have no face.
        device: OpenCL device spec or :class:`clrender.device.Runtime`.
        atomics64: use the 64-bit atomic depth test; None: where the device has it.
    """

    def __init__(self, meshes, device=None, atomics64: bool | None = None):
        if hasattr(meshes, "mesh"):
            meshes = [meshes.mesh(k)[:2] for k in range(meshes.config.K)]
        self.runtime = rt = get_runtime(device)
        self.K = len(meshes)
        self.atomics64 = has_int64_atomics(rt.device) if atomics64 is None else bool(atomics64)
        if self.atomics64 and not has_int64_atomics(rt.device):
            raise ValueError(f"{rt.name}: no cl_khr_int64_extended_atomics for the 64-bit "
                             "depth test")
        program = rt.program("ndrf_raster.cl",
                             {"K": self.K, "TILE": TILE, "ATOMICS64": self.atomics64})
        self._kernels = {n: program.kernel(n) for n in
                         ("ndrf_raster_clear", "ndrf_raster_tris", "ndrf_raster_tiles",
                          "ndrf_resolve")}
        geometry = packed_geometry(meshes)
        self.n_faces = int(geometry["face_start"][-1])
        mf = cl.mem_flags
        # A buffer of zero bytes is invalid: an empty mesh set still gets one element.
        self._geo = {name: cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                     hostbuf=np.ascontiguousarray(a) if a.size
                                     else np.zeros(3, a.dtype))
                     for name, a in geometry.items()}
        self._n_pairs = cl.Buffer(rt.context, mf.READ_WRITE, 4)
        self._capacity = 0
        self.binned_pairs = 0        # (triangle, tile) pairs the last frame binned
        self._size = None
        self._bufs: dict = {}
        self._local: dict = {}

    @property
    def mode(self) -> str:
        """Which depth test runs: "64-bit atomics" or "32-bit two-pass"."""
        return "64-bit atomics" if self.atomics64 else "32-bit two-pass"

    def _frame_buffers(self, width: int, height: int) -> dict:
        if self._size != (width, height):
            n = self.K * width * height
            if n >= 2 ** 31:
                raise ValueError(f"{width}x{height} pixels x K={self.K} meshes: more hit slots "
                                 "than the rasteriser's int32 indices address")
            sizes = {"tri": 4 * n, "bary": 8 * n, "depth": 4 * n}
            sizes.update({"keys": 8 * n} if self.atomics64 else
                         {"depth_bits": 4 * n, "ids": 4 * n})
            ctx, mf = self.runtime.context, cl.mem_flags
            for name, nbytes in sizes.items():
                check_allocation(self.runtime.device, f"raster buffer '{name}' for "
                                 f"{width}x{height} pixels, K={self.K}", nbytes)
            self._bufs = {"cam": cl.Buffer(ctx, mf.READ_ONLY, 16 * 4),
                          "ray_ab": cl.Buffer(ctx, mf.READ_ONLY, 4 * (width + height))}
            self._bufs.update({name: cl.Buffer(ctx, mf.READ_WRITE, max(nbytes, 4))
                               for name, nbytes in sizes.items()})
            self._size = (width, height)
        return self._bufs

    def _pairs(self, capacity: int) -> cl.Buffer:
        if capacity > self._capacity:
            check_allocation(self.runtime.device, f"raster tile pairs ({capacity})", 8 * capacity)
            self._pairs_buf = cl.Buffer(self.runtime.context, cl.mem_flags.READ_WRITE,
                                        8 * capacity)
            self._capacity = capacity
        return self._pairs_buf

    def _run(self, name: str, shape: tuple[int, ...], *args) -> cl.Event:
        key = (name, shape)
        if key not in self._local:
            self._local[key] = work_group_size(self._kernels[name], self.runtime.device, shape)
        local = self._local[key]
        return self._kernels[name](self.runtime.queue, padded(shape, local), local, *args)

    def _target(self, b: dict, pass_: int) -> tuple:
        if self.atomics64:
            return (b["keys"],)
        return (b["depth_bits"], b["ids"], np.int32(pass_))

    def _cover(self, camera, b: dict, pass_: int) -> list[cl.Event]:
        """One covering pass (both kernels); grows the pair buffer and reruns if it overflowed."""
        q, g, w, h = self.runtime.queue, self._geo, np.int32(camera.width), np.int32(camera.height)
        count = np.zeros(1, I32)
        capacity = max(self._capacity, INITIAL_PAIRS)
        while True:
            pairs = self._pairs(capacity)
            cl.enqueue_copy(q, self._n_pairs, np.zeros(1, I32))
            ev_tris = self._run("ndrf_raster_tris", (max(self.n_faces, 1),), b["cam"], w, h,
                                np.int32(self.n_faces), g["face_start"], g["faces"],
                                g["vertices"], b["ray_ab"], np.int32(self._capacity),
                                self._n_pairs, pairs, *self._target(b, pass_))
            cl.enqueue_copy(q, count, self._n_pairs)
            if count[0] <= self._capacity:
                break
            capacity = int(count[0])
        self.binned_pairs = int(count[0])
        ev_tiles = self._run("ndrf_raster_tiles", (max(int(count[0]), 1),), b["cam"], w, h,
                             g["face_start"], g["faces"], g["vertices"], b["ray_ab"],
                             np.int32(count[0]), pairs, *self._target(b, pass_))
        return [ev_tris, ev_tiles]

    def rasterise(self, camera) -> tuple[dict, dict]:
        """Hits of every pixel of ``camera`` on each mesh, left on the device.

        Returns:
            ``(buffers, ms)``: device buffers ``tri`` (K, H, W) int32 (-1 on a miss),
            ``bary`` (K, H, W, 2) float32 Embree (u, v), ``depth`` (K, H, W) float32 along
            the unit ray (inf on a miss); ``ms`` {"ms_raster", "ms_resolve"} kernel times.
        """
        w, h = camera.width, camera.height
        b, q = self._frame_buffers(w, h), self.runtime.queue
        cl.enqueue_copy(q, b["cam"], camera.packed())
        cl.enqueue_copy(q, b["ray_ab"], pixel_ray_ab(camera))
        n = self.K * w * h
        events = [self._run("ndrf_raster_clear", (max(n, 1),), np.int32(n),
                            *self._target(b, 0))]
        for pass_ in (0,) if self.atomics64 else (0, 1):
            events += self._cover(camera, b, pass_)
        resolve = self._run("ndrf_resolve", (w, h), b["cam"], np.int32(w), np.int32(h),
                            self._geo["face_start"], self._geo["faces"], self._geo["vertices"],
                            b["ray_ab"],
                            b["keys"] if self.atomics64 else b["ids"], b["tri"], b["bary"],
                            b["depth"])
        return b, {"ms_raster": sum(event_ms(e) for e in events),
                   "ms_resolve": event_ms(resolve)}

    def read_hits(self, camera) -> Hits:
        """The last :meth:`rasterise` of ``camera`` read back: arrays (K, H, W[, 2])."""
        shape = (self.K, camera.height, camera.width)
        tri, bary, depth = np.empty(shape, I32), np.empty(shape + (2,), F32), np.empty(shape, F32)
        q = self.runtime.queue
        for name, a in (("tri", tri), ("bary", bary), ("depth", depth)):
            cl.enqueue_copy(q, a, self._bufs[name])
        return Hits(tri, bary, depth)

    def hits(self, camera) -> Hits:
        """First hits of the rays through every pixel centre, as
        :meth:`clrender.ndrf.hits.HitCaster.cast_camera`."""
        self.rasterise(camera)
        return self.read_hits(camera)
