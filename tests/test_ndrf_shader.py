"""The NDRF shader: OpenCL kernels (kernels/ndrf_shade.cl) against the numpy reference
(clrender/ndrf/shader_ref.py), and the reference against torch.

Random models (clrender.ndrf.random_model) with K = 1, 2, 3 meshes and kernel_size 2 and 1,
hits from Embree, orbit cameras at radius ~3, odd image sizes; PoCL on the CPU.
Tolerances (stated, not tuned):
- rgb, kernel vs reference: max abs 1e-5 (sin/cos/exp differ by a few ulps between the
  OpenCL builtins and numpy; sums run in different orders).
- screen buffer (what conv0 gathers), kernel vs reference: features and hit positions
  bit-identical (same float32 operations in the same order), view encoding within 1e-6.
- the fast build (the tabulated view channels, native exp) against the exact one: >= 50 dB
  PSNR, in the GPU layout (one pixel a conv0 work-item), blocks of 3 x 5 and the device's
  own layout.
- reference conv shader vs torch.nn.functional.conv2d in float64: max abs 1e-5.
- uncovered pixels: exactly the background.
"""
from __future__ import annotations

import functools

import numpy as np
import pytest

from clrender.camera import Camera, generate_rays, look_at
from clrender.ndrf.baked import validate
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.hits import HitCaster
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ndrf.shader_cl import GPU_LAYOUT, Shader
from clrender.ndrf.shader_cl import kernel_defines
from clrender.ndrf.shader_ref import _conv, conv0_factored, conv_shader, screen_buffer, \
    shade_reference, vertex_projections, view_encoding, view_weights

RGB_ATOL = 1e-5
VIEW_ATOL = 1e-6
TORCH_ATOL = 1e-5
THRESHOLDS = (1e-4, 1e-3, 1e-2, 5e-2)


@functools.lru_cache(maxsize=None)
def _model(K: int, kernel_size: int, seed: int = 0):
    config = NDRFConfig(thresholds=THRESHOLDS[:K], kernel_size=kernel_size)
    return random_ndrf_model(config, seed=seed + 10 * K + kernel_size)


@functools.lru_cache(maxsize=None)
def _shader(K: int, kernel_size: int) -> Shader:
    return Shader(_model(K, kernel_size), exact=True)


def _orbit(azimuth_deg: float, elevation_deg: float, radius: float = 3.0, target=(0, 0, 0)):
    az, el = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    eye = radius * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return look_at(eye, target)


# (width, height, c2w): the mesh inside the image with misses around it; the mesh
# crossing the image border (target off centre); a wider, closer view.
VIEWS = [
    (37, 23, _orbit(30.0, 20.0)),
    (23, 37, _orbit(200.0, -35.0, 3.0, target=(0.55, -0.4, 0.3))),
    (32, 29, _orbit(110.0, 60.0, 2.5)),
]


def _inputs(model, width: int, height: int, c2w):
    camera = Camera.from_fov(0.8, width, height, c2w)
    hits = HitCaster(model).cast_camera(camera)
    _, dirs = generate_rays(camera)
    return camera, hits, dirs


@pytest.mark.parametrize("kernel_size", [2, 1])
@pytest.mark.parametrize("K", [1, 2, 3])
def test_shade_matches_reference(K, kernel_size, cl_platform):
    model, shader = _model(K, kernel_size), _shader(K, kernel_size)
    background = (0.2, 0.7, 0.4)
    for width, height, c2w in VIEWS:
        camera, hits, dirs = _inputs(model, width, height, c2w)
        coverage = hits.coverage
        assert 0.1 < coverage.mean() < 0.95, "test view should hold hits and misses"
        rgb, ms = shader.shade(camera, hits.tri, hits.bary, background)
        ref = shade_reference(model, hits.tri, hits.bary, dirs, background)
        assert rgb.shape == (height, width, 3) and rgb.dtype == np.float32
        np.testing.assert_allclose(rgb, ref, rtol=0, atol=RGB_ATOL)
        np.testing.assert_array_equal(rgb[~coverage], np.broadcast_to(
            np.float32(background), rgb[~coverage].shape))
        assert set(ms) == {"ms_conv0", "ms_conv1"}
        assert all(v >= 0.0 for v in ms.values())


