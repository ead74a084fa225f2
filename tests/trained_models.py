"""The suite's trained models, each trained once per run (session fixtures that
tests/conftest.py imports), so that every test asking for "a trained `tiny` model" gets
the same one:

- ``tiny_scene``: the built-in bounded scene at test size (seed 1, 12 training and 2 test
  views of 40x40 pixels), a dataset folder;
- ``bench_cache``: the suite's bench model cache (bench/modelcache/cache.py, a folder under
  the session's temporary folder), where the two models below are trained by the
  harness's own ``ensure_model``: a table run on ``tiny_scene`` with ``--cache`` this
  folder reuses them (Table 4's L=2 rows, the ndrf-teacher table) and trains only the rows
  it lacks;
- ``tiny_teacher``: the `tiny` NGP-RT model of ``tiny_scene`` (separate-v, L=2, seed 0,
  the fast engine), {"data", "run", "baked"};
- ``tiny_ndrf_student``: its `tiny` NDRF student, {"scene", "teacher", "run", "student"};
- ``tiny_run``: the `tiny` NGP-RT model of a larger bounded scene (seed 0, 20 training
  views of 48x48; separate-v, L=2, seed 0, the fast engine), {"data", "run", "baked",
  "train", "test"}: its bake at the paper's grids renders >= 30 dB PSNR against its bake
  at the preset's grids, as tests/test_train.py checks (``tiny_teacher``'s does not).

Tests read these models and never change them (a test that bakes or trains again writes
under its own ``tmp_path``; a table run adds models and bakes beside them, as a cache
shared by tables does).
"""
from __future__ import annotations

import pytest

TEACHER = {"variant": "separate-v", "L": 2}       # ndrf-teacher's and Table 4's L=2 rows


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    from clrender.data import make_scene

    return make_scene("bounded", tmp_path_factory.mktemp("tiny_scene") / "scene", seed=1,
                      n_train=12, n_test=2, width=40, height=40)


@pytest.fixture(scope="session")
def bench_cache(tmp_path_factory):
    """The suite's bench model cache folder (models trained into it as asked for)."""
    return tmp_path_factory.mktemp("bench_cache")


def _ensure(bench_cache, tiny_scene, method: str, options: dict):
    """The cache entry of ``method``'s `tiny` model of ``tiny_scene`` (seed 0), trained
    and baked into ``bench_cache`` unless a test (a table run) already did."""
    from bench.modelcache import cache

    return cache.ensure_model(bench_cache, tiny_scene, cache.data_fingerprint(tiny_scene),
                              "tiny", method, options)


@pytest.fixture(scope="session")
def tiny_teacher(bench_cache, tiny_scene):
    entry = _ensure(bench_cache, tiny_scene, "ngprt", TEACHER)
    return {"data": tiny_scene, "run": entry.run_dir, "baked": entry.baked}


@pytest.fixture(scope="session")
def tiny_ndrf_student(bench_cache, tiny_scene, tiny_teacher):
    entry = _ensure(bench_cache, tiny_scene, "ndrf", {"teacher": TEACHER})
    return {"scene": tiny_scene, "teacher": tiny_teacher["baked"], "run": entry.run_dir,
            "student": entry.baked}


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    from clrender.data import load_dataset, make_scene
    from clrender.ngprt.bake import bake_run
    from clrender.ngprt.train import train

    root = tmp_path_factory.mktemp("ngprt_tiny")
    data = make_scene("bounded", root / "scene", seed=0, n_train=20, n_test=2, width=48,
                      height=48)
    run = train(data, root / "run", preset="tiny", variant="separate-v", L=2, seed=0,
                device="cpu", progress=False)
    baked = bake_run(run, root / "model.npz")
    return {"data": data, "run": run, "baked": baked,
            "train": load_dataset(data, split="train"), "test": load_dataset(data, split="test")}
