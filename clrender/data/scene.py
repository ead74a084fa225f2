"""Built-in scenes: textured meshes ray cast with Embree into a Blender-format folder.

Several objects (sphere, box, torus, cylinder, a tree of thin twigs) on a slab, with solid
procedural textures evaluated at the 3D hit point (checker, wavy stripes, spots, blotches, and
fine grain), Blinn-Phong shading with specular highlights and shadows cast towards one
directional light, 8x8 supersampling (:data:`SUPERSAMPLE`).

* ``bounded``: everything inside [-0.9, 0.9]^3, cameras on the upper hemisphere (radius 3.0,
  40° field of view), RGBA images whose alpha is the coverage.
* ``unbounded``: the same objects shrunk into [-0.6, 0.6]^3 on a ground plane (42 x 42), a
  ring of tall blocks at distances 4-15 and a sky sphere (radius 30); cameras on a ring of radius
  1.0-1.3 look inward; every pixel hits something (RGB images).

Everything is drawn from ``np.random.default_rng(seed)`` and computed element-wise in numpy, so
a seed gives the same bytes on every run.
"""
from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from tqdm import tqdm

from ..atomic import atomic_write
from ..camera import Camera, look_at

F32 = np.float32
CHECKER, STRIPES, SPOTS, BLOTCHES = range(4)
LIGHT = (np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])).astype(F32)
# Saturated albedos, none near white, so near-white pixels come from highlights only.
PALETTE = np.array([[0.85, 0.15, 0.1], [0.1, 0.45, 0.85], [0.95, 0.7, 0.1], [0.15, 0.65, 0.25],
                    [0.6, 0.2, 0.7], [0.95, 0.45, 0.1], [0.1, 0.7, 0.7], [0.8, 0.2, 0.5],
                    [0.25, 0.2, 0.15], [0.5, 0.75, 0.2], [0.2, 0.25, 0.6], [0.55, 0.35, 0.2]], F32)
# Rays per pixel side (a box filter over the pixel). The finest grain and the checker edges
# lie above a 200x200 view's Nyquist rate, so fewer rays left aliasing that differs from
# view to view, which no 3D model can fit, and capped every method's test PSNR
# (docs/results.md, "The built-in scene").
SUPERSAMPLE = 8
AMBIENT = 0.25
# Views rendered at once hold at most this many rays (~0.4 GB each 2.56M, a 200x200 view).
RAYS_AT_ONCE = 4 * 200 * 200 * SUPERSAMPLE ** 2


@dataclass
class _Scene:
    """Merged triangle mesh with per-face materials, its Embree scene and the sky."""

    vertices: np.ndarray   # (V, 3) float32
    faces: np.ndarray      # (F, 3) int64
    normals: np.ndarray    # (V, 3) float32 smooth-shaded vertex normals
    face_mat: np.ndarray   # (F,) int64 material index
    mats: dict             # name -> (M, ...) per-material arrays
    waves: np.ndarray      # (4, K) float32 noise bank: direction xyz, phase
    amps: np.ndarray       # (K,) float32 noise octave weights
    embree: object         # Embree scene of all triangles
    sky_radius: float      # rays missing every mesh end on this sphere (0: no sky)


