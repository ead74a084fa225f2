"""The NGP-RT kernels under the Oclgrind simulator: no out-of-bounds access, no
data race, no use of uninitialised values, no OpenCL API misuse.

NGP-RT: generates camera rays (kernels/camera.cl) and renders a tiny random model (L_C=16,
10x8 pixels) with every aggregation variant, both scene types (unbounded: from inside the
unit cube and from the contracted shell): with every variant the exact build and the fast
build with 16 rays / pixels per work-item; with separate-v also the exact build without G,
the fast build at lane widths 1, 2, 4 and 8 (10 pixels a row: full and partly filled
work-items at 4, 8 and 16) and the paper's march with G (``MARCH_PAPER``) in its counting
build (``COUNT_READS``), exact and fast at 16 lanes. Every build must sample the same
points (per pixel), the builds of one march with G the same marching points, some of
each, the paper's builds the same reads, and the fast builds' images agree across
widths. Oclgrind 21.10 mis-evaluates a vector comparison mask turned into
a number (``-(a < b)`` gives 255 per true lane, not 1), which once kept the vector march from
starting under it; kernels/ngprt_lanes.h spells mask arithmetic with select() (which, like
comparisons, any() and as_int, it evaluates right), so the vector march runs here as on a
device. Left unchecked: the code PoCL's own LLVM generates (its vectoriser, its contraction
of a * b + c) and work-groups larger than Oclgrind's. NDRF's kernels:
tests/test_oclgrind_ndrf.py. Each
runs in a subprocess run by ``oclgrind --check-api --data-races --uninitialized``. One
report is expected and ignored: pyopencl, when it builds or fetches a kernel, asks
``clGetDeviceInfo`` for a property Oclgrind 21.10 does not implement (CL_INVALID_VALUE for
'param_name'); it involves no kernel and no call of ours. Every Renderer and Shader is
kept alive until the end, each at one image size (a Shader frees its frame buffers when the
size changes): Oclgrind 21.10's --uninitialized plugin reports reads of freshly written
buffers as uninitialised once the memory of released buffers is reused by new ones (seen
with a second Renderer after the first was freed; none while all stay alive, and none with
a single Renderer rendering repeatedly).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from deps import require

SCRIPT = """
import hashlib

import numpy as np

from clrender.camera import Camera, generate_rays_cl, look_at
from clrender.ngprt.config import VARIANTS, preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import LANE_WIDTHS, Renderer

# Unbounded: an eye inside the unit cube, and one in the contracted shell whose rays cross
# several pieces of the contracted-space lattice (docs/ngprt.md "Step lattice").
views = [("bounded", look_at([0.3, -2.5, 1.2])), ("unbounded", look_at([0.2, -0.6, 0.3])),
         ("unbounded", look_at([2.5, -1.8, 0.9]))]
keep = []  # see the module doc: no buffer is released while Oclgrind watches
keep.append(generate_rays_cl(Camera.from_fov(0.8, 8, 6, views[0][1])))
print("RENDERED camera", flush=True)
digest = lambda a: hashlib.sha1(np.ascontiguousarray(a).tobytes()).hexdigest()[:12]
for view, (scene, c2w) in enumerate(views):
    camera = Camera.from_fov(1.0, 10, 8, c2w)
    for variant in VARIANTS + ("separate-v/occ64",):
        # "/occ64": occupancy finer than the coarse grid (the paper's grids in small: 64^3
        # occupancy, G 32^3, L_C 16), both marches' exact builds with G.
        fine = variant.endswith("/occ64")
        config = preset("tiny", variant=variant.split("/")[0], scene=scene, L_C=16, log2_T=8,
                        G_res=32 if fine else 8, occupancy_res=64 if fine else None)
        model = random_baked_model(config, 0, 1.0)
        # Every variant: the exact build with the device's lane width (1 on Oclgrind) and
        # the fast build with 16 rays / pixels per work-item. The lane code does not depend
        # on the variant (only the per-lane fusion does), so one variant, the method's,
        # also runs the exact build without G and the fast build at the other widths.
        # The paper's march (and the counting build) runs with separate-v only, too.
        builds = [(True, True, None, "ours"), (True, False, 16, "ours")]
        if fine:
            builds = [(True, True, None, "ours"), (True, True, None, "paper")]
        if variant == "separate-v":
            builds[1:1] = [(False, True, None, "ours")] + [
                (True, False, w, "ours") for w in LANE_WIDTHS[:-1]]
            builds += [(True, True, None, "paper"), (True, False, 16, "paper")]
        rgb_one = None
        for use_G, exact, lanes, march in builds:
            keep.append(Renderer(model, use_G=use_G, exact=exact, rays=lanes, deferred_vec=lanes,
                                 march=march, count_reads=march == "paper"))
            out = keep[-1].render(camera, stats=True)
            if lanes == 1:
                rgb_one = out["rgb"]
            diff = float(np.abs(out["rgb"] - rgb_one).max()) if rgb_one is not None else 0.0
            reads = digest(out["n_reads"]) if "n_reads" in out else "-"
            print("RENDERED", view, variant, use_G, exact, lanes, int(out["n_march"].sum()),
                  int(out["n_occ"].sum()), digest(out["n_march"]), digest(out["n_occ"]),
                  diff, march, reads, flush=True)
