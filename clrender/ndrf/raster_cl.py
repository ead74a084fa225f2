"""The OpenCL visibility-buffer rasteriser of NDRF's K meshes (``kernels/ndrf_raster.cl``).

Per frame, on the device: set up every triangle in camera space and bin it into the TS x TS
screen tiles its edges may cover (count, a one-work-group prefix sum, fill), then cover
each tile's pixels with its triangles, a whole tile row as one vector, keeping the nearest
triangle per pixel and mesh in private memory (a tile owns its pixels: no atomic depth
test, so any OpenCL 1.1 device runs it) with the hits the shader reads: triangle id,
Embree's barycentrics (u, v) and the depth along the unit ray, from the same edge functions
(exact ray-triangle in camera space, docs/ndrf.md). The hit buffers stay on the device for
:class:`clrender.ndrf.shader_cl.Shader`; :meth:`Rasteriser.hits` reads them back (tests,
statistics). :class:`clrender.ndrf.hits.HitCaster` (Embree) is the reference.

A frame makes no blocking call: the list of (triangle, tile) pairs is not sized from a
read-back of their count; the frame bins into the list it has (the kernels neither write
nor read past it) and reads the count back without waiting. After the frame's blocking
read of its outputs, :meth:`Rasteriser.settle` checks the count: on overflow (rare: the
list only grows) the list is grown and the frame binned and tiled again.

The layout (:func:`device_layout`): a setup work-item takes ``lanes`` triangles, 16 on CPUs
(one a float16 lane) and 1 on GPUs; a tile work-item covers ``rows`` rows of a tile, the
whole tile on CPUs (one float16 a row, the triangle list read once) and one row on GPUs (TS
work-items a tile). However close the camera,
no work-item loops over more than TS^2 pixels a triangle, and a triangle enters only the
tiles its edge functions do not exclude at the tile's corners (long slivers stay cheap).

Examples:
    >>> raster = Rasteriser(model)
    >>> bufs = raster.rasterise(camera)   # device buffers "tri", "bary", "depth"
    >>> ...                               # the frame's blocking read of what uses them
    >>> if raster.settle(): ...           # the list overflowed: hits redone, read again
    >>> raster.frame_ms()                 # the kernels' time
    >>> hits = raster.hits(camera)        # all of it: Hits, as HitCaster.cast_camera

References: NDRF (Wan et al., CVPR 2023) §3.4 (hardware rasterisation); M. Olano and
T. Greer, "Triangle scan conversion using 2D homogeneous coordinates", 1997; S. Laine and
T. Karras, "High-performance software rasterization on GPUs", 2011 (binning into tiles).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..camera import CAM_BYTES
from ..device import (check_allocation, device_type_name, event_ms, get_runtime, padded,
                      work_group_size)
from .hits import Hits

F32, I32 = np.float32, np.int32
TS = 16                     # pixels a side of a tile: one float16 a tile row
INITIAL_PAIRS = 1 << 16     # (triangle, tile) list slots first allocated; grown on demand
TRI_WORDS = 16              # 32-bit words of a triangle's setup record (-D TRI_WORDS)
SCAN_ITEMS = 256            # work-items of the tile scan's one work-group, at most
GPU_LAYOUT = {"rows": 1, "lanes": 1}   # device_layout on GPUs


def device_layout(device: cl.Device) -> dict:
    """How the rasteriser is organised on ``device``: ``rows``, the tile rows a tile
    work-item covers (-D TROWS), and ``lanes``, the triangles a setup work-item takes, one a
    vector lane (-D LANES). CPUs: a whole tile (its triangle list read once) and 16 lanes
    (PoCL vectorises within a work-item, not across them); GPUs (:data:`GPU_LAYOUT`): one
    row and one triangle, parallelism from the work-items."""
    if device_type_name(device) == "GPU":
        return dict(GPU_LAYOUT)
    return {"rows": TS, "lanes": 16}


def scan_items(kernel: cl.Kernel, device: cl.Device) -> int:
    """Work-items of the tile scan's one work-group on ``device``: :data:`SCAN_ITEMS`, or
    fewer where the kernel's work-group size or the local memory (an int each) is smaller."""
    limit = kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, device)
    return max(1, min(SCAN_ITEMS, int(limit), int(device.local_mem_size) // 4))


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


def morton_order(points) -> np.ndarray:
    """(N,) int32: ``points`` (N, 3) sorted along a Morton (Z-order) curve, 10 bits an axis
    over their bounds. The rasteriser stores its faces in this order of their centroids (the
    triangles a screen tile lists lie close together in memory: their setup records come
    from cache; hits still report the faces' own indices), the shader its vertices (a
    pixel's neighbours' vertex rows too)."""
    c = np.nan_to_num(np.asarray(points, np.float64).reshape(-1, 3))
    if not len(c):
        return np.zeros(0, I32)
    lo, span = c.min(axis=0), np.ptp(c, axis=0)
    q = np.clip((c - lo) / np.where(span > 0, span, 1.0) * 1023, 0, 1023).astype(np.uint64)
    code = np.zeros(len(c), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable").astype(I32)


def vertices_in_morton_order(vertices, faces) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A mesh renumbered with its vertices in Morton order (:func:`morton_order`), faces in
    their own order: ``(vertices (V, 3) float32, faces (F, 3) int32, perm)``, perm (V,) int32
    the vertex each row had."""
    vertices = np.asarray(vertices, F32).reshape(-1, 3)
    faces = np.asarray(faces, I32).reshape(-1, 3)
    perm = morton_order(vertices)
    inverse = np.empty_like(perm)
    inverse[perm] = np.arange(len(perm), dtype=I32)
    return vertices[perm], inverse[faces] if len(faces) else faces, perm


def spatially_ordered(vertices, faces) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
    """A mesh with its vertices and faces in Morton order (:func:`morton_order`; faces by
    their centroids): ``((vertices, faces), face_ids)``, face_ids (F,) int32 the index each
    face had."""
    vertices, faces, _ = vertices_in_morton_order(vertices, faces)
    face_ids = morton_order(vertices[faces].mean(axis=1)) if len(faces) else np.zeros(0, I32)
    return (vertices, faces[face_ids]), face_ids


def pixel_ray_ab(camera) -> np.ndarray:
    """(W' + H,) float32: a = (x + 0.5 - cx) / fx per column, NaN past the last one up to
    W' = W rounded up to whole tiles (no edge test passes there), then
    b = -((y + 0.5 - cy) / fy) per row: the camera-space pixel ray (a, b, -1) with the
    float32 operations of ``kernels/camera.h`` (and :func:`clrender.camera.generate_rays`),
    bit for bit."""
    p = camera.packed()
    x = np.arange(camera.width, dtype=F32) + F32(0.5)
    y = np.arange(camera.height, dtype=F32) + F32(0.5)
    pad = np.full(-camera.width % TS, np.nan, F32)
    return np.concatenate([(x - p[2]) / p[0], pad, -((y - p[3]) / p[1])]).astype(F32)


class Rasteriser:
    """First hits of every pixel on K meshes, computed on an OpenCL device.

    Args:
        meshes: an :class:`clrender.ndrf.baked.NDRFModel` (validated by its loader) or
            ``[(vertices (V, 3), faces (F, 3)), ...]``; a mesh may have no face.
        device: OpenCL device spec or :class:`clrender.device.Runtime`.
        rows: tile rows a work-item covers (a divisor of TS); None: :func:`device_layout`.
        lanes: triangles a setup work-item takes (1 or 16); None: :func:`device_layout`.
            Every layout gives the same hits, bit for bit.
    """

    KERNELS = ("ndrf_raster_setup", "ndrf_raster_scan", "ndrf_raster_bin", "ndrf_raster_tile")

    def __init__(self, meshes, device=None, rows: int | None = None,
                 lanes: int | None = None):
        if hasattr(meshes, "mesh"):
            meshes = [meshes.mesh(k)[:2] for k in range(meshes.config.K)]
        self.runtime = rt = get_runtime(device)
        self.K = len(meshes)
        layout = device_layout(rt.device)
        self.rows = layout["rows"] if rows is None else int(rows)
        self.lanes = layout["lanes"] if lanes is None else int(lanes)
        if self.rows < 1 or TS % self.rows:
            raise ValueError(f"rows={rows}: must divide the tile side {TS}")
        if self.lanes not in (1, 16):
            raise ValueError(f"lanes={lanes}: the setup takes 1 or 16 triangles a work-item")
        program = rt.program("ndrf_raster.cl", {"K": self.K, "TS": TS, "TROWS": self.rows,
                                                "LANES": self.lanes, "TRI_WORDS": TRI_WORDS})
        self._kernels = {n: program.kernel(n) for n in self.KERNELS}
        self._scan_items = scan_items(self._kernels["ndrf_raster_scan"], rt.device)
        meshes, orders = zip(*[spatially_ordered(v, f) for v, f in meshes])
        geometry = packed_geometry(meshes)
        geometry["face_ids"] = np.concatenate(orders)
        self.n_faces = int(geometry["face_start"][-1])
        mf = cl.mem_flags
        # A buffer of zero bytes is invalid: an empty mesh set still gets one element.
        self._geo = {name: cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                     hostbuf=np.ascontiguousarray(a) if a.size
                                     else np.zeros(3, a.dtype))
                     for name, a in geometry.items()}
        n = max(self.n_faces, 1)
        record = 4 * TRI_WORDS
        check_allocation(rt.device, f"raster triangle setup ({self.n_faces} faces)", record * n)
        self._setup = {"tri_geo": cl.Buffer(rt.context, mf.READ_WRITE, record * n),
                       "tri_box": cl.Buffer(rt.context, mf.READ_WRITE, 16 * n)}
        self._capacity = 0
        self.binned_pairs = 0        # (triangle, tile) pairs the last settled frame binned
        self._total = np.zeros(1, I32)   # the frame's pair count, read back without waiting
        self._total_read = None
        self._uploads: list = []
        self._events: list = []
        self._size = None
        self._bufs: dict = {}
        self._local: dict = {}

    @property
    def kernels(self) -> dict:
        """``{kernel name: cl.Kernel}`` of the program."""
        return dict(self._kernels)

    def launch_sizes(self, width: int, height: int) -> list[tuple[str, tuple[int, ...]]]:
        """The kernel launches of a ``width`` x ``height`` frame, in order (a frame binned
        again after an overflow repeats the last two): ``(kernel name, global work-items
        per axis before padding to the work-group size)``: setup one per :attr:`lanes`
        faces, scan one work-group (:func:`scan_items`), bin one a face, tile one per
        :attr:`rows` rows of a tile."""
        tiles_x, tiles_y, faces = -(-width // TS), -(-height // TS), max(self.n_faces, 1)
        return [("ndrf_raster_setup", (-(-faces // self.lanes),)),
                ("ndrf_raster_scan", (self._scan_items,)),
                ("ndrf_raster_bin", (faces,)),
                ("ndrf_raster_tile", (tiles_x, tiles_y * (TS // self.rows)))]

    @property
    def mode(self) -> str:
        """The layout, e.g. "16x16 tiles, 16 rows a work-item, 16 triangles a setup
        work-item"."""
        return (f"{TS}x{TS} tiles, {self.rows} row{'s' if self.rows > 1 else ''} a work-item, "
                f"{self.lanes} triangle{'s' if self.lanes > 1 else ''} a setup work-item")

    @property
    def capacity(self) -> int:
        """(triangle, tile) pairs the tile list holds: 0 before the first frame, then at
        least :data:`INITIAL_PAIRS`, grown when a frame overflows it."""
        return self._capacity

    def _frame_buffers(self, width: int, height: int) -> dict:
        if self._size != (width, height):
            n = self.K * width * height
            if n >= 2 ** 31:
                raise ValueError(f"{width}x{height} pixels x K={self.K} meshes: more hit slots "
                                 "than the rasteriser's int32 indices address")
            if height >= 2 ** 16:
                raise ValueError(f"{width}x{height} pixels: the rasteriser packs a triangle's "
                                 "rows in 16 bits, so an image has at most 65535 rows")
            n_tiles = -(-width // TS) * -(-height // TS)
            sizes = {"tri": 4 * n, "bary": 8 * n, "depth": 4 * n}
            ctx, mf = self.runtime.context, cl.mem_flags
            for name, nbytes in sizes.items():
                check_allocation(self.runtime.device, f"raster buffer '{name}' for "
                                 f"{width}x{height} pixels, K={self.K}", nbytes)
            self._bufs = {"cam": cl.Buffer(ctx, mf.READ_ONLY, CAM_BYTES),
                          "ray_ab": cl.Buffer(ctx, mf.READ_ONLY,
                                              4 * (-(-width // TS) * TS + height)),
                          # 0 between frames: the scan zeroes what the setup counted
                          "tile_count": cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR,
                                                  hostbuf=np.zeros(n_tiles, I32)),
                          "cursor": cl.Buffer(ctx, mf.READ_WRITE, 4 * n_tiles),
                          "tile_start": cl.Buffer(ctx, mf.READ_WRITE, 4 * (n_tiles + 1))}
            self._bufs.update({name: cl.Buffer(ctx, mf.READ_WRITE, max(nbytes, 4))
                               for name, nbytes in sizes.items()})
            self._size, self._n_tiles = (width, height), n_tiles
        return self._bufs

    def _list(self, capacity: int) -> None:
        """Grow the tile list to hold at least ``capacity`` entries."""
        if capacity > self._capacity:
            capacity = max(capacity, 2 * self._capacity, INITIAL_PAIRS)
            check_allocation(self.runtime.device, f"raster tile list ({capacity} entries)",
                             4 * capacity)
            self._list_buf = cl.Buffer(self.runtime.context, cl.mem_flags.READ_WRITE,
                                       4 * capacity)
            self._capacity = capacity

    def _run(self, name: str, shape: tuple[int, ...], *args) -> cl.Event:
        key = (name, shape)
        if key not in self._local:
            self._local[key] = work_group_size(self._kernels[name], self.runtime.device, shape)
        local = self._local[key]
        return self._kernels[name](self.runtime.queue, padded(shape, local), local, *args)

    def rasterise(self, camera) -> dict:
        """Hits of every pixel of ``camera`` on each mesh, enqueued and left on the device;
        nothing waits for the device. Call :meth:`settle` after the frame's first blocking
        read.

        Returns:
            device buffers ``tri`` (K, H, W) int32 (-1 on a miss), ``bary`` (K, H, W, 2)
            float32 Embree (u, v), ``depth`` (K, H, W) float32 along the unit ray (inf on
            a miss).
        """
        b, q = self._frame_buffers(camera.width, camera.height), self.runtime.queue
        g, s = self._geo, self._setup
        w, h = np.int32(camera.width), np.int32(camera.height)
        self._list(1)
        # pyopencl's event of a copy from the host keeps the host array alive and, when
        # dropped, waits for the copy: kept until settle().
        self._uploads = [cl.enqueue_copy(q, b["cam"], camera.packed(), is_blocking=False),
                         cl.enqueue_copy(q, b["ray_ab"], pixel_ray_ab(camera),
                                         is_blocking=False)]
        n_tiles = np.int32(self._n_tiles)
        size = dict(self.launch_sizes(camera.width, camera.height))
        scan = size["ndrf_raster_scan"]
        self._events = [
            self._run("ndrf_raster_setup", size["ndrf_raster_setup"], b["cam"], w, h,
                      np.int32(self.n_faces), g["face_start"], g["faces"], g["face_ids"],
                      g["vertices"], b["ray_ab"], s["tri_geo"], s["tri_box"], b["tile_count"]),
            self._kernels["ndrf_raster_scan"](q, scan, scan, n_tiles, b["tile_count"],
                                              b["tile_start"], b["cursor"],
                                              cl.LocalMemory(4 * scan[0]))]
        self._total_read = cl.enqueue_copy(q, self._total, b["tile_start"],
                                           src_offset=4 * int(n_tiles), is_blocking=False)
        self._events += self._bin_and_tile()
        return b

    def _bin_and_tile(self) -> list[cl.Event]:
        """Enqueue the bin and tile passes of the current frame into the current list."""
        b, s, (width, height) = self._bufs, self._setup, self._size
        w, h, capacity = np.int32(width), np.int32(height), np.int32(self._capacity)
        size = dict(self.launch_sizes(width, height))
        return [
            self._run("ndrf_raster_bin", size["ndrf_raster_bin"], w, np.int32(self.n_faces),
                      b["ray_ab"], s["tri_geo"], s["tri_box"], b["cursor"], capacity,
                      self._list_buf),
            self._run("ndrf_raster_tile", size["ndrf_raster_tile"], w, h,
                      b["ray_ab"], s["tri_geo"], b["tile_start"], capacity, self._list_buf,
                      b["tri"], b["bary"], b["depth"])]

    def settle(self) -> bool:
        """Finish the last :meth:`rasterise` after a blocking read enqueued behind it (the
        queue runs in order, so its pair count has arrived): :attr:`binned_pairs` set. If
        the pairs overflowed the list, the list is grown and the frame binned and tiled
        again (enqueued): returns True, and what was read from the hits must be read again.
        """
        self._total_read.wait()
        self._uploads = []
        self.binned_pairs = int(self._total[0])
        if self.binned_pairs <= self._capacity:
            return False
        self._list(self.binned_pairs)
        b = self._bufs
        # The bin pass advanced each tile's cursor to its end: back to its start.
        self._events.append(cl.enqueue_copy(self.runtime.queue, b["cursor"],
                                            b["tile_start"], byte_count=4 * self._n_tiles))
        self._events += self._bin_and_tile()
        return True

    def frame_ms(self) -> float:
        """The last frame's kernel time in milliseconds (both passes of a re-binned frame),
        to be read after the frame's final read (then it waits for nothing)."""
        return sum(event_ms(e) for e in self._events)

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
        hits = self.read_hits(camera)
        return self.read_hits(camera) if self.settle() else hits
