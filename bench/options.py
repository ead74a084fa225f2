"""Command-line options every benchmark entry point shares (``bench.run``,
``bench.train_curve``) and the run's metadata they record."""
from __future__ import annotations

import argparse
import datetime
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
