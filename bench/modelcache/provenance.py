"""What trained a cached model: host, process, library versions and the git revision, recorded
beside the model (``meta.json``'s ``trained_by``) so a table can say which code made it."""
from __future__ import annotations

import os
import platform
import socket
import subprocess
from importlib import metadata
from pathlib import Path

from clrender import methods

# Distributions whose versions can change any trained model or its measurement (each method
# adds its own, its bench spec's libraries).
LIBRARIES = ("clrender", "torch", "numpy", "scipy", "pyopencl", "ray")


def git_revision() -> str:
    """The short git revision of this checkout (``+dirty`` when tracked files differ from
    it), ``unknown`` outside a git work tree."""
    here = Path(__file__).parent
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True, cwd=here).stdout.strip()
        dirty = subprocess.run(["git", "diff", "--quiet", "HEAD"], cwd=here).returncode != 0
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return rev + ("+dirty" if dirty else "")


def versions() -> dict[str, str]:
    """{distribution: version} of :data:`LIBRARIES` and every method's that are installed,
    plus Python's."""
    found = {"python": platform.python_version()}
    extra = [lib for bench in methods.benched().values() for lib in bench.libraries]
    for name in dict.fromkeys([*LIBRARIES, *extra]):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return found


def trained_by(torch_device: str, torch_threads: int, revision: str | None = None) -> dict:
    """The record of the process training a model now: host, pid, torch device and threads,
    library versions, git revision (``revision``: the driver's, for code a Ray worker runs
    from an uploaded copy without ``.git``; default this checkout's)."""
    return {"host": socket.gethostname(), "pid": os.getpid(), "torch_device": torch_device,
            "torch_threads": int(torch_threads), "versions": versions(),
            "git_revision": revision or git_revision()}
