"""The OpenCL rasteriser (kernels/ndrf_raster.cl) against Embree (clrender/ndrf/hits.py),
and the NDRF renderer's two hit sources against each other.

Tolerances (stated, not tuned; tests/ndrf_hits_check.py says what "explained" means):
- the same triangle on >= 99.9% of the pixels either path covers, every disagreement
  explained: the pixel's float64 ray-triangle intersection on an edge of a triangle involved
  (barycentric margin 1e-5 / |cos|, the angle between ray and triangle), or two depths within
  1e-6 relative, or a ray starting on the triangle (a camera on the surface);
- where the triangles agree: barycentrics within 1e-4 and depth within 1e-5 relative for
  rays meeting the triangle at |cos| >= 0.1; at grazing angles, where the float32 ray itself
  moves the hit (both paths differ from the float64 hit by up to ~5e-4), within those
  bounds times 0.1 / |cos|; barycentrics also within 4 eps32 |origin - p0| / (h |cos|), h
  the triangle's smallest height (a small or thin triangle far from the camera: the float32 origin's rounding moves the
  hit by about that on either path); depth also within 1e-7 |origin| absolute (float32
  cannot place a hit more finely than the rounding of origin - vertex: a camera 1e-4 off
  the surface);
- rendered images: >= 50 dB PSNR between the raster and the Embree path (random and
  trained models); the shader's exact build within 1e-5 of the numpy reference on raster hits.
Both work layouts run: a whole tile a tile work-item and 16 triangles a setup work-item
(CPUs), a tile row and one triangle (GPUs); every layout gives the same hits bit for bit.
"""
from __future__ import annotations

import functools

import numpy as np
import pytest

from clrender.camera import Camera, generate_rays, look_at
from clrender.metrics import psnr
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.hits import HitCaster
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ndrf.raster_cl import GPU_LAYOUT, Rasteriser, morton_order
from clrender.ndrf.render import Renderer
from clrender.ndrf.shader_ref import shade_reference
from ndrf_hits_check import compare

AGREE = 0.999
BARY_TOL, DEPTH_RTOL, GOOD_COS = 1e-4, 1e-5, 0.1
IMAGE_DB = 50.0
THRESHOLDS = (1e-4, 1e-3, 1e-2, 5e-2)


@functools.lru_cache(maxsize=None)
def _model(K: int, seed: int = 0):
    return random_ndrf_model(NDRFConfig(thresholds=THRESHOLDS[:K]), seed=seed + K)


def _views(model) -> dict:
    """Cameras: orbit, close-up (triangles off screen), inside every mesh's box (triangles
    crossing the camera plane), between two meshes, grazing a silhouette (a narrow field of
    view along the tangent plane at the mesh's extreme x), on a vertex and just off one (touching the surface)."""
    vertices = model.mesh(0)[0].astype(np.float64)
    v, rim = vertices[17], vertices[np.argmax(vertices[:, 0])]
    return {
        "orbit": (0.9, look_at([2.2, -1.9, 1.1])),
        "close-up": (0.9, look_at([0.9, -0.8, 0.5])),
        "inside": (1.4, look_at([0.1, 0.05, -0.02], [1.0, 0.3, 0.2])),
        "between": (0.9, look_at([0.0, -0.75, 0.0], [0.5, 0.0, 0.2])),
        "grazing": (0.05, look_at(rim - [0.0, 3.0, 0.0], rim)),
        "on-vertex": (0.9, look_at(v, 0.2 * v + [0.3, 0.0, 0.0])),
        "off-vertex": (0.9, look_at(1.0001 * v, [0.0, 0.0, 0.5])),
    }


def _check_hits(meshes, camera, raster_hits, embree_hits, strict_agreement=True):
    o, d = generate_rays(camera)
    s = compare(meshes, o, d, raster_hits, embree_hits)
    assert s["unexplained"] == 0, s["unexplained"]
    if strict_agreement:
        assert s["agree"] >= AGREE * s["covered"], (s["agree"], s["covered"])
    scale = np.maximum(1.0, GOOD_COS / np.maximum(s["cos"], 1e-6))
    float32 = 4 * np.finfo(np.float32).eps * s["kappa"]
    assert np.all(s["bary_err"] <= np.maximum(BARY_TOL * scale, float32)), s["bary_err"].max()
    origin = float(np.abs(o[0, 0]).max())
    assert np.all(s["depth_rerr"] <= DEPTH_RTOL * scale + 1e-7 * origin / s["depth"]), \
        s["depth_rerr"].max()
    return s


