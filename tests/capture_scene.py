"""A small textured scene for the capture tests, ray cast in numpy: the inside corner of a
box (a floor and two walls, each 2 x 2 world units) covered in multi-scale colour noise,
which gives SIFT blobs at every scale, seen by cameras on an arc looking into the corner."""
import numpy as np
from scipy.ndimage import map_coordinates, zoom

from clrender.camera import look_at

TEXTURE = 256            # texels per plane side
FOCAL_FRACTION = 1.0     # focal length in units of the image width (about 53° field of view)
# (origin, u axis, v axis) of each textured square, u and v spanning 2 world units each.
PLANES = (((-1.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),   # floor z = 0
          ((-1.0, -1.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),   # wall x = -1
          ((-1.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))   # wall y = -1
TARGET = np.array([-0.3, -0.3, 0.5])


def noise_texture(rng) -> np.ndarray:
    """(TEXTURE, TEXTURE, 3) float in [0, 1]: random grids of 4 to 64 cells, summed."""
    tex = np.zeros((TEXTURE, TEXTURE, 3))
    for cells in (4, 8, 16, 32, 64):
        grid = rng.uniform(-1, 1, (cells, cells, 3))
        tex += zoom(grid, (TEXTURE / cells, TEXTURE / cells, 1), order=3)[:TEXTURE, :TEXTURE]
    tex -= tex.min()
    return tex / tex.max()


def arc_poses(n: int, radius: float = 3.2) -> np.ndarray:
    """(n, 4, 4) NeRF c2w on an arc in front of the corner, each looking at TARGET."""
    az = np.deg2rad(np.linspace(15.0, 75.0, n))
    el = np.deg2rad(30.0 + 8.0 * np.sin(np.linspace(0, np.pi, n)))
    eyes = TARGET + radius * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                       np.sin(el)], -1)
    return np.stack([look_at(e, TARGET) for e in eyes])


def render_corner(c2w: np.ndarray, size: int, textures) -> np.ndarray:
    """(size, size, 3) uint8 view of the corner from NeRF c2w (4, 4), pixel centres +0.5."""
    f = FOCAL_FRACTION * size
    j, i = np.mgrid[0:size, 0:size] + 0.5
    dirs = np.stack([(i - size / 2) / f, -(j - size / 2) / f, -np.ones_like(i)], -1)
    d = dirs @ c2w[:3, :3].T
    o = c2w[:3, 3]
    best, rgb = np.full(d.shape[:2], np.inf), np.ones(d.shape)
    for (origin, u, v), tex in zip(PLANES, textures):
        origin, u, v = map(np.asarray, (origin, u, v))
        n = np.cross(u, v)
        t = ((origin - o) @ n) / np.where(np.abs(d @ n) < 1e-9, 1e-9, d @ n)
        p = o + t[..., None] * d - origin
        a, b = p @ u / 2.0, p @ v / 2.0          # plane coordinates in [0, 1]
        hit = (t > 0) & (t < best) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        coords = [b[hit] * (TEXTURE - 1), a[hit] * (TEXTURE - 1)]
        rgb[hit] = np.stack([map_coordinates(tex[..., c], coords, order=1) for c in range(3)], -1)
        best = np.where(hit, t, best)
    return (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)


def corner_views(n: int, size: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """(images (n, size, size, 3) uint8, NeRF c2w (n, 4, 4), focal in pixels)."""
    rng = np.random.default_rng(seed)
    textures = [noise_texture(rng) for _ in PLANES]
    poses = arc_poses(n)
    return np.stack([render_corner(p, size, textures) for p in poses]), poses, \
        FOCAL_FRACTION * size
