"""Fuzzing the baked NGP-RT file: every field of the manifest's config, gamma, and every
array (wrong shape, wrong dtype, NaN, inf, huge, negative, empty) mutated one at a time,
and the file's bytes truncated or flipped.

Each mutant either fails to load with a :class:`BakedFormatError` (a ``ValueError``)
whose message names the file, or loads; every mutant that loads is rendered by the
OpenCL renderer (16x16) in a subprocess that must finish within a time limit, so a
march that runs away (a tiny step, an int overflow) fails the test instead of hanging it.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from clrender.ngprt.baked import load_baked, save_baked
from clrender.ngprt.config import ModelConfig, preset
from clrender.ngprt.random_model import random_baked_model

RENDER_TIMEOUT_S = 150
# Values for any config field: wrong kinds, zero, negative, non-integer, huge, non-finite.
ANY_VALUE = [0, -1, -3.5, 1.5, 10**30, 1e300, math.inf, -math.inf, math.nan, None, True, "x",
             [2], {"a": 1}]
# Valid values that change the meaning (shapes then disagree, or the file loads).
VALID_VALUE = {"L": [1, 3, 30], "L_C": [32, 48, 1024, 2048], "log2_T": [4, 9, 24, 25],
               "variant": ["sum", "mlp", "shared-v", "separate-inv", "Separate-V"],
               "scene": ["unbounded", "Bounded"], "G_res": [1, 4, 16, 32],
               "coarse_block": [1, 2, 16, 32], "near": [0.0, 0.5, 5.0, 1e30],
               "far": [0.06, 2.0, 1e30], "aux_levels": [1, 64], "aux_min_res": [1, 10**6],
               "aux_log2_T": [4, 30], "aux_features": [1], "aux_hidden": [1],
               "step_res": [1, 64, 512, 10**7], "occupancy_res": [16, 32, 48, 64, 2048]}
GAMMAS = [0, 0.0, -1.0, 1e-9, 1e-30, 5e-324, math.nan, math.inf, -math.inf, 1e300, 10**400,
          "1.0", True, None, [1.0], 1e-3, 0.3, 1e6, 3e38]


def _show(value) -> str:
    """repr, with huge ints as powers of ten."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**20:
        return f"10**{len(str(abs(value))) - 1}"
    return repr(value)


def _config():
    return preset("tiny", variant="separate-v", L=2, L_C=16, G_res=8, log2_T=8)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """The valid file's manifest (dict) and arrays, and its bytes."""
    path = save_baked(random_baked_model(_config(), seed=4, gamma=1.0),
                      tmp_path_factory.mktemp("base") / "base.npz")
    with np.load(path, allow_pickle=False) as npz:
        arrays = {n: npz[n] for n in npz.files if n != "manifest"}
        manifest = json.loads(str(npz["manifest"]))
    return manifest, arrays, path.read_bytes()


def _listing(arrays):
    return {n: {"shape": list(a.shape), "dtype": str(a.dtype)} for n, a in arrays.items()}


def _write(path: Path, manifest: dict, arrays: dict) -> Path:
    manifest = dict(manifest, arrays=_listing(arrays))
    np.savez(path, manifest=np.array(json.dumps(manifest)), **arrays)
    return path


def _config_mutants(manifest):
    for f in fields(ModelConfig):
        for value in ANY_VALUE + VALID_VALUE[f.name]:
            yield f"config.{f.name}={_show(value)}", dict(manifest, config={**manifest["config"],
                                                                      f.name: value}), None
        config = dict(manifest["config"])
        del config[f.name]
        yield f"config without {f.name}", dict(manifest, config=config), None
    yield "config with an unknown key", dict(manifest, config={**manifest["config"], "Q": 1}), None
    for value in (None, [], "tiny", 3):
        yield f"config={value!r}", dict(manifest, config=value), None