def make_scene(kind: str, out_dir, seed: int = 0, n_train: int = 100, n_test: int = 20,
               width: int = 200, height: int = 200) -> Path:
    """Render a built-in scene to a Blender-format folder and return its path.

    Writes ``transforms_{train,val,test}.json`` (val = test) with a ``"clrender"`` key,
    :func:`scene_key` (scene kind, scale, seed, supersampling), and ``{train,test}/r_000.png`` images
    (RGBA for ``bounded``, RGB for ``unbounded``), ``width`` x ``height`` pixels.
    """
    if kind not in ("bounded", "unbounded"):
        raise ValueError(f"scene kind must be 'bounded' or 'unbounded', got {kind!r}")
    rng = np.random.default_rng(seed)
    scene = _build(kind, rng)
    fov = np.deg2rad(40.0 if kind == "bounded" else 55.0)
    views = {"train": _poses(kind, rng, n_train, spread=True),
             "test": _poses(kind, rng, n_test, spread=False)}
    out = Path(out_dir)
    bar = tqdm(total=n_train + n_test, desc=f"rendering {kind} scene", unit="view")
    # Views render on threads (Embree and numpy release the GIL); each view's bytes do not
    # depend on the others, so the folder is the same as one thread's.
    threads = max(1, min(len(os.sched_getaffinity(0)),
                         RAYS_AT_ONCE // (width * height * SUPERSAMPLE ** 2)))
    with ThreadPoolExecutor(threads) as pool:
        for split, poses in views.items():
            (out / split).mkdir(parents=True, exist_ok=True)
            cams = [Camera.from_fov(fov, width, height, c2w) for c2w in poses]
            frames = []
            for i, (rgba, c2w) in enumerate(zip(pool.map(partial(_render, scene), cams), poses)):
                img = rgba if kind == "bounded" else rgba[..., :3]
                atomic_write(out / split / f"r_{i:03d}.png",
                             lambda f, img=img: iio.imwrite(f, img, extension=".png"))
                frames.append({"file_path": f"./{split}/r_{i:03d}",
                               "transform_matrix": np.round(c2w, 12).tolist()})
                bar.update()
            meta = {"camera_angle_x": float(fov), "w": width, "h": height, "frames": frames,
                    "clrender": scene_key(kind, seed)}
            text = json.dumps(meta, indent=2)
            for name in (split, "val") if split == "test" else (split,):
                atomic_write(out / f"transforms_{name}.json",
                             lambda f, t=text: Path(f).write_text(t))
    bar.close()
    return out


def scene_key(kind: str, seed: int) -> dict:
    """The ``"clrender"`` key of a built-in scene's transforms: what generated its images."""
    return {"scene": kind, "scale": 1.0, "seed": seed, "supersample": SUPERSAMPLE}


def _poses(kind: str, rng, n: int, spread: bool) -> list[np.ndarray]:
    """``n`` camera-to-world matrices; ``spread`` places them on a jittered golden spiral."""
    u = (np.arange(n) + rng.uniform(0.2, 0.8, n)) / max(n, 1) if spread else rng.uniform(0, 1, n)
    golden = np.pi * (3.0 - np.sqrt(5.0))
    az = np.arange(n) * golden + rng.uniform(0, 2 * np.pi) if spread \
        else rng.uniform(0, 2 * np.pi, n)
    if kind == "bounded":
        el = np.arcsin(np.sin(np.deg2rad(8.0)) + u * (np.sin(np.deg2rad(75.0))
                                                      - np.sin(np.deg2rad(8.0))))
        eyes = 3.0 * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
        return [look_at(e) for e in eyes]
    r = rng.uniform(1.0, 1.3, n)
    eyes = np.stack([r * np.cos(az), r * np.sin(az), -0.12 + 0.5 * u], -1)
    targets = rng.uniform(-0.06, 0.06, (n, 3)) + [0.0, 0.0, -0.12]
    return [look_at(e, t) for e, t in zip(eyes, targets)]


# -- geometry ------------------------------------------------------------------------------

def _material(rng, pattern: int, freq: float, ks: float, shininess: float) -> dict:
    a, b = PALETTE[rng.choice(len(PALETTE), 2, replace=False)]
    return {"a": a, "b": b, "pattern": pattern, "freq": freq, "ks": ks, "shininess": shininess}


def _placed(mesh: trimesh.Trimesh, offset, angle: float = 0.0) -> trimesh.Trimesh:
    """``mesh`` rotated by ``angle`` about z, then moved by ``offset``."""
    t = trimesh.transformations.rotation_matrix(angle, [0, 0, 1])
    t[:3, 3] = offset
    return mesh.apply_transform(t)


def _twigs(rng, base, scale: float) -> list[trimesh.Trimesh]:
    """A little tree of thin cylinders (radius 0.02 down to 0.01, times ``scale``)."""
    parts, stack = [], [(np.asarray(base, float), np.array([0.0, 0.0, 1.0]), 0.42, 0)]
    while stack:
        p, d, length, depth = stack.pop()
        q = p + d * length * scale
        radius = (0.02 - 0.004 * depth) * scale
        parts.append(trimesh.creation.cylinder(radius, segment=[p, q], sections=8))
        if depth < 3:
            for k in range(2 + (depth == 0)):
                tilt, turn = rng.uniform(0.5, 0.9), rng.uniform(0, 2 * np.pi)
                axis = np.array([np.cos(turn), np.sin(turn), 0.0])
                nd = np.cos(tilt) * d + np.sin(tilt) * np.cross(axis, d)
                nd[2] = abs(nd[2]) + 0.2
                stack.append((q, nd / np.linalg.norm(nd), length * 0.62, depth + 1))
    return parts


def _objects(rng, s: float, ground: float) -> list[tuple[trimesh.Trimesh, dict]]:
    """The central objects: sizes and positions times ``s``, standing on z = ``ground``."""
    j = lambda x, y: np.array([x, y]) * s + rng.uniform(-0.03, 0.03, 2) * s  # noqa: E731
    torus = trimesh.creation.torus(0.22 * s, 0.07 * s, major_sections=48, minor_sections=16)
    torus.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    objs = [
        (trimesh.creation.box([1.7 * s, 1.7 * s, 0.1 * s]), (0, 0, ground - 0.05 * s), 0.0,
         _material(rng, CHECKER, 10.0 / s, 0.15, 20.0)),
        (trimesh.creation.icosphere(4, 0.28 * s), (*j(-0.4, -0.35), ground + 0.28 * s), 0.0,
         _material(rng, STRIPES, 4.0 / s, 1.0, 40.0)),
        (trimesh.creation.box([0.36 * s] * 3), (*j(0.4, -0.35), ground + 0.18 * s),
         rng.uniform(0, np.pi), _material(rng, SPOTS, 12.0 / s, 0.5, 40.0)),
        (torus, (*j(0.35, 0.38), ground + 0.3 * s), rng.uniform(0, np.pi),
         _material(rng, BLOTCHES, 5.0 / s, 0.9, 50.0)),
        (trimesh.creation.cylinder(0.14 * s, 0.55 * s, sections=64),
         (*j(-0.4, 0.4), ground + 0.275 * s), 0.0, _material(rng, CHECKER, 14.0 / s, 0.6, 50.0)),
        (trimesh.creation.icosphere(3, 0.1 * s), (*j(0.0, -0.62), ground + 0.1 * s), 0.0,
         _material(rng, BLOTCHES, 9.0 / s, 1.0, 60.0)),
    ]
    out = [(_placed(m, off, ang), mat) for m, off, ang, mat in objs]
    twig_mat = _material(rng, STRIPES, 25.0 / s, 0.4, 30.0)
    out += [(m, twig_mat) for m in _twigs(rng, (0.02 * s, 0.05 * s, ground), s)]
    return out


def _surroundings(rng, ground: float) -> list[tuple[trimesh.Trimesh, dict]]:
    """Unbounded extras: ground plane, a ring of tall blocks and pillars."""
    # Subdivided so that Embree's boxes stay tight (one huge quad slows every ray down).
    plane = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(
        [[-21, -21, 0], [21, -21, 0], [21, 21, 0], [-21, 21, 0]], [[0, 1, 2], [0, 2, 3]], 1.5))
    out = [(_placed(plane, (0, 0, ground)), _material(rng, CHECKER, 1.5, 0.2, 20.0))]
    for k in range(28):
        az, dist = 2 * np.pi * (k + rng.uniform(0, 0.6)) / 28, rng.uniform(4.0, 15.0)
        h = rng.uniform(1.0, 6.0)
        mesh = trimesh.creation.box([rng.uniform(0.5, 2.0), rng.uniform(0.5, 2.0), h]) \
            if k % 2 else trimesh.creation.cylinder(rng.uniform(0.3, 1.0), h, sections=32)
        pattern = (CHECKER, STRIPES, SPOTS, BLOTCHES)[k % 4]
        out.append((_placed(mesh, (dist * np.cos(az), dist * np.sin(az), ground + h / 2),
                            rng.uniform(0, np.pi)),
                    _material(rng, pattern, rng.uniform(1.0, 3.0), 0.4, 30.0)))
    return out


def _embree(vertices: np.ndarray, faces: np.ndarray):
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, np.ascontiguousarray(vertices[faces], dtype=F32))
    return scene


