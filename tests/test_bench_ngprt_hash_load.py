"""bench.studies.ngprt_hash_load: the exact count of fine vertices on the occupied cells, the load."""
import itertools

import numpy as np
import pytest

from bench.studies.ngprt_hash_load import hash_load, occupied_vertices
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model


def _brute_force(occ: np.ndarray, split: int) -> int:
    points = set()
    for i, j, k in zip(*np.nonzero(occ)):
        for a, b, c in itertools.product(range(split + 1), repeat=3):
            points.add((i * split + a, j * split + b, k * split + c))
    return len(points)


@pytest.mark.parametrize("split", [1, 2, 3, 5])
def test_occupied_vertices_match_a_brute_force_count(split):
    rng = np.random.default_rng(split)
    occ = (rng.random((5, 4, 6)) < 0.3).astype(np.uint8)
    assert occupied_vertices(occ, split) == _brute_force(occ, split)
    one = np.zeros((3, 3, 3), np.uint8)
    one[1, 1, 1] = 1
    assert occupied_vertices(one, split) == (split + 1) ** 3
    one[1, 1, 2] = 1              # two cells sharing a face
    assert occupied_vertices(one, split) == (2 * split + 1) * (split + 1) ** 2


def test_hash_load_per_level_of_a_model():
    model = random_baked_model(preset("tiny", L=2), seed=0)
    occ, cfg = model.arrays["occupancy_0"], model.config
    rows = hash_load(model)
    assert [r["resolution"] for r in rows] == list(cfg.fine_resolutions)
    for r in rows:
        n = _brute_force(occ, r["resolution"] // cfg.L_C) if r["level"] == 0 else r["vertices"]
        assert r["vertices"] == n and r["alpha"] == pytest.approx(n / cfg.T)
        assert r["shared"] == pytest.approx(1 - (1 - 1 / cfg.T) ** (n - 1))
    assert rows[1]["vertices"] > rows[0]["vertices"]
    half = hash_load(model, T=cfg.T // 2)
    assert [r["alpha"] for r in half] == pytest.approx([2 * r["alpha"] for r in rows])
