"""NDRF's kernels under the Oclgrind simulator (the harness and what it checks:
tests/test_oclgrind.py): the rasteriser (kernels/ndrf_raster.cl) in both layouts (a tile
and 16 triangles, or a tile row and one triangle, a work-item), from an orbit, from close
(triangles over several tiles) and from inside the meshes (triangles crossing the camera
plane); the shader (kernels/ndrf_shade.cl) on a tiny random model (K=2, 10x8 pixels, hits
on the image border and misses) with both kernel sizes, both conv0 organisations and both
builds, two frames each, from rasterised hits, and once in bands of 3 rows; and the refusal
of an image whose buffers exceed the simulator's 128 MiB allocation limit (a clear error,
nothing enqueued).
"""
from __future__ import annotations

import shutil

import pytest

from deps import require
from test_oclgrind import _oclgrind, assert_clean

SCRIPT = """
from clrender.camera import Camera, look_at
from clrender.ndrf import raster_cl, shader_cl
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ndrf.raster_cl import Rasteriser
from clrender.ndrf.render import Renderer

keep = []  # see tests/test_oclgrind.py: no buffer is released while Oclgrind watches
model = random_ndrf_model(NDRFConfig(thresholds=(1e-4, 1e-2)), 0)
views = {"border": Camera.from_fov(0.8, 10, 8, look_at([1.6, -1.2, 0.7], [-0.4, 0.4, 0.45])),
         "close": Camera.from_fov(1.2, 40, 36, look_at([0.9, -0.2, 0.1])),
         "inside": Camera.from_fov(1.4, 10, 8, look_at([0.1, 0.05, 0.0], [1.0, 0.3, 0.2]))}
for layout in ({"rows": 16, "lanes": 16}, raster_cl.GPU_LAYOUT):
    for name, camera in views.items():
        keep.append(Rasteriser(model, **layout))
        hits = keep[-1].hits(camera)
        print("RASTER", layout["rows"], name, int((hits.tri >= 0).sum()), keep[-1].binned_pairs,
              flush=True)
keep.append(Rasteriser(model))
hits = keep[-1].hits(views["border"])
# Both conv0 organisations: one pixel per work-item (GPUs) and 8 x 4 per work-item (CPUs,
# gathering past the image's right and bottom edges).
for layout in ({"H_VEC": 8, "SEG": 1, "ROWS": 1}, {"H_VEC": 16, "SEG": 8, "ROWS": 4}):
    shader_cl.device_layout = lambda device, layout=layout: dict(layout)
    for kernel_size in (2, 1):
        for exact in (True, False):
            config = NDRFConfig(thresholds=(1e-4, 1e-2), kernel_size=kernel_size)
            m = random_ndrf_model(config, 0)
            keep.append(shader_cl.Shader(m, exact=exact))
            for frame in range(2):
                rgb, ms = keep[-1].shade(views["border"], hits.tri, hits.bary)
            print("SHADED", keep[-1].defines["SEG"], kernel_size, exact,
                  round(float(hits.coverage.mean()), 3), bool(hits.coverage[-1, -1]), flush=True)
shader_cl.Shader.band_rows = lambda self, width, height: 3
keep.append(shader_cl.Shader(model, exact=True))
for frame in range(2):
    rgb, ms = keep[-1].shade(views["border"], hits.tri, hits.bary)
print("BANDED", keep[-1]._band, flush=True)
keep.append(Renderer(model))
out = keep[-1].render(views["border"], stats=True)
print("RENDERED", round(float(out["coverage"].mean()), 3), flush=True)
try:
    keep[-1].render(Camera.from_fov(0.8, 4096, 4096, look_at([1.6, -1.2, 0.7])))
except ValueError as e:
    print("REFUSED", e, flush=True)
# Last (growing the list releases a buffer): a frame overflowing its tile list reads none
# of it past its end, and is binned again into a larger one.
raster_cl.INITIAL_PAIRS = 8
keep.append(Rasteriser(model))
hits = keep[-1].hits(views["close"])
print("OVERFLOWED", keep[-1].binned_pairs, keep[-1].capacity, int((hits.tri >= 0).sum()),
      flush=True)
"""


@pytest.mark.oclgrind
def test_ndrf_kernels_clean_under_oclgrind():
    require(shutil.which("oclgrind") is not None, "oclgrind (apt install oclgrind)")
    proc, log, errors = _oclgrind(SCRIPT)
    assert_clean(proc, log, errors)
    raster = [line.split() for line in log.splitlines() if line.startswith("RASTER")]
    assert len(raster) == 6 and all(int(r[3]) > 0 for r in raster), raster
    # Both layouts cover the same pixels from the same (triangle, tile) lists.
    assert {r[2]: r[3:] for r in raster[:3]} == {r[2]: r[3:] for r in raster[3:]}, raster
    assert all(int(r[4]) > 0 for r in raster), raster
    shaded = [line.split() for line in log.splitlines() if line.startswith("SHADED")]
    assert len(shaded) == 8, log[-4000:]
    overflowed = [line.split() for line in log.splitlines() if line.startswith("OVERFLOWED")]
    close = next(r for r in raster if r[2] == "close")
    assert len(overflowed) == 1 and overflowed[0][1] == close[4] and int(close[4]) > 8, log
    assert int(overflowed[0][2]) >= int(close[4]) and overflowed[0][3] == close[3], log
    assert {r[1] for r in shaded} == {"1", "8"}, shaded
    assert all(0.0 < float(r[4]) < 1.0 and r[5] == "True" for r in shaded), shaded
    assert "BANDED 3" in log and "RENDERED" in log
    refused = [line for line in log.splitlines() if line.startswith("REFUSED")]
    assert len(refused) == 1 and "4096x4096 pixels" in refused[0] and "MiB" in refused[0], \
        log[-2000:]
