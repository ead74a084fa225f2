"""The launches of a 1920x1080 frame in the GPU layouts give a GPU enough work-items to fill
it: at least 10^4 each (bench/speed/kernel_resources.py's ``frame_launches``: the renderers' own
``launch_sizes``), on the default device. A property of the launch geometry, not a timing.

Named exceptions, which do not scale with the frame's pixels: the NDRF rasteriser's tile
scan (``ndrf_raster_scan``: the prefix sum of the 8160 tiles' counts at 1080p, a parallel
scan by one work-group of up to 256 work-items, 32 tiles each) and its per-face passes
(``ndrf_raster_setup``: one a face in the GPU layout, ``ndrf_raster_bin``: one a face),
sized by the model (the random one here has 6400 faces).
"""
from __future__ import annotations

from bench.speed.kernel_resources import frame_launches
from clrender.device import get_runtime

MIN_WORK_ITEMS = 10**4
NOT_PER_PIXEL = {"ndrf_raster_scan", "ndrf_raster_setup", "ndrf_raster_bin"}


def test_gpu_layout_launches_of_a_1080p_frame_fill_a_gpu():
    launches = frame_launches(get_runtime(), "gpu", 1920, 1080)
    kernels = {launch["kernel"] for launch in launches}
    assert kernels >= {"ngprt_march", "ngprt_deferred", "ndrf_raster_tile",
                       "ndrf_zero_padding", "ndrf_conv0", "ndrf_conv1"} | NOT_PER_PIXEL
    small = [(launch["kernel"], launch["size"]) for launch in launches
             if launch["kernel"] not in NOT_PER_PIXEL
             and launch["work_items"] < MIN_WORK_ITEMS]
    assert not small, f"launches with fewer than {MIN_WORK_ITEMS} work-items: {small}"
    scans = [launch["work_items"] for launch in launches if launch["kernel"] == "ndrf_raster_scan"]
    assert scans and all(n > 1 for n in scans), f"the tile scan is not parallel: {scans}"
