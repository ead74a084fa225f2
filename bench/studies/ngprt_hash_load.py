"""How crowded a trained NGP-RT model's fine hash tables are: the collision load per level.

    python -m bench.studies.ngprt_hash_load model.npz [more.npz ...]
    python -m bench.studies.ngprt_hash_load model.npz --log2-T 18     # the same space, 2^18 entries

The attention of NGP-RT exists to disambiguate hash collisions (ngp-rt.md §3.2, S3.1):
positions of different content that share a table entry. A sample in occupied space
reads the corners of its fine cell, so a level's load is ``alpha = N / T``: the ``N`` distinct
vertices of the level's grid (resolution ``L_C * 2^(l+1)``) on the closed occupied
``occupancy_0`` cells, over its ``T`` table entries. ``N`` is counted exactly from the
occupied coarse cells and the faces, edges and corners they touch (a coarse cell split
``f`` times per axis holds ``(f-1)^3`` interior vertices, a face ``(f-1)^2``, an edge
``f - 1``). Under a uniform hash, ``1 - (1 - 1/T)^(N-1)`` (about ``1 - exp(-alpha)``) of
those vertices share their entry with another: at ``alpha`` well above 1 nearly all do.
Never asserts; prints a table and returns its rows.
"""
from __future__ import annotations

import argparse
import math

import numpy as np

from clrender.ngprt.baked import load_baked


def _touched(occ: np.ndarray, axes: tuple[int, ...]) -> int:
    """Elements of the occupied cells' closure that span the cell axes not in ``axes``:
    the grid is padded by one cell and OR-ed with its shift along each axis in ``axes``
    (the cells on either side of a face, around an edge or a corner), then counted."""
    grid = np.pad(occ, 1)
    for a in axes:
        grid = grid[(slice(None),) * a + (slice(1, None),)] | \
            grid[(slice(None),) * a + (slice(None, -1),)]
    return int(grid.sum())


def occupied_vertices(occupancy_0: np.ndarray, split: int) -> int:
    """Distinct vertices of the grid ``split`` times finer than ``occupancy_0`` (L_C^3, 0/1)
    that lie on the closed occupied cells."""
    occ = np.asarray(occupancy_0) != 0
    cells = int(occ.sum())
    faces = sum(_touched(occ, (a,)) for a in range(3))
    edges = sum(_touched(occ, tuple(b for b in range(3) if b != a)) for a in range(3))
    corners = _touched(occ, (0, 1, 2))
    m = split - 1
    return cells * m ** 3 + faces * m ** 2 + edges * m + corners


def hash_load(model, T: int | None = None) -> list[dict]:
    """Per fine level of a baked NGP-RT model: ``{level, resolution, vertices, T, alpha,
    shared}``, ``shared`` the expected fraction of occupied vertices whose table entry
    another occupied vertex also uses (uniform hash); ``T`` entries a table instead of the
    model's (another preset's tables over the same occupied space)."""
    cfg, occ = model.config, model.arrays["occupancy_0"]
    T = T or cfg.T
    rows = []
    for level, res in enumerate(cfg.fine_resolutions):
        n = occupied_vertices(occ, res // cfg.L_C)
        rows.append({"level": level, "resolution": res, "vertices": n, "T": T,
                     "alpha": n / T, "shared": -math.expm1((n - 1) * math.log1p(-1.0 / T))})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.studies.ngprt_hash_load", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("models", nargs="+", help="baked NGP-RT models (.npz)")
    p.add_argument("--log2-T", type=int, default=None, metavar="N",
                   help="count against 2^N entries a table instead of the model's")
    args = p.parse_args(argv)
    for path in args.models:
        model = load_baked(path)
        occ = model.arrays["occupancy_0"]
        print(f"{path}: L_C {model.config.L_C}, {int(np.count_nonzero(occ))} of "
              f"{occ.size} coarse cells occupied ({np.count_nonzero(occ) / occ.size:.1%})")
        print(f"{'level':>5s} {'resolution':>10s} {'vertices':>12s} {'T':>9s} "
              f"{'alpha':>8s} {'shared':>7s}")
        for r in hash_load(model, None if args.log2_T is None else 1 << args.log2_T):
            print(f"{r['level']:5d} {r['resolution']:10d} {r['vertices']:12d} {r['T']:9d} "
                  f"{r['alpha']:8.2f} {r['shared']:7.1%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