@pytest.mark.parametrize("layout", [{"rows": 16, "lanes": 16}, GPU_LAYOUT], ids=["cpu", "gpu"])
@pytest.mark.parametrize("K", [1, 2, 3, 4])
def test_raster_matches_embree(K, layout, cl_platform):
    model = _model(K)
    meshes = [model.mesh(k)[:2] for k in range(K)]
    raster, caster = Rasteriser(model, **layout), HitCaster(model)
    for name, (fov, c2w) in _views(model).items():
        camera = Camera.from_fov(fov, 96, 72, c2w)
        s = _check_hits(meshes, camera, raster.hits(camera), caster.cast_camera(camera),
                        strict_agreement=name != "on-vertex")
        assert s["covered"] > 0, name


def test_layouts_agree_bit_for_bit(cl_platform):
    model = _model(3)
    for name in ("close-up", "inside"):
        camera = Camera.from_fov(0.9, 61, 47, _views(model)[name][1])
        a = Rasteriser(model, rows=16, lanes=16).hits(camera)
        for rows, lanes in ((1, 1), (4, 16), (16, 1)):
            b = Rasteriser(model, rows=rows, lanes=lanes).hits(camera)
            for x, y in ((a.tri, b.tri), (a.bary, b.bary), (a.depth, b.depth)):
                np.testing.assert_array_equal(x, y)


def test_morton_order_is_a_local_permutation():
    rng = np.random.default_rng(5)
    points = rng.uniform(-1.0, 1.0, (4096, 3))
    order = morton_order(points)
    assert np.array_equal(np.sort(order), np.arange(len(points)))
    # Consecutive points along the curve are close: the mean step is a small fraction of
    # the mean distance between random points (~1.4 here).
    step = np.linalg.norm(np.diff(points[order], axis=0), axis=1).mean()
    assert step < 0.25, step
    assert morton_order(np.zeros((0, 3))).shape == (0,)
    assert np.array_equal(np.sort(morton_order(np.ones((5, 3)))), np.arange(5))


def test_invalid_layout_is_refused():
    with pytest.raises(ValueError, match="rows=3: must divide the tile side 16"):
        Rasteriser(_model(1), rows=3)
    with pytest.raises(ValueError, match="lanes=8: the setup takes 1 or 16 triangles"):
        Rasteriser(_model(1), lanes=8)


def test_shared_edges_cover_each_pixel_once(cl_platform):
    # Two triangles sharing the diagonal of a square, a pixel centre exactly on it (the image
    # is 2x2 pixels looking straight down at the square; its diagonal passes through the
    # pixel centres (0.5, 0.5) and (1.5, 1.5)), and the same square split the other way.
    for faces in ([[0, 1, 2], [0, 2, 3]], [[0, 1, 3], [1, 2, 3]]):
        vertices = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
        camera = Camera(1.0, 1.0, 1.0, 1.0, 2, 2, look_at([0, 0, 1], [0, 0, 0], [0, 1, 0]))
        hits = Rasteriser([(vertices, np.array(faces, np.int32))]).hits(camera)
        assert (hits.tri[0] >= 0).all()
        # Each half alone covers a disjoint set of pixels, together all of them.
        covered = [Rasteriser([(vertices, np.array([f], np.int32))]).hits(camera).tri[0] >= 0
                   for f in faces]
        assert not (covered[0] & covered[1]).any() and (covered[0] | covered[1]).all()


def test_degenerate_triangles_and_empty_layer():
    rng = np.random.default_rng(3)
    base = rng.uniform(-0.5, 0.5, (3, 3)).astype(np.float32)
    vertices = np.concatenate([base, base[:1], base[:1] + [1e-6, 0, 0],
                               0.5 * (base[:1] + base[1:2]), base[:1] + [0.2, 1e-7, 0]])
    faces = np.array([[0, 1, 2], [0, 3, 0], [0, 3, 4], [0, 1, 5], [0, 6, 1]], np.int32)
    meshes = [(vertices, faces), (vertices, np.zeros((0, 3), np.int32))]
    camera = Camera.from_fov(0.9, 64, 48, look_at([0.3, -2.0, 0.8]))
    raster, caster = Rasteriser(meshes), HitCaster([meshes[0]])
    hits = raster.hits(camera)
    assert (hits.tri[1] == -1).all() and np.isinf(hits.depth[1]).all()
    assert set(np.unique(hits.tri[0])) <= {-1, 0, 2, 4}       # 1 and 3 have zero area
    one = type(hits)(hits.tri[:1], hits.bary[:1], hits.depth[:1])
    _check_hits(meshes[:1], camera, one, caster.cast_camera(camera))


