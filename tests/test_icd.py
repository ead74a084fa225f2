"""Pip-installed OpenCL runtimes registered beside the system's (clrender/icd.py): the
vendors folder it writes, the variables it leaves alone, and the real ICD loader in a
fresh process listing Intel's runtime and PoCL with nothing exported."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from clrender import icd
from deps import require


@pytest.fixture
def fake_system(tmp_path, monkeypatch):
    """A system vendors folder with one .icd, a pip runtime library, an empty cache and
    none of the loader's variables: (library path, system folder)."""
    system = tmp_path / "etc_vendors"
    system.mkdir()
    (system / "pocl.icd").write_text("libpocl.so.2\n")
    lib = tmp_path / "venv" / "lib" / "libintelocl.so"
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"")
    monkeypatch.setattr(icd, "SYSTEM_VENDORS", system)
    monkeypatch.setattr(icd, "pip_runtimes", lambda: {"intel-opencl-rt": lib})
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    for var in ("OCL_ICD_VENDORS", "OPENCL_VENDOR_PATH"):
        monkeypatch.delenv(var, raising=False)
    return lib, system


def test_folder_holds_the_systems_icds_and_the_pip_runtime(fake_system):
    lib, system = fake_system
    folder = icd.register()
    assert os.environ["OCL_ICD_VENDORS"] == str(folder)
    assert sorted(p.name for p in folder.iterdir()) == [
        "clrender-pip-intel-opencl-rt.icd", "pocl.icd"]
    assert (folder / "pocl.icd").read_text() == "libpocl.so.2\n"
    assert icd.registered_libraries() == [lib]
    assert icd.from_pip("Intel(R) OpenCL") == "intel-opencl-rt"
    assert icd.from_pip("Portable Computing Language") is None
    # The same content gives the same folder (written once), a new system ICD a new one.
    del os.environ["OCL_ICD_VENDORS"]
    assert icd.register() == folder
    del os.environ["OCL_ICD_VENDORS"]
    (system / "other.icd").write_text("libother.so\n")
    assert icd.register() != folder


@pytest.mark.parametrize("var", ["OCL_ICD_VENDORS", "OPENCL_VENDOR_PATH"])
def test_the_users_loader_variables_stand(fake_system, monkeypatch, tmp_path, var):
    monkeypatch.setenv(var, str(tmp_path))
    assert icd.register() is None
    assert os.environ[var] == str(tmp_path)
    assert not (tmp_path / "cache").exists()


def test_nothing_registered_without_a_pip_runtime(fake_system, monkeypatch):
    monkeypatch.setattr(icd, "pip_runtimes", dict)
    assert icd.register() is None and "OCL_ICD_VENDORS" not in os.environ
    assert icd.registered_libraries() == []


PROBE = """
import json
import pyopencl as cl
import clrender.device
print(json.dumps([p.name.strip() for p in cl.get_platforms()]))
"""


def test_fresh_process_lists_intel_and_pocl_with_nothing_exported():
    require(bool(icd.pip_runtimes()), "Intel's CPU runtime (pip install intel-opencl-rt "
            "intel-cmplr-lib-rt tbb)")
    require(Path("/etc/OpenCL/vendors/pocl.icd").is_file(), "PoCL (apt install pocl-opencl-icd)")
    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items()
           if k not in ("OCL_ICD_VENDORS", "OPENCL_VENDOR_PATH", "LD_LIBRARY_PATH",
                        "LD_PRELOAD", "CLRENDER_DEVICE")}
    env["PYTHONPATH"] = str(root)
    proc = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                          env=env, cwd=root, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    names = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "Intel(R) OpenCL" in names and "Portable Computing Language" in names, names
