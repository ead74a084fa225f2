"""Shared fixtures; with ``CLRENDER_TEST_WITH_TOY=1`` the toy method (tests/toymethod) is
installed for the whole run, child processes included, as a third-party plug-in would be
(tests/test_extra_plugin.py runs the shell's tests so)."""
import os
import sys
import tempfile
from pathlib import Path

import pytest

# The suite's trained models, trained once per run (tests/trained_models.py).
from trained_models import (bench_cache, tiny_ndrf_student, tiny_run, tiny_scene,  # noqa: F401
                            tiny_teacher)

TESTS = Path(__file__).resolve().parent


def install_toy(site: Path) -> None:
    """Register tests/toymethod as an installed distribution on ``site`` (a dist-info with
    its ``clrender.methods`` entry point)."""
    dist = site / "clrender_toy-0.1.dist-info"
    dist.mkdir(parents=True, exist_ok=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: clrender-toy\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[clrender.methods]\ntoy = toymethod.method\n")


def replace_bench(monkeypatch, method: str, **changes) -> None:
    """For the test, method ``method``'s spec with its bench spec's fields ``changes``
    (``ablations=tmp_path``): specs are frozen, so the registry hands out a changed copy."""
    import dataclasses

    from clrender import methods

    real = methods.get
    spec = real(method)
    changed = dataclasses.replace(spec, bench=dataclasses.replace(spec.bench, **changes))
    monkeypatch.setattr(methods, "get", lambda name: changed if name == method else real(name))


def pytest_configure(config):
    if os.environ.get("CLRENDER_TEST_WITH_TOY") == "1":
        site = Path(tempfile.mkdtemp(prefix="clrender-toy-site-"))
        install_toy(site)
        paths = [str(site), str(TESTS)]
        sys.path[:0] = paths
        os.environ["PYTHONPATH"] = os.pathsep.join(paths + [os.environ.get("PYTHONPATH", "")])


# The CPU OpenCL implementations the kernel tests run on (cl_platform): PoCL (Debian's or
# pip's, the [pocl] extra) and Intel's CPU runtime from pip (clrender/icd.py registers it).
# More by $CLRENDER_TEST_PLATFORMS, "key=platform name" pairs separated by commas (a GPU's
# driver, e.g. "nvidia=NVIDIA CUDA"): each runs the same tests, skipped where absent.
CL_PLATFORMS = {"pocl": "Portable Computing Language", "intel": "Intel(R) OpenCL"}
_INSTALL = {"intel": "pip install intel-opencl-rt intel-cmplr-lib-rt tbb",
            "pocl": "apt install pocl-opencl-icd, or pip install pocl-binary-distribution"}
for _pair in filter(None, os.environ.get("CLRENDER_TEST_PLATFORMS", "").split(",")):
    _key, _, _name = _pair.partition("=")
    CL_PLATFORMS[_key.strip()] = _name.strip()
    _INSTALL.setdefault(_key.strip(), "its vendor's OpenCL driver")


@pytest.fixture(params=list(CL_PLATFORMS))
def cl_platform(request, monkeypatch):
    """The test runs once per implementation in CL_PLATFORMS, on its first device that
    builds kernels, by $CLRENDER_DEVICE (the device's index, inherited by child
    processes); where the implementation is absent, skipped saying what to install (failed
    under CI=true, as .ci/install installs both: tests/deps.py)."""
    from clrender import device
    from deps import require

    name = CL_PLATFORMS[request.param]
    found = [i for i, d in enumerate(device.list_devices())
             if d.platform.name.strip() == name and device._compiles(d)]
    require(bool(found), f"a {name} device that builds kernels ({_INSTALL[request.param]})")
    monkeypatch.setenv("CLRENDER_DEVICE", str(found[0]))
    return request.param


@pytest.fixture
def one_torch_thread():
    """torch on one thread for the test: CPU training is then bit-reproducible (with two
    threads, reductions may add in another order and runs differ by ~1e-5 after 20 steps)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
