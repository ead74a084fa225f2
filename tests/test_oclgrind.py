"""The NGP-RT kernels under the Oclgrind simulator: no out-of-bounds access, no data race,
no use of uninitialised values, no OpenCL API misuse.

Generates camera rays (kernels/camera.cl) and renders a tiny random model (L_C=16, 8x8
pixels) with every aggregation variant, both scene types and G on and off, in a subprocess run by
``oclgrind --check-api --data-races --uninitialized``. One report is expected and
ignored: pyopencl, when it builds or fetches a kernel, asks ``clGetDeviceInfo`` for a
property Oclgrind 21.10 does not implement (CL_INVALID_VALUE for 'param_name'); it
involves no kernel and no call of ours. Every Renderer is kept alive until the end:
Oclgrind 21.10's --uninitialized plugin reports reads of freshly written buffers as
uninitialised once the memory of released buffers is reused by new ones (seen with a
second Renderer after the first was freed; none while all stay alive, and none with a
single Renderer rendering repeatedly).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = """
from clrender.camera import Camera, generate_rays_cl, look_at
from clrender.ngprt.config import VARIANTS, preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer

views = {"bounded": look_at([0.3, -2.5, 1.2]), "unbounded": look_at([0.2, -0.6, 0.3])}
keep = []  # see the module doc: no buffer is released while Oclgrind watches
keep.append(generate_rays_cl(Camera.from_fov(0.8, 8, 6, views["bounded"])))
print("RENDERED camera", flush=True)
for scene, c2w in views.items():
    camera = Camera.from_fov(1.0, 8, 8, c2w)
    for variant in VARIANTS:
        config = preset("tiny", variant=variant, scene=scene, L_C=16, log2_T=8, G_res=8)
        model = random_baked_model(config, 0, 1.0)
        for use_G in (True, False):
            keep.append(Renderer(model, use_G=use_G))
            out = keep[-1].render(camera)
            print("RENDERED", scene, variant, use_G, int(out["n_march"].sum()),
                  int(out["n_occ"].sum()), flush=True)
"""
ERROR = re.compile(r"invalid (read|write)|data race|uninitiali[sz]ed|runtime error|"
                   r"out of bounds|oclgrind -|error", re.IGNORECASE)


@pytest.mark.oclgrind
@pytest.mark.skipif(shutil.which("oclgrind") is None,
                    reason="the oclgrind executable is not on PATH (apt install oclgrind)")
def test_kernels_clean_under_oclgrind():
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, CLRENDER_DEVICE="",
               PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run(
        ["oclgrind", "--check-api", "--data-races", "--uninitialized", sys.executable, "-c",
         SCRIPT], capture_output=True, text=True, env=env, cwd=root, timeout=300)
    log = proc.stdout + proc.stderr
    blocks = [b for b in re.split(r"\n\s*\n", log)
              if not ("clGetDeviceInfo" in b and "CL_INVALID_VALUE" in b and "param_name" in b)]
    errors = [line for b in blocks for line in b.splitlines() if ERROR.search(line)]
    assert proc.returncode == 0, f"oclgrind run failed ({proc.returncode}):\n{log[-4000:]}"
    assert not errors, "Oclgrind reported:\n" + "\n".join(errors[:40])
    assert log.count("RENDERED") == 25, log[-4000:]
