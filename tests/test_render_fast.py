"""The fast build of the NGP-RT kernels (``Renderer(exact=False)``, what rendering uses)
against the exact build (``exact=True``, the one compared with the numpy reference in
tests/test_render_cl.py).

Random structured models of every variant, bounded and unbounded, several orbit views.
Tolerance (stated, not tuned): PSNR >= 50 dB between the two builds' images on every view
(docs/ngprt.md "Builds": the fast build may use native exp and reciprocal, contract
multiply-adds in the deferred MLP and relax division; it places the same samples where
the device divides correctly rounded, which this test does not rely on).
"""
from __future__ import annotations

import numpy as np
import pytest

from clrender.metrics import psnr
from clrender.ngprt.config import VARIANTS, preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer
from clrender.paths import path_cameras

SIZE = 48
VIEWS = (0, 3, 6)               # of an 8-frame orbit
MIN_PSNR = 50.0


@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_fast_build_within_50db_of_exact(variant, scene, cl_platform):
    config = preset("tiny", variant=variant, scene=scene, L_C=32, log2_T=11, G_res=16)
    model = random_baked_model(config, seed=2)
    fast, exact = Renderer(model), Renderer(model, exact=True)
    assert not fast.exact and exact.exact
    cameras = path_cameras(scene, "orbit", 8, SIZE, SIZE)
    for view in VIEWS:
        a = fast.render(cameras[view], background=(0.1, 0.7, 0.4), stats=True)
        b = exact.render(cameras[view], background=(0.1, 0.7, 0.4), stats=True)
        assert b["n_occ"].sum() > 0, f"view {view}: no occupied sample in view"
        assert np.all(np.isfinite(a["rgb"])) and a["rgb"].min() >= 0 and a["rgb"].max() <= 1
        assert psnr(a["rgb"], b["rgb"]) >= MIN_PSNR, (
            f"{variant} {scene} view {view}: fast build {psnr(a['rgb'], b['rgb']):.1f} dB "
            f"from the exact build, expected >= {MIN_PSNR}")