# Organisations of conv0 (kernel_defines): GPU-style one pixel per work-item, AVX2-style
# float8 and AVX-512-style float16 on 8 x 4 blocks, blocks of sizes dividing no image side;
# model shapes whose hidden width is not a whole vector (20) and is several (48), and view
# encodings of 7 frequencies (two float16 chunks).
LAYOUTS = [{"H_VEC": 8, "SEG": 1, "ROWS": 1}, {"H_VEC": 8, "SEG": 8, "ROWS": 4},
           {"H_VEC": 16, "SEG": 8, "ROWS": 4}, {"H_VEC": 8, "SEG": 3, "ROWS": 5}]
SHAPES = [dict(thresholds=THRESHOLDS, hidden=20, n_freq=7, kernel_size=2),
          dict(thresholds=THRESHOLDS[:2], hidden=48, n_freq=3, kernel_size=1),
          dict(thresholds=THRESHOLDS[:1], hidden=48, n_freq=0, kernel_size=2)]


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("layout", LAYOUTS)
def test_other_shapes_and_layouts_match_reference(monkeypatch, layout, shape, cl_platform):
    from clrender.ndrf import shader_cl

    monkeypatch.setattr(shader_cl, "device_layout", lambda device: dict(layout))
    model = random_ndrf_model(NDRFConfig(**shape), seed=7)
    shader = Shader(model, exact=True)
    assert shader.defines["H_VEC"] == layout["H_VEC"]
    camera, hits, dirs = _inputs(model, *VIEWS[1])
    rgb, _ = shader.shade(camera, hits.tri, hits.bary)
    ref = shade_reference(model, hits.tri, hits.bary, dirs, model.background)
    np.testing.assert_allclose(rgb, ref, rtol=0, atol=RGB_ATOL)


def test_view_crossing_the_border_reaches_it():
    # The second view must put covered pixels on the image border, where conv reads fall
    # outside the image.
    _, hits, _ = _inputs(_model(2, 2), *VIEWS[1])
    c = hits.coverage
    assert c[0].any() or c[-1].any() or c[:, 0].any() or c[:, -1].any()


@pytest.mark.parametrize("kernel_size", [2, 1])
def test_screen_buffer_matches_reference(kernel_size, cl_platform):
    model, shader = _model(2, kernel_size), _shader(2, kernel_size)
    for width, height, c2w in VIEWS:
        camera, hits, dirs = _inputs(model, width, height, c2w)
        out = shader.screen_buffer(camera, hits.tri, hits.bary)
        ref = screen_buffer(model, hits.tri, hits.bary, dirs)
        assert out.shape == ref.shape == (height, width, model.config.c_in)
        n_geo = 11 * model.config.K
        np.testing.assert_array_equal(out[..., :n_geo], ref[..., :n_geo])
        np.testing.assert_allclose(out[..., n_geo:], ref[..., n_geo:], rtol=0, atol=VIEW_ATOL)


# The view table lookups of a conv0 row, SEG + KSIZE - 1 pixels, run 1 (GPU layout,
# kernel_size 1), 2, 4 (SEG = 3), 8 and 16 (the CPU layouts' SEG = 8) lanes wide.
@pytest.mark.parametrize("layout", [GPU_LAYOUT, {"H_VEC": 8, "SEG": 3, "ROWS": 5}, None],
                         ids=["gpu", "seg3", "device"])
@pytest.mark.parametrize("kernel_size", [2, 1])
def test_fast_build_within_50_db_of_exact(kernel_size, layout, cl_platform):
    from clrender.metrics import psnr

    model = _model(2, kernel_size)
    fast, exact = Shader(model, layout=layout), Shader(model, exact=True, layout=layout)
    for width, height, c2w in VIEWS:
        camera, hits, _ = _inputs(model, width, height, c2w)
        exact_rgb, _ = exact.shade(camera, hits.tri, hits.bary)
        fast_rgb, _ = fast.shade(camera, hits.tri, hits.bary)
        assert psnr(fast_rgb, exact_rgb) >= 50.0