def _build(kind: str, rng) -> _Scene:
    """Lay out the meshes of ``kind``, merge them and build the Embree scenes."""
    if kind == "bounded":
        parts = _objects(rng, 1.0, -0.5)
    else:
        parts = _objects(rng, 0.6, -0.3) + _surroundings(rng, -0.3)
    names = ("a", "b", "pattern", "freq", "ks", "shininess")
    mat_index, verts, faces, norms, face_mat = {}, [], [], [], []
    offset = 0
    for mesh, mat in parts:
        index = mat_index.setdefault(id(mat), (len(mat_index), mat))[0]
        # Split vertices along sharp edges: smooth normals on curves, flat box faces.
        smooth = trimesh.graph.smooth_shade(mesh, angle=np.deg2rad(35.0))
        verts.append(smooth.vertices)
        norms.append(smooth.vertex_normals)
        faces.append(smooth.faces + offset)
        face_mat.append(np.full(len(smooth.faces), index))
        offset += len(smooth.vertices)
    v, f, fm = np.concatenate(verts).astype(F32), np.concatenate(faces), np.concatenate(face_mat)
    mats = {k: np.array([m[k] for _, m in mat_index.values()]) for k in names}
    n_waves = 32
    octave = np.repeat(2.0 ** np.arange(4), n_waves // 4)
    dirs = rng.normal(size=(n_waves, 3))
    dirs *= (octave * 2 * np.pi / np.linalg.norm(dirs, axis=1))[:, None]
    waves = np.concatenate([dirs.T, rng.uniform(0, 2 * np.pi, (1, n_waves))]).astype(F32)
    return _Scene(v, f, np.concatenate(norms).astype(F32), fm, mats, waves,
                  (1.0 / octave).astype(F32), _embree(v, f), 0.0 if kind == "bounded" else 30.0)


# -- shading -------------------------------------------------------------------------------

def _render(scene: _Scene, cam: Camera) -> np.ndarray:
    """(H, W, 4) uint8 RGBA (straight alpha = coverage) of ``cam``, SUPERSAMPLE^2 rays a pixel."""
    n, h, w = SUPERSAMPLE, cam.height, cam.width
    x = (np.arange(w * n, dtype=F32) + F32(0.5)) / F32(n)
    y = (np.arange(h * n, dtype=F32) + F32(0.5)) / F32(n)
    a = np.broadcast_to((x[None, :] - F32(cam.cx)) / F32(cam.fx), (h * n, w * n))
    b = np.broadcast_to(-(y[:, None] - F32(cam.cy)) / F32(cam.fy), (h * n, w * n))
    R = cam.c2w[:3, :3].astype(F32)
    d = np.stack([R[i, 0] * a + R[i, 1] * b - R[i, 2] for i in range(3)], -1).reshape(-1, 3)
    d /= np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])[:, None]
    o = np.broadcast_to(cam.origin.astype(F32), d.shape).copy()
    rgb, hit = _shade(scene, o, d)
    rgb = (rgb * hit[:, None]).reshape(h, n, w, n, 3)
    hit = hit.astype(F32).reshape(h, n, w, n)
    # Explicit sums in a fixed order keep the output bit-reproducible.
    premult, alpha = np.zeros((h, w, 3), F32), np.zeros((h, w), F32)
    for i in range(n):
        for j in range(n):
            premult += rgb[:, i, :, j]
            alpha += hit[:, i, :, j]
    straight = premult / np.maximum(alpha, F32(1e-6))[..., None]
    rgba = np.concatenate([straight, (alpha / F32(n * n))[..., None]], -1)
    return np.round(np.clip(rgba, 0.0, 1.0) * 255.0).astype(np.uint8)


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1] + u[..., 2] * v[..., 2]


