"""Command-line options every benchmark entry point shares (``bench.run``,
``bench.train_curve``), the run's metadata they record and how they record a path."""
from __future__ import annotations

import argparse
import datetime
import os
from pathlib import Path

from clrender.cliopts import whole_number


def add_common(p: argparse.ArgumentParser) -> None:
    """Scene, devices, output, cache and seeds."""
    p.add_argument("--scene", default=None,
                   help="builtin-bounded | builtin-unbounded | a dataset folder (default: the table's)")
    p.add_argument("--downscale", type=whole_number("downscale"), default=1, metavar="N",
                   help="of a --scene folder: read its images_N/, else shrink its images N "
                        "times (default 1)")
    p.add_argument("--device", default=None, help="OpenCL device spec (see `clrender info`)")
    p.add_argument("--torch-device", default=None, help="torch device for training")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--cache", type=Path, default=None,
                   help="model/scene cache folder (default $CLRENDER_CACHE, else "
                        "~/.cache/clrender)")
    p.add_argument("--seed", type=int, default=0, help="training seed (the first one)")
    p.add_argument("--seeds", type=whole_number("seeds"), default=1,
                   help="train and measure for seeds SEED..SEED+N-1 (fixed before the run; "
                        "default 1)")


def run_meta(device: str | None) -> dict:
    """What every results file records: the OpenCL device's name, the git revision, the
    UTC time."""
    from bench.modelcache import provenance
    from clrender.device import get_runtime

    return {"device": get_runtime(device).name, "git_revision": provenance.git_revision(),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def shown_path(path) -> str:
    """``path`` as a run records it, without the machine's folders: relative to the working
    directory where it lies inside it (``data/lego``), else from the home folder
    (``~/.cache/clrender``), else as given (a system, temporary or shared folder)."""
    full = Path(os.path.abspath(Path(path).expanduser()))
    for base, prefix in ((Path.cwd(), None), (Path.home(), Path("~"))):
        if full == base or base in full.parents:
            rel = full.relative_to(base)
            return str(rel if prefix is None else prefix / rel)
    return str(path)


def shown_scene(scene: str, downscale: int = 1) -> str:
    """A ``--scene`` as a run records it: a built-in name as it is, a folder by
    :func:`shown_path`, with `` (downscale N)`` where read downscaled."""
    from bench.modelcache.cache import BUILTIN_SCENES

    name = scene if scene in BUILTIN_SCENES else shown_path(scene)
    return name if downscale == 1 else f"{name} (downscale {downscale})"