def test_all_misses_give_the_background():
    model = _model(2, 2)
    camera = Camera.from_fov(0.5, 13, 11, look_at([0.0, -3.0, 0.0], [0.0, -6.0, 0.0]))
    hits = HitCaster(model).cast_camera(camera)
    assert not hits.coverage.any()
    rgb, _ = _shader(2, 2).shade(camera, hits.tri, hits.bary)
    np.testing.assert_array_equal(rgb, np.broadcast_to(model.arrays["background"], rgb.shape))


def test_buffers_persist_per_size():
    model, shader = _model(1, 2), _shader(1, 2)
    camera, hits, _ = _inputs(model, *VIEWS[0])
    first, _ = shader.shade(camera, hits.tri, hits.bary)
    hidden = shader._bufs["hidden"]
    again, _ = shader.shade(camera, hits.tri, hits.bary)
    assert shader._bufs["hidden"] is hidden
    np.testing.assert_array_equal(first, again)
    other, hits2, _ = _inputs(model, *VIEWS[2])
    shader.shade(other, hits2.tri, hits2.bary)
    assert shader._bufs["hidden"] is not hidden


@pytest.mark.parametrize("kernel_size", [2, 1])
def test_bands_equal_one_pass(monkeypatch, kernel_size, cl_platform):
    # A hidden layer larger than the device's biggest buffer is shaded in bands of rows;
    # bands of 1, 5 and 7 rows give the one-pass image bit for bit, frame after frame (the
    # first band's zero rows are restored after the later bands overwrote them).
    model = _model(2, kernel_size)
    camera, hits, _ = _inputs(model, *VIEWS[1])
    whole, _ = Shader(model, exact=True).shade(camera, hits.tri, hits.bary)
    for rows in (1, 5, 7):
        monkeypatch.setattr(Shader, "band_rows", lambda self, w, h, rows=rows: rows)
        banded = Shader(model, exact=True)
        for _ in range(2):
            rgb, _ = banded.shade(camera, hits.tri, hits.bary)
            np.testing.assert_array_equal(rgb, whole)
        assert banded._band == rows


def test_bad_hits_are_rejected():
    model, shader = _model(1, 2), _shader(1, 2)
    camera, hits, _ = _inputs(model, *VIEWS[0])
    tri = hits.tri.copy()
    tri[0, 0, 0] = len(model.arrays["faces_0"])
    with pytest.raises(ValueError, match=r"tri\[0\] has values"):
        shader.shade(camera, tri, hits.bary)
    with pytest.raises(ValueError, match="expected"):
        shader.shade(camera, hits.tri[:, :-1], hits.bary)


@pytest.mark.parametrize("K", [1, 2, 3, 4])
def test_random_model_is_valid_and_nested(K):
    model = _model(K, 2)
    validate(model)
    radii = [np.linalg.norm(model.mesh(k)[0] - model.mesh(k)[0].mean(0), axis=1)
             for k in range(K)]
    for k in range(K):
        assert np.abs(model.mesh(k)[0]).max() < 1.0
        assert 1000 <= len(model.mesh(k)[1]) <= 6000
        if k:
            assert radii[k].max() < radii[k - 1].min()


def test_view_encoding_layout():
    d = np.array([[0.6, 0.0, -0.8]], np.float32)
    enc = view_encoding(d, 2)
    expected = [0.6, 0.0, -0.8, *np.sin(d[0]), *np.cos(d[0]), *np.sin(2 * d[0]),
                *np.cos(2 * d[0])]
    np.testing.assert_allclose(enc[0], expected, rtol=0, atol=1e-7)