def _shade(scene: _Scene, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Colour (R, 3) float32 and hit mask (R,) bool of rays ``o``, ``d`` (R, 3) float32."""
    hit = scene.embree.run(o, d, output=1)
    ok = hit["primID"] >= 0
    rgb = np.zeros(o.shape, F32)
    rgb[ok] = _surface(scene, o[ok] + d[ok] * hit["tfar"][ok][:, None], d[ok], hit["primID"][ok],
                       hit["u"][ok][:, None], hit["v"][ok][:, None])
    if scene.sky_radius:
        # Analytic sky sphere around the origin; its texture is fixed to the sphere (parallax).
        om, dm = o[~ok], d[~ok]
        b = _dot(om, dm)
        t = -b + np.sqrt(b * b - _dot(om, om) + F32(scene.sky_radius ** 2))
        rgb[~ok] = _sky(scene, (om + dm * t[:, None]) / F32(scene.sky_radius))
        ok = np.ones_like(ok)
    return rgb, ok


def _surface(scene: _Scene, p, d, prim, u, v) -> np.ndarray:
    """Blinn-Phong colour (K, 3) at hits ``p`` (K, 3) of triangles ``prim`` (barycentrics u, v)."""
    fv, N = scene.faces[prim], scene.normals
    nrm = (1 - u - v) * N[fv[:, 0]] + u * N[fv[:, 1]] + v * N[fv[:, 2]]
    nrm /= np.sqrt(_dot(nrm, nrm))[:, None]
    nrm *= np.where(_dot(nrm, d) > 0, F32(-1), F32(1))[:, None]
    mat = scene.face_mat[prim]
    ndl = _dot(nrm, LIGHT)
    sun = np.flatnonzero(ndl > 0)
    light = np.zeros(len(p), F32)
    rays = np.ascontiguousarray(np.broadcast_to(LIGHT, (len(sun), 3)))
    light[sun] = scene.embree.run(p[sun] + nrm[sun] * F32(1e-3), rays, query="OCCLUDED") == -1
    half = LIGHT - d
    half /= np.sqrt(_dot(half, half))[:, None]
    ks, shininess = scene.mats["ks"][mat].astype(F32), scene.mats["shininess"][mat].astype(F32)
    spec = ks * np.maximum(_dot(nrm, half), 0) ** shininess * light
    shade = AMBIENT + (1 - AMBIENT) * np.maximum(ndl, 0) * light
    return _albedo(scene, p, mat) * shade[:, None] + spec[:, None]


def _fbm(scene: _Scene, x: np.ndarray) -> np.ndarray:
    """Band-limited noise at (K, 3) points, four octaves from base frequency 1: (K,) in [0, 1]."""
    w, s = scene.waves, np.zeros(len(x), F32)
    for k in range(w.shape[1]):
        s += scene.amps[k] * np.sin(x[:, 0] * w[0, k] + x[:, 1] * w[1, k] + x[:, 2] * w[2, k]
                                    + w[3, k])
    std = np.sqrt(0.5 * np.sum(scene.amps.astype(np.float64) ** 2))
    return np.clip(0.5 + s / F32(4.0 * std), 0.0, 1.0)


def _smooth(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _albedo(scene: _Scene, p: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """Solid-texture albedo (K, 3) float32 at hit points ``p`` (K, 3) of materials ``mat``."""
    m = scene.mats
    pattern, q = m["pattern"][mat], p * m["freq"][mat].astype(F32)[:, None]
    t = np.zeros(len(p), F32)
    for kind in np.unique(pattern):
        sel = pattern == kind
        qs = q[sel]
        if kind == CHECKER:
            t[sel] = np.floor(qs).astype(np.int64).sum(1) & 1
        elif kind == STRIPES:
            t[sel] = _smooth(0.5 + 2 * np.sin(2 * np.pi * qs[:, 2] + 8 * _fbm(scene, 0.3 * qs)))
        elif kind == SPOTS:
            f = qs - np.floor(qs) - F32(0.5)
            t[sel] = _smooth((F32(0.34) - np.sqrt(_dot(f, f))) * 20)
        elif kind == BLOTCHES:
            t[sel] = _smooth((_fbm(scene, 0.5 * qs) - 0.5) * 5 + 0.5)
    a, b = m["a"][mat].astype(F32), m["b"][mat].astype(F32)
    colour = a + (b - a) * t[:, None]
    grain = F32(0.75) + F32(0.5) * _fbm(scene, q * F32(0.5))
    return colour * grain[:, None]


def _sky(scene: _Scene, d: np.ndarray) -> np.ndarray:
    """Sky colour (K, 3) at unit sphere points ``d`` (K, 3): gradient, clouds and far hills."""
    horizon, zenith = np.array([0.55, 0.7, 0.9], F32), np.array([0.15, 0.3, 0.7], F32)
    el = np.clip(d[:, 2], 0.0, 1.0)[:, None]
    colour = horizon + (zenith - horizon) * np.sqrt(el)
    clouds = _smooth((_fbm(scene, d * F32(2.5)) - 0.5) * 4)[:, None] * np.sqrt(el)
    colour = colour + (F32(0.85) - colour) * clouds
    flat = d * np.array([3.0, 3.0, 0.0], F32)
    hills = 0.04 + 0.12 * _fbm(scene, flat)
    rock = np.array([0.3, 0.45, 0.2], F32) + np.array([0.25, 0.1, 0.0], F32) * \
        _fbm(scene, d * F32(40.0))[:, None]
    return np.where((d[:, 2] < hills)[:, None], rock, colour)
