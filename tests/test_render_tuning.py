"""The GPU variants of the NGP-RT renderer (render_cl.Tuning), exact builds, against the
numpy reference on random models, on every CPU runtime (cl_platform) and under Oclgrind.

A variant that keeps the default's values (march_tile, deferred_local, deferred_streamed)
is held to the reference with the tolerances of tests/test_render_cl.py (rgb and opacity
max abs 1e-4, depth relative 1e-4, marching and occupied points identical) and to the
default build: the march's outputs bit for bit, rgb within 1e-6 (Intel's CPU compiler
gives a partial work-group's pixels an exp an ulp away from a full group's); half_tables to the reference of the model with its tables
rounded to float16 (render_cl.half_rounded), with the same tolerances.
"""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer, Tuning, half_rounded
from clrender.ngprt.render_ref import render_reference
from clrender.paths import path_cameras
from deps import require
from test_oclgrind import _oclgrind, assert_clean
from test_render_cl import BACKGROUND, _assert_matches

SIZE = 29            # not a multiple of a tile or a lane width: partial groups everywhere
TUNINGS = {
    "half-tables": Tuning(half_tables=True),
    "tile-8x8": Tuning(march_tile=(8, 8)),
    "tile-4x2": Tuning(march_tile=(4, 2)),
    "occupancy-image": Tuning(occupancy_image=True),
    "deferred-local": Tuning(deferred_local=True),
    "deferred-streamed": Tuning(deferred_streamed=True),
    "all": Tuning(half_tables=True, march_tile=(8, 4), occupancy_image=True,
                  deferred_local=True, deferred_streamed=True),
}
ONE_RAY = ("occupancy-image", "all")      # variants that need one ray a work-item


def _model(variant: str, scene: str, seed: int = 3):
    config = preset("tiny", variant=variant, scene=scene, L=2, L_C=32, log2_T=11, G_res=16)
    return random_baked_model(config, seed, 1.0)


def _render(model, scene: str, tuning: Tuning, rays=None):
    camera = path_cameras(scene, "orbit", 8, SIZE, SIZE)[2]
    out = Renderer(model, use_G=True, exact=True, rays=rays, deferred_vec=rays,
                   tuning=tuning).render(camera, background=BACKGROUND, stats=True)
    return out, camera


@pytest.mark.parametrize("rays", [None, 1])
@pytest.mark.parametrize("scene", ["bounded", "unbounded"])
@pytest.mark.parametrize("name", list(TUNINGS))
def test_tuning_matches_reference(name, scene, rays, cl_platform):
    tuning = TUNINGS[name]
    if name in ONE_RAY and rays is None:
        rays = 1
    model = _model("separate-v", scene)
    out, camera = _render(model, scene, tuning, rays)
    assert out["n_occ"].sum() > 0, "test model has no occupied sample in view"
    ref = render_reference(half_rounded(model) if tuning.half_tables else model, camera,
                           background=BACKGROUND, use_G=True)
    _assert_matches(out, {k: np.asarray(v).reshape(out[k].shape) for k, v in ref.items()
                          if k in out})
    if not tuning.half_tables:
        default, _ = _render(model, scene, Tuning(), rays)
        for key in ("depth", "opacity", "n_march", "n_occ"):
            np.testing.assert_array_equal(out[key], default[key], err_msg=key)
        np.testing.assert_allclose(out["rgb"], default["rgb"], rtol=0, atol=1e-6)


def test_half_tables_change_the_image_where_the_tables_round():
    # The half build reads other values than the float build: its reference is not the
    # default's (else the test above would not tell the two apart).
    model = _model("separate-v", "bounded")
    rounded = half_rounded(model)
    assert not np.array_equal(rounded.arrays["fine_tables"], model.arrays["fine_tables"])
    camera = path_cameras("bounded", "orbit", 8, SIZE, SIZE)[2]
    a = render_reference(model, camera, background=BACKGROUND)["rgb"]
    b = render_reference(rounded, camera, background=BACKGROUND)["rgb"]
    assert np.abs(np.asarray(a) - np.asarray(b)).max() > 1e-6


def test_bad_tunings_say_what_is_wrong():
    model = _model("separate-v", "bounded")
    with pytest.raises(ValueError, match="two positive sizes"):
        Tuning(march_tile=(8, 0))
    camera = path_cameras("bounded", "orbit", 8, SIZE, SIZE)[2]
    with pytest.raises(ValueError, match="more than the march kernel's"):
        Renderer(model, tuning=Tuning(march_tile=(1 << 16, 1))).render(camera)
    big = half_rounded(model)
    big.arrays["fine_tables"] = big.arrays["fine_tables"] * 1e6
    with pytest.raises(ValueError, match="beyond float16's range"):
        Renderer(big, tuning=Tuning(half_tables=True))
    with pytest.raises(ValueError, match="one ray a work-item"):
        Renderer(model, rays=4, tuning=Tuning(occupancy_image=True))
    with pytest.raises(ValueError, match="one ray a work-item"):
        Renderer(model, rays=1, march="paper", tuning=Tuning(occupancy_image=True))
    assert Tuning().name == "default"
    assert TUNINGS["all"].name == ("half-tables+tile-8x4+occupancy-image+deferred-local+"
                                   "deferred-streamed")


SCRIPT = """
import numpy as np

from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer, Tuning
from clrender.paths import path_cameras

keep = []  # no buffer released while Oclgrind watches (tests/test_oclgrind.py)
for scene in ("bounded", "unbounded"):
    config = preset("tiny", variant="separate-v", scene=scene, L_C=16, log2_T=8, G_res=8)
    model = random_baked_model(config, 0, 1.0)
    camera = path_cameras(scene, "orbit", 8, 11, 9)[2]
    for tuning in (Tuning(), TUNING):
        keep.append(Renderer(model, use_G=True, exact=True, rays=1, tuning=tuning))
        out = keep[-1].render(camera, stats=True)
        print("RENDERED", scene, tuning.name, int(out["n_occ"].sum()),
              float(out["rgb"].sum()), flush=True)
"""


# Every variant but the occupancy image under all of Oclgrind's checks; the image alone
# without its uninitialised-value check, which does not track image contents (it flags
# every branch on a code read from one, though the images equal the buffer's).
@pytest.mark.oclgrind
@pytest.mark.parametrize("tuning, uninitialized", [
    ("Tuning(half_tables=True, march_tile=(4, 4), deferred_local=True, "
     "deferred_streamed=True)", True),
    ("Tuning(occupancy_image=True)", False)])
def test_tunings_clean_under_oclgrind(tuning, uninitialized):
    require(shutil.which("oclgrind") is not None, "oclgrind (apt install oclgrind)")
    proc, log, errors = _oclgrind(f"from clrender.ngprt.render_cl import Tuning\n"
                                  f"TUNING = {tuning}\n" + SCRIPT, uninitialized)
    assert_clean(proc, log, errors)
    rendered = [line.split() for line in log.splitlines() if line.startswith("RENDERED")]
    assert len(rendered) == 4, log[-4000:]
    assert all(int(r[3]) > 0 for r in rendered), rendered
    for default, variant in (rendered[0:2], rendered[2:4]):       # per scene
        assert variant[3] == default[3], (default, variant)        # the same samples