def _set_weights(model, value: float):
    a = dict(model.arrays)
    for name in ("conv0_w", "conv1_w"):
        a[name] = np.full_like(a[name], value)
    for name in ("conv0_b", "conv1_b"):
        a[name] = np.zeros_like(a[name])
    return type(model)(model.config, a)


@pytest.mark.parametrize("kernel_size", [2, 1])
def test_conv_pair_is_centred(kernel_size):
    model = _set_weights(_model(1, kernel_size), 0.1)
    buf = np.zeros((9, 11, model.config.c_in), np.float32)
    buf[4, 5, 3] = 1.0
    s = conv_shader(model, buf)
    footprint = np.abs(s - 0.5).max(axis=-1) > 1e-7
    expected = np.zeros((9, 11), bool)
    r = kernel_size - 1
    expected[4 - r:5 + r, 5 - r:6 + r] = True
    np.testing.assert_array_equal(footprint, expected)
    window = s[4 - r:5 + r, 5 - r:6 + r]
    np.testing.assert_array_equal(window, window[::-1])
    np.testing.assert_array_equal(window, window[:, ::-1])


@pytest.mark.parametrize("kernel_size", [2, 1])
def test_reference_conv_matches_torch(kernel_size):
    import torch                # a dependency of clrender (training): never skipped

    F = torch.nn.functional
    model = _model(2, kernel_size)
    rng = np.random.default_rng(5)
    buf = rng.normal(0.0, 1.0, (13, 17, model.config.c_in)).astype(np.float32)
    a = {k: torch.from_numpy(np.asarray(v, np.float64)) for k, v in model.arrays.items()}
    x = torch.from_numpy(buf.astype(np.float64)).permute(2, 0, 1)[None]
    p = kernel_size - 1
    # torch pads (left, right, top, bottom); weights (out, in, dy, dx).
    h = F.relu(F.conv2d(F.pad(x, (0, p, 0, p)), a["conv0_w"].permute(3, 2, 0, 1),
                        a["conv0_b"]))
    s = torch.sigmoid(F.conv2d(F.pad(h, (p, 0, p, 0)), a["conv1_w"].permute(3, 2, 0, 1),
                               a["conv1_b"]))
    expected = s[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(conv_shader(model, buf), expected, rtol=0, atol=TORCH_ATOL)


@pytest.mark.parametrize("kernel_size", [2, 1])
@pytest.mark.parametrize("K", [1, 2])
def test_conv0_factored_is_the_direct_layer(K, kernel_size):
    """The kernel's factored conv0 (vertex projections blended by barycentrics, the view
    term from its weights or its table) equals the direct conv of the screen buffer:
    exactly up to float32 rounding (1e-4 on values of order 1) with the weights; with the
    table within linear interpolation's error, bounded from the table's own second
    differences (|f''| h^2 / 8 per component and tap) plus that rounding."""
    model = _model(K, kernel_size)
    _, hits, dirs = _inputs(model, *VIEWS[0])
    a = model.arrays
    direct = _conv(screen_buffer(model, hits.tri, hits.bary, dirs), a["conv0_w"],
                   a["conv0_b"], False)
    H = model.config.hidden
    defines = kernel_defines(model.config)
    b0 = np.zeros(defines["H_STRIDE"], np.float32)
    b0[:H] = a["conv0_b"]
    proj = vertex_projections(model, defines)
    exact = conv0_factored(model, hits.tri, hits.bary, dirs, proj,
                           view_weights(model, defines, True), b0, exact=True)
    np.testing.assert_allclose(exact[..., :H], direct, atol=1e-4, rtol=0)
    assert not exact[..., H:].any()                     # the padding channels stay zero
    table = view_weights(model, defines, False)
    fast = conv0_factored(model, hits.tri, hits.bary, dirs, proj, table, b0, exact=False)
    second = np.abs(np.diff(table[:, :, :, 0, :H].astype(np.float64), 2, axis=1)).max(1)
    bound = (second.sum(0) / 8).sum(0) + 1e-4            # per output channel
    assert (np.abs(fast[..., :H] - direct) <= bound).all()
