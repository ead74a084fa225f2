"""OpenCL runtimes installed by pip, made visible to the ICD loader beside the system's.

Intel's CPU runtime (``pip install intel-opencl-rt``) puts ``libintelocl.so`` into the
environment's ``lib/``, but the ``.icd`` file it ships names its build prefix
(``/opt/anaconda1anaconda2anaconda3/lib``) and lies where no loader looks, so no platform
appears. What the loaders here honour (ocl-icd 2.3: Debian's ``libOpenCL.so.1`` and the copy
in pyopencl's wheel, which also reads ``$PYOPENCL_HOME/.libs``), checked with both:

* ``OCL_ICD_VENDORS`` naming a folder: its ``*.icd`` files *replace* ``/etc/OpenCL/vendors``;
* ``OCL_ICD_VENDORS`` naming a file, or ``OPENCL_VENDOR_PATH``: that ICD or folder alone;
* ``OCL_ICD_FILENAMES`` (the Khronos loader's "add these"): ignored by both.

So :func:`register` writes a folder holding a copy of every system ``.icd`` file plus one
line naming each pip runtime's library, and points ``OCL_ICD_VENDORS`` at it. The loader
reads the variable at the first platform query (not at ``import pyopencl``), and child
processes inherit it. No library path is needed: ``libintelocl.so`` has ``RUNPATH $ORIGIN``,
so TBB, libimf and the compiler beside it load without ``LD_LIBRARY_PATH``. Nothing is done
when the user set ``OCL_ICD_VENDORS`` or ``OPENCL_VENDOR_PATH`` (their choice stands), or
when no pip runtime is installed. Under Oclgrind the simulator replaces the loader and none
of this is read.
"""
from __future__ import annotations

import hashlib
import os
import site
import sys
import tempfile
from pathlib import Path

from .atomic import atomic_folder

SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
# pip package -> (its runtime library, in the environment's or the user base's lib/; the
# name of the platform it provides).
PIP_RUNTIMES = {"intel-opencl-rt": ("libintelocl.so", "Intel(R) OpenCL")}
# Prefix of the .icd files clrender writes, so device choice can tell them from the system's.
ICD_PREFIX = "clrender-pip-"


def pip_runtimes() -> dict[str, Path]:
    """Installed pip runtimes: {package: absolute library path}."""
    found = {}
    for package, (lib, _) in PIP_RUNTIMES.items():
        for base in (sys.prefix, site.getuserbase()):
            path = Path(base) / "lib" / lib
            if path.is_file():
                found[package] = path.resolve()
                break
    return found


def registered_libraries() -> list[Path]:
    """Libraries that :func:`register` added to this process's loader (empty if none)."""
    folder = os.environ.get("OCL_ICD_VENDORS", "")
    if not folder or not Path(folder).is_dir():
        return []
    return [Path(p.read_text().strip()) for p in sorted(Path(folder).glob(ICD_PREFIX + "*.icd"))]


def from_pip(platform_name: str) -> str | None:
    """The pip package whose runtime :func:`register` added and which provides the platform
    named ``platform_name``; None for the system's (and the user's) platforms."""
    libs = {p.name for p in registered_libraries()}
    for package, (lib, name) in PIP_RUNTIMES.items():
        if platform_name.strip() == name and lib in libs:
            return package
    return None


def _cache_root() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "clrender"


def _write_folder(files: dict[str, str]) -> Path:
    """A folder holding ``files`` ({name: text}), named by their hash and written once,
    atomically (a temporary folder renamed into place)."""
    def write(folder: Path) -> None:
        for name, text in files.items():
            (folder / name).write_text(text)

    digest = hashlib.sha256(repr(sorted(files.items())).encode()).hexdigest()[:16]
    for root in (_cache_root(), Path(tempfile.gettempdir()) / f"clrender-{os.getuid()}"):
        final = root / f"opencl-vendors-{digest}"
        if final.is_dir():
            return final
        try:
            atomic_folder(final, write)
        except OSError:  # unwritable, or another process renamed its copy first
            pass
        if final.is_dir():
            return final
    raise OSError(f"cannot write an OpenCL vendors folder under {_cache_root()} or "
                  f"{tempfile.gettempdir()}")


def register() -> Path | None:
    """Point ``OCL_ICD_VENDORS`` at a folder of the system's ICDs plus the pip runtimes
    (see the module doc); the folder, or None when nothing was done."""
    if os.environ.get("OCL_ICD_VENDORS") or os.environ.get("OPENCL_VENDOR_PATH"):
        return None
    runtimes = pip_runtimes()
    if not runtimes:
        return None
    files = {}
    if SYSTEM_VENDORS.is_dir():
        for icd in sorted(SYSTEM_VENDORS.glob("*.icd")):
            try:
                files[icd.name] = icd.read_text()
            except OSError:
                continue
    for package, lib in runtimes.items():
        files[f"{ICD_PREFIX}{package}.icd"] = f"{lib}\n"
    try:
        folder = _write_folder(files)
    except OSError:
        return None
    os.environ["OCL_ICD_VENDORS"] = str(folder)
    return folder