"""
ERROR = re.compile(r"invalid (read|write)|data race|uninitiali[sz]ed|runtime error|"
                   r"out of bounds|oclgrind -|error", re.IGNORECASE)


def _oclgrind(script: str, uninitialized: bool = True
              ) -> tuple[subprocess.CompletedProcess, str, list[str]]:
    """Runs ``script`` under Oclgrind; returns the process, its log and the error lines
    (the one known clGetDeviceInfo report left out, see the module doc). ``uninitialized``:
    with the uninitialised-value check (off only for kernels that read images, whose
    values that plugin does not track)."""
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, CLRENDER_DEVICE="",
               PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run(
        ["oclgrind", "--check-api", "--data-races",
         *(["--uninitialized"] if uninitialized else []), sys.executable, "-c", script],
        capture_output=True, text=True, env=env, cwd=root, timeout=1800)
    log = proc.stdout + proc.stderr
    blocks = [b for b in re.split(r"\n\s*\n", log)
              if not ("clGetDeviceInfo" in b and "CL_INVALID_VALUE" in b and "param_name" in b)]
    return proc, log, [line for b in blocks for line in b.splitlines() if ERROR.search(line)]


def assert_clean(proc: subprocess.CompletedProcess, log: str, errors: list[str]) -> None:
    """The run under Oclgrind (:func:`_oclgrind`'s three results) exited 0 and Oclgrind
    reported nothing."""
    assert proc.returncode == 0, f"oclgrind run failed ({proc.returncode}):\n{log[-4000:]}"
    assert not errors, "Oclgrind reported:\n" + "\n".join(errors[:40])


@pytest.mark.oclgrind
def test_kernels_clean_under_oclgrind():
    require(shutil.which("oclgrind") is not None, "oclgrind (apt install oclgrind)")
    proc, log, errors = _oclgrind(SCRIPT)
    assert_clean(proc, log, errors)
    assert log.count("RENDERED") == 1 + 3 * (5 * 2 + 9 + 2), log[-4000:]
    builds = {}
    for line in log.splitlines():
        f = line.split()
        if f[:1] == ["RENDERED"] and len(f) == 13:
            builds.setdefault((f[1], f[2]), []).append(
                {"G": f[3] == "True", "lanes": f[5], "n_march": int(f[6]), "n_occ": int(f[7]),
                 "march_digest": f[8], "occ_digest": f[9], "rgb_diff": float(f[10]),
                 "march": f[11], "reads_digest": f[12]})
    assert len(builds) == 21, sorted(builds)
    for (view, variant), rows in builds.items():
        widths = ["None", "None", "1", "2", "4", "8", "16", "None", "16"] if (
            variant == "separate-v") else ["None", "None"] if variant.endswith("/occ64") \
            else ["None", "16"]
        assert [r["lanes"] for r in rows] == widths, rows
        # Every build samples the same points, pixel by pixel, and some.
        assert len({r["occ_digest"] for r in rows}) == 1 and rows[0]["n_occ"] > 0, (view, rows)
        # With G, every build of one march marches the same points (without it, the
        # unbounded skip may test one more empty point, so G off is only held to marching
        # some); the paper's builds count the same reads.
        for march in ("ours", "paper"):
            with_G = [r for r in rows if r["G"] and r["march"] == march]
            assert len({r["march_digest"] for r in with_G}) <= 1, (view, rows)
        paper = [r for r in rows if r["march"] == "paper"]
        assert len({r["reads_digest"] for r in paper}) == (1 if paper else 0), (view, rows)
        assert min(r["n_march"] for r in rows) > 0, (view, rows)
        # The fast build's image at every width against its one-lane image: the same
        # operations per lane; -cl-mad-enable may fuse a * b + c differently per width
        # (a few float32 ulps, through exp and the deferred MLP).
        assert max(r["rgb_diff"] for r in rows) <= 1e-5, (view, rows)

