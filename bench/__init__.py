"""Benchmarks: each module writes results/ files and prints tables; none asserts.

They train the models they measure, so they need the ``bench`` extra (torch, the mesh
libraries, matplotlib, filelock): without it ``python -m bench.*`` says so in one line and
exits with status 2."""
import sys

from clrender.extras import MissingExtra, require

try:
    require("bench", "python -m bench")
except MissingExtra as _exc:
    print(f"bench: error: {_exc}", file=sys.stderr)
    sys.exit(2)
