"""Fuzzing the baked NDRF file, as tests/test_baked_fuzz.py fuzzes NGP-RT's: every field of
the manifest's config and every array (wrong shape, wrong dtype, NaN, inf, huge, negative,
empty; face indices out of range) mutated one at a time, and the file's bytes truncated or
flipped.

Each mutant either fails to load with a :class:`BakedFormatError` (a ``ValueError``) whose
message names the file, or loads; every mutant that loads is rendered by both hit sources
(the OpenCL rasteriser and Embree, 24x24) in a subprocess that must finish within a time
limit.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from clrender.ndrf.baked import BakedFormatError, load_baked, save_baked
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from test_baked_fuzz import (ANY_VALUE, _array_variants, _show, _write, byte_mutants,
                             load_outcomes)

RENDER_TIMEOUT_S = 150
VALID_VALUE = {"thresholds": [[1e-4], [1e-4, 1e-3, 1e-2], [1e-2, 1e-4], [0.5, 0.5], [],
                              [1e-4, 1.0], [1e-4, "x"]],
               "hidden": [1, 31, 256, 257], "n_freq": [0, 4, 16, 17],
               "kernel_size": [1, 3], "scene": ["unbounded", "Bounded"]}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """The valid file's manifest (dict) and arrays, and its bytes."""
    model = random_ndrf_model(NDRFConfig(thresholds=(1e-4, 1e-2)), seed=4)
    path = save_baked(model, tmp_path_factory.mktemp("base") / "base.npz")
    with np.load(path, allow_pickle=False) as npz:
        arrays = {n: npz[n] for n in npz.files if n != "manifest"}
        manifest = json.loads(str(npz["manifest"]))
    return manifest, arrays, path.read_bytes()


def _config_mutants(manifest):
    for f in fields(NDRFConfig):
        for value in ANY_VALUE + VALID_VALUE[f.name]:
            yield f"config.{f.name}={_show(value)}", dict(
                manifest, config={**manifest["config"], f.name: value})
        config = dict(manifest["config"])
        del config[f.name]
        yield f"config without {f.name}", dict(manifest, config=config)
    yield "config with an unknown key", dict(manifest, config={**manifest["config"], "Q": 1})
    for value in (None, [], "tiny", 3):
        yield f"config={value!r}", dict(manifest, config=value)


def _array_mutants(arrays):
    for name, a in arrays.items():
        for label, b in _array_variants(a):
            yield f"{name} {label}", {**arrays, name: b}
        yield f"without {name}", {n: v for n, v in arrays.items() if n != name}
        if name.startswith("faces_"):
            V = len(arrays["vertices_" + name.split("_")[1]])
            for value in (V, V + 1000, -2):
                b = a.copy()
                b[len(b) // 3, 1] = value
                yield f"{name} index {value}", {**arrays, name: b}
    yield "an extra array", {**arrays, "extra": np.zeros(3, np.float32)}


def _mutants(base, tmp: Path):
    """Yields (label, path) of every mutant file."""
    manifest, arrays, data = base
    paths = (tmp / f"m{n:04d}.npz" for n in range(10**6))
    for label, man in _config_mutants(manifest):
        yield label, _write(next(paths), man, arrays)
    for label, arr in _array_mutants(arrays):
        yield label, _write(next(paths), manifest, arr)
    yield from byte_mutants(data, lambda: next(paths))


@pytest.fixture(scope="module")
def outcomes(base, tmp_path_factory):
    """[(label, path, error or None)] for every mutant."""
    return load_outcomes(_mutants(base, tmp_path_factory.mktemp("mutants")), load_baked)


def test_every_mutant_is_refused_clearly_or_loads(outcomes):
    unclear = [f"{label}: {type(e).__name__}: {e}" for label, path, e in outcomes
               if e is not None and not (isinstance(e, BakedFormatError) and str(path) in str(e))]
    assert not unclear, "mutants refused without a clear error naming the file:\n" + \
        "\n".join(unclear[:30])
    refused = {label for label, _, e in outcomes if e is not None}
    loaded = {label for label, _, e in outcomes if e is None}
    assert len(outcomes) > 250 and len(loaded) >= 10
    for label in ("faces_0 index 2562", "faces_1 index -2", "faces_0 huge", "vertices_0 nan",
                  "features_1 inf", "conv0_w one short", "background huge", "config.hidden=1.5",
                  "config.kernel_size=3", "config.thresholds=[]", "config.scene='unbounded'",
                  "faces_0 empty", "truncated to 100 bytes"):
        assert label in refused, label


RENDER = """
import sys, time
from clrender.camera import Camera, look_at
from clrender.ndrf.baked import load_baked
from clrender.ndrf.render import Renderer

camera = Camera.from_fov(0.9, 24, 24, look_at((2.2, -1.9, 1.1)))
for path in sys.argv[1:]:
    model = load_baked(path)
    for hits in ("raster", "embree"):
        t = time.perf_counter()
        rgb = Renderer(model, hits=hits).render(camera)["rgb"]
        print("RENDERED", hits, path, rgb.shape, f"{time.perf_counter() - t:.2f}s", flush=True)
"""


def test_loaded_mutants_render_in_bounded_time(outcomes, cl_platform):
    loaded = [(label, str(path)) for label, path, e in outcomes if e is None]
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root),
                                                       os.environ.get("PYTHONPATH", "")]))
    try:
        proc = subprocess.run([sys.executable, "-c", RENDER] + [p for _, p in loaded],
                              capture_output=True, text=True, env=env, cwd=root,
                              timeout=RENDER_TIMEOUT_S)
    except subprocess.TimeoutExpired as e:
        done = e.stdout.decode() if isinstance(e.stdout, bytes) else e.stdout or ""
        n = done.count("RENDERED") // 2
        pytest.fail(f"rendering the loaded mutants took over {RENDER_TIMEOUT_S} s; stuck at "
                    f"{loaded[n][0] if n < len(loaded) else '?'} after {n} models")
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-4000:]
    assert log.count("RENDERED") == 2 * len(loaded), log[-4000:]
