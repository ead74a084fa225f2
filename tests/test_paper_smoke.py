"""bench.speed.paper_smoke's memory figures for NDRF's views (clrender/ndrf/paper_smoke.py) are a
real ViewSet's: the bytes per view it reports (and docs/guides/cluster.md quotes: 23 MB at 800x800,
K = 2) equal the tensors ``ViewSet.build`` holds per view, exactly, in memory or disk-backed, and a disk-backed view
keeps the resident bytes it reports. The smoke run itself trains `paper`-sized models for
minutes: a benchmark (``python -m bench.speed.paper_smoke``), not a test."""
from __future__ import annotations

import numpy as np

from clrender.ndrf.paper_smoke import DISK_BACKED_VIEW_BYTES, view_bytes
from clrender import Camera, look_at
from clrender.ndrf import view_memory
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ndrf.shader_torch import ViewSet


def test_view_bytes_is_what_a_viewset_holds_per_view(tmp_path):
    model = random_ndrf_model(NDRFConfig(thresholds=(1e-4, 1e-2)), seed=3)
    H, W, n = 12, 20, 3
    cams = [Camera.from_fov(0.7, W, H, look_at([0.0, -3.0, 0.5 * i])) for i in range(n)]
    images = np.zeros((n, H, W, 3), np.float32)
    for budget in (1 << 40, 0):                    # in memory, disk-backed
        views = ViewSet.build(model, cams, images, "cpu", budget=budget, folder=tmp_path)
        held = sum(t.numel() * t.element_size() for t in (views.tri, views.bary, views.images))
        assert held == n * view_bytes(model.config.K, H, W)
        assert views.disk_backed == (budget == 0)
    assert views.resident_bytes == n * DISK_BACKED_VIEW_BYTES
    assert DISK_BACKED_VIEW_BYTES == view_memory.DISK_BACKED_VIEW_BYTES
    assert view_bytes(2, 800, 800) == 23_040_000
    assert (views.tri >= 0).any()                  # the views do see the meshes