@pytest.mark.parametrize("size", [(1, 1), (1, 7), (300, 2)])
def test_odd_image_sizes(size):
    model = _model(2)
    camera = Camera.from_fov(0.9, *size, _views(model)["close-up"][1])
    _check_hits([model.mesh(k)[:2] for k in range(2)], camera, Rasteriser(model).hits(camera),
                HitCaster(model).cast_camera(camera))


def test_renderer_hit_sources_agree_and_match_reference(cl_platform):
    model = _model(2)
    camera = Camera.from_fov(0.9, 80, 60, _views(model)["orbit"][1])
    raster = Renderer(model, hits="raster", exact=True).render(camera, stats=True)
    embree = Renderer(model, hits="embree", exact=True).render(camera, stats=True)
    assert psnr(raster["rgb"], embree["rgb"]) >= IMAGE_DB
    hits = Rasteriser(model).hits(camera)
    ref = shade_reference(model, hits.tri, hits.bary, generate_rays(camera)[1],
                          model.background)
    np.testing.assert_allclose(raster["rgb"], ref, rtol=0, atol=1e-5)
    assert set(raster) == set(embree) and {"ms_intersect", "ms_conv0", "ms_conv1"} <= set(raster)
    np.testing.assert_array_equal(raster["coverage"], embree["coverage"])
    fast = Renderer(model).render(camera)
    assert psnr(fast["rgb"], raster["rgb"]) >= IMAGE_DB


def test_large_image_renders_and_too_large_is_refused():
    model = _model(2)
    far = Camera.from_fov(0.05, 4096, 4096, look_at([30.0, -20.0, 10.0]))
    out = Renderer(model).render(far)
    assert out["rgb"].shape == (4096, 4096, 3) and 0 < (out["rgb"] != model.background).mean()
    # The smallest square image whose barycentrics buffer (8 bytes a pixel and mesh, the
    # largest) exceeds the device's largest allocation is refused naming that buffer; past
    # 2^31 hit slots the int32 indices refuse it first. (PoCL sizes its allocation limit
    # from the memory free when it starts, so the side is computed, not fixed.)
    renderer = Renderer(model)
    limit = renderer.runtime.device.max_mem_alloc_size
    side = int(np.sqrt(limit / (8 * 2))) + 1
    huge = Camera.from_fov(0.9, side, side, look_at([3.0, -2.0, 1.0]))
    expected = (rf"buffer 'bary' for {side}x{side} pixels.*: needs" if 2 * side * side < 2 ** 31
                else "more hit slots than the rasteriser's int32 indices address")
    with pytest.raises(ValueError, match=expected):
        renderer.render(huge)
    # A triangle's rows are packed in 16 bits: 2^16 rows are refused, whatever the width.
    tall = Camera.from_fov(0.9, 1, 2 ** 16, look_at([3.0, -2.0, 1.0]))
    with pytest.raises(ValueError, match="at most 65535 rows"):
        renderer.render(tall)


def test_unknown_hit_source_is_refused():
    with pytest.raises(ValueError, match="option 'hits' is 'gl'"):
        Renderer(_model(1), hits="gl")


@pytest.mark.slow
def test_trained_student_raster_matches_embree(tiny_ndrf_student):
    from clrender.data import load_dataset
    from clrender.ndrf.baked import load_baked

    model = load_baked(tiny_ndrf_student["student"])
    meshes = [model.mesh(k)[:2] for k in range(model.config.K)]
    raster, embree = Renderer(model, exact=True), Renderer(model, hits="embree", exact=True)
    cameras = load_dataset(tiny_ndrf_student["scene"], "test").cameras
    for camera in cameras + [c.scaled_to(97, 83) for c in cameras]:
        _check_hits(meshes, camera, raster.rasteriser.hits(camera),
                    embree.caster.cast_camera(camera))
        assert psnr(raster.render(camera)["rgb"], embree.render(camera)["rgb"]) >= IMAGE_DB


def test_embree_on_threads_equals_one_thread(monkeypatch):
    from clrender.ndrf import hits as hits_module

    monkeypatch.setattr(hits_module, "MIN_CHUNK", 1000)      # several chunks a mesh
    model = _model(2)
    camera = Camera.from_fov(0.9, 96, 72, _views(model)["orbit"][1])
    one, many = HitCaster(model, threads=1), HitCaster(model, threads=3)
    a, b = one.cast_camera(camera), many.cast_camera(camera)
    for x, y in ((a.tri, b.tri), (a.bary, b.bary), (a.depth, b.depth)):
        np.testing.assert_array_equal(x, y)
