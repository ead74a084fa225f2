"""The core install alone (``pip install clrender``, no extra) loads and renders a baked
file of each method, to the same pixels as the full install, importing no extra's package;
a job whose extra is missing says so in one line.

The core's virtual environment is ``.venv-core`` beside ``.venv`` (.ci/install makes it,
with ``pip install -e .``: this checkout's code, the core's dependencies only). Without it
these tests skip (fail under CI).

Tolerance: none. Both installs run the same kernels with the same options on the same
device, so the images are equal bit for bit.
"""
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from clrender import Camera, extras, load, look_at, render
from clrender.ndrf.method import example_model as ndrf_example
from clrender.ngprt.method import example_model as ngprt_example
from deps import require

ROOT = Path(__file__).resolve().parent.parent
CORE_PYTHON = ROOT / ".venv-core" / "bin" / "python"
# Every package an extra brings (extras.EXTRAS), none of which the core may import.
EXTRA_PACKAGES = sorted({m for modules in extras.EXTRAS.values() for m in modules})
CAMERA = dict(fov=0.69, width=48, height=40, eye=[0.4, -3.0, 1.5])

RENDER = """
import json, sys
import numpy as np
import clrender
cam = clrender.Camera.from_fov({fov}, {width}, {height}, clrender.look_at({eye}))
for path, out in zip(sys.argv[1::2], sys.argv[2::2]):
    np.save(out, clrender.render(clrender.load(path), cam))
print(json.dumps(sorted(m for m in sys.modules if m.partition(".")[0] in {extras})))
"""


@pytest.fixture(scope="module")
def core_python():
    require(CORE_PYTHON.is_file(), f"the core-only environment {CORE_PYTHON} (.ci/install)")
    return CORE_PYTHON


@pytest.fixture(scope="module")
def device_spec():
    """The platform of this install's default device, for both installs (the core has no
    pip-installed OpenCL runtime, so its default could be another)."""
    from clrender.device import select_device

    return select_device().platform.name.strip()


def run_core(python, args, device_spec, **kw):
    env = {**os.environ, "CLRENDER_DEVICE": device_spec}
    env.pop("PYTHONPATH", None)
    return subprocess.run([str(python), *args], capture_output=True, text=True, env=env,
                          timeout=600, **kw)


def test_the_core_renders_each_method_as_the_full_install(core_python, device_spec, tmp_path,
                                                           monkeypatch):
    files = {"ngprt": ngprt_example(tmp_path / "ngprt.npz"),
             "ndrf": ndrf_example(tmp_path / "ndrf.npz")}
    args = [a for name, path in files.items() for a in (str(path), str(tmp_path / name))]
    script = RENDER.format(**CAMERA, extras=EXTRA_PACKAGES)
    done = run_core(core_python, ["-c", script, *args], device_spec, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1]) == []       # no extra's package imported
    monkeypatch.setenv("CLRENDER_DEVICE", device_spec)
    cam = Camera.from_fov(CAMERA["fov"], CAMERA["width"], CAMERA["height"],
                          look_at(CAMERA["eye"]))
    for name, path in files.items():
        core = np.load(tmp_path / f"{name}.npy")
        assert core.shape == (CAMERA["height"], CAMERA["width"], 3)
        assert np.array_equal(core, render(load(path), cam)), name


def test_the_core_has_none_of_the_extras(core_python, device_spec):
    script = ("import importlib.util, json; print(json.dumps([m for m in "
              f"{EXTRA_PACKAGES} if importlib.util.find_spec(m)]))")
    done = run_core(core_python, ["-c", script], device_spec)
    assert done.returncode == 0 and json.loads(done.stdout) == [], done.stderr


@pytest.mark.parametrize("argv, extra", [
    (["-m", "clrender.cli", "train", "DATA", "--out", "RUN"], "train"),
    (["-m", "clrender.cli", "eval", "MODEL", "DATA"], "eval"),
    (["-m", "clrender.cli", "capture", "PHOTOS", "--out", "OUT"], "capture"),
    (["-m", "clrender.cli", "view", "MODEL"], "view"),
    (["-m", "bench.run", "--list"], "bench"),
])
def test_a_job_without_its_extra_says_so_in_one_line(core_python, device_spec, argv, extra):
    done = run_core(core_python, argv, device_spec, cwd=ROOT)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1, done.stderr
    assert f"which is not installed: pip install 'clrender[{extra}]'" in done.stderr


def test_the_core_says_its_version(core_python, device_spec):
    from importlib import metadata

    done = run_core(core_python, ["-m", "clrender.cli", "--version"], device_spec)
    assert done.returncode == 0 and done.stdout == f"clrender {metadata.version('clrender')}\n"


def test_each_extras_modules_come_from_its_pyproject_extra():
    """clrender.extras.EXTRAS (what a command checks) against pyproject.toml's extras (what
    pip installs), an extra's included extras expanded."""
    import re
    from importlib import metadata

    try:
        import tomllib
    except ModuleNotFoundError:                 # Python 3.10: the bench extra's tomli
        import tomli as tomllib

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]

    def dists(extra: str) -> set[str]:
        out = set()
        for req in declared[extra]:
            name = re.match(r"[A-Za-z0-9_.\-]+(\[[^\]]*\])?", req)
            if name.group(1) and name.group(0).startswith("clrender"):
                for included in name.group(1)[1:-1].split(","):
                    out |= dists(included.strip())
            else:
                out.add(re.sub(r"[-_.]+", "-", name.group(0)).lower())
        return out

    by_module = metadata.packages_distributions()
    for extra, modules in extras.EXTRAS.items():
        for module in modules:
            provided = {re.sub(r"[-_.]+", "-", d).lower() for d in by_module[module]}
            assert provided & dists(extra), (extra, module, provided)