def _array_variants(a: np.ndarray):
    """(label, mutated copy) pairs for one array."""
    yield "one short", a.reshape(-1)[:-1].copy() if a.size else np.zeros(1, a.dtype)
    yield "extra axis", a[None].copy()
    yield "empty", a[:0].copy()
    for dt in ((np.float64, np.float16, np.int32) if a.dtype.kind == "f" else
               (np.int64, np.float32, np.uint8) if a.dtype == np.int32 else
               (np.int8, np.bool_, np.int32)):
        yield f"as {np.dtype(dt).name}", a.astype(dt)
    if a.size == 0:
        return
    if a.dtype.kind == "f":
        specials = [("nan", np.nan), ("inf", np.inf), ("-inf", -np.inf), ("huge", 3e38),
                    ("negative huge", -3e38), ("all huge", None)]
    elif a.dtype == np.int32:
        specials = [("huge", 2**31 - 1), ("negative", -7), ("all -1", None)]
    else:
        specials = [("huge", 255), ("2", 2), ("all 1", None)]
    for label, value in specials:
        b = a.copy()
        if value is None:
            b[...] = 3e38 if a.dtype.kind == "f" else (-1 if a.dtype == np.int32 else 1)
        else:
            b.flat[b.size // 2] = value
        yield label, b


def _array_mutants(manifest, arrays):
    for name, a in arrays.items():
        for label, b in _array_variants(a):
            yield f"{name} {label}", manifest, {**arrays, name: b}
        yield f"without {name}", manifest, {n: v for n, v in arrays.items() if n != name}
    yield "an extra array", manifest, {**arrays, "extra": np.zeros(3, np.float32)}


def _mutants(base, tmp: Path):
    """Yields (label, path) of every mutant file."""
    manifest, arrays, data = base
    n = 0

    def out():
        nonlocal n
        n += 1
        return tmp / f"m{n:04d}.npz"

    for label, man, arr in _config_mutants(manifest):
        yield label, _write(out(), man, arr if arr is not None else arrays)
    for gamma in GAMMAS:
        yield f"gamma={_show(gamma)}", _write(out(), dict(manifest, gamma=gamma), arrays)
    for factor in (0.99, 1.01):     # either side of the lattice bound (the longest march)
        gamma = _config().min_gamma * factor
        yield f"gamma=min_gamma*{factor}", _write(out(), dict(manifest, gamma=gamma), arrays)
    yield "no gamma", _write(out(), {k: v for k, v in manifest.items() if k != "gamma"}, arrays)
    for label, man, arr in _array_mutants(manifest, arrays):
        yield label, _write(out(), man, arr)
    yield from byte_mutants(data, out)


def byte_mutants(data: bytes, new_path):
    """(label, path) of ``data`` (a valid file's bytes) truncated and with bytes flipped,
    each written to a fresh ``new_path()``."""
    for cut in (0, 1, 22, 100, len(data) // 4, len(data) // 2, len(data) - 30, len(data) - 1):
        path = new_path()
        path.write_bytes(data[:cut])
        yield f"truncated to {cut} bytes", path
    rng = np.random.default_rng(0)
    # Zip headers at both ends (local header, central directory, end record) and data.
    for pos in [0, 4, 8, 18, 26, 30, len(data) - 22, len(data) - 12, len(data) - 6,
                len(data) - 60] + list(rng.integers(0, len(data), 8)):
        path, flipped = new_path(), bytearray(data)
        flipped[pos] ^= 0x5A
        path.write_bytes(bytes(flipped))
        yield f"byte {pos} flipped", path


def load_outcomes(mutants, load) -> list:
    """[(label, path, error or None)]: each (label, path) of ``mutants`` loaded by ``load``;
    any exception is kept, to be judged by the test."""
    out = []
    for label, path in mutants:
        try:
            load(path)
            out.append((label, path, None))
        except Exception as e:          # noqa: BLE001 - anything else is a finding
            out.append((label, path, e))
    return out


@pytest.fixture(scope="module")
def outcomes(base, tmp_path_factory):
    """[(label, path, error or None)] for every mutant."""
    return load_outcomes(_mutants(base, tmp_path_factory.mktemp("mutants")), load_baked)


def test_every_mutant_is_refused_clearly_or_loads(outcomes):
    unclear = [f"{label}: {type(e).__name__}: {e}" for label, path, e in outcomes
               if e is not None and not (isinstance(e, ValueError) and str(path) in str(e))]
    assert not unclear, "mutants refused without a clear error naming the file:\n" + \
        "\n".join(unclear[:30])
    refused = {label for label, _, e in outcomes if e is not None}
    loaded = {label for label, _, e in outcomes if e is None}
    assert len(outcomes) > 300 and len(loaded) >= 10
    assert "gamma=min_gamma*1.01" in loaded
    # The holes this file was written for.
    for label in ("gamma=1e-09", "gamma=5e-324", "gamma=10**400", "gamma='1.0'", "gamma=True",
                  "gamma=1e+300", "config.L_C=0", "config.L_C=1.5", "config.coarse_block=0",
                  "config.L=30", "config.L=10**30", "config.far=inf", "config.near=nan",
                  "config.G_res=0", "config.aux_levels=0", "config.L=True",
                  "config.aux_log2_T=30", "config.aux_levels=10**30", "gamma=min_gamma*0.99",
                  "config.aux_min_res=1000000", "config.far=1e+300", "config.far=1e+30",
                  "config.step_res=0", "config.step_res=1.5", "config.step_res=True",
                  "config.step_res=10000000"):
        assert label in refused, label


RENDER = """
import sys, time
from clrender.camera import Camera, look_at
from clrender.ngprt.baked import load_baked
from clrender.ngprt.render_cl import Renderer

eyes = {"bounded": (0.3, -2.5, 1.2), "unbounded": (0.2, -0.6, 0.3)}
for path in sys.argv[1:]:
    model = load_baked(path)
    camera = Camera.from_fov(1.0, 16, 16, look_at(eyes[model.config.scene]))
    t = time.perf_counter()
    rgb = Renderer(model).render(camera)["rgb"]
    print("RENDERED", path, rgb.shape, f"{time.perf_counter() - t:.2f}s", flush=True)
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
        proc, done = None, e.stdout.decode() if isinstance(e.stdout, bytes) else e.stdout or ""
    if proc is None:
        n = done.count("RENDERED")
        pytest.fail(f"rendering the loaded mutants took over {RENDER_TIMEOUT_S} s; stuck at "
                    f"{loaded[n][0] if n < len(loaded) else '?'} after {n} renders")
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-4000:]
    assert log.count("RENDERED") == len(loaded), log[-4000:]
