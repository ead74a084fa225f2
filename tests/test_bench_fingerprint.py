"""The model cache knows its code: a change to a method's training sources makes new cache
keys, an edit of comments, docstrings or white space does not (bench/modelcache/fingerprint.py)."""
from __future__ import annotations

import pytest

from bench.modelcache import cache, fingerprint
from clrender import methods
from conftest import replace_bench

PY = '''"""A module."""
import math


def step(x):
    """Half a step."""
    return math.sqrt(x) * 0.5
'''
PY_COMMENTED = PY.replace("import math\n", "import math  # the standard one\n\n") \
    .replace('"""Half a step."""', '"""Half a step: a new docstring."""')
PY_CHANGED = PY.replace("* 0.5", "* 0.25")
CL = "/* header */\nfloat f(float x) { // lerp\n  return x * 0.5f;\n}\n"
CL_COMMENTED = "// new\nfloat f(float x)\n{\n  return x * 0.5f; /* same */\n}\n"
CL_CHANGED = CL.replace("0.5f", "0.25f")


@pytest.fixture
def sources(tmp_path, monkeypatch):
    """NGP-RT with its ``sources`` replaced by a Python file and a kernel folder of tmp_path."""
    (tmp_path / "kernels").mkdir()
    replace_bench(monkeypatch, "ngprt", sources=(tmp_path / "train.py", tmp_path / "kernels"))
    fingerprint.code_fingerprint.cache_clear()
    yield tmp_path
    fingerprint.code_fingerprint.cache_clear()


def _key(root, py: str, cl: str) -> str:
    (root / "train.py").write_text(py)
    (root / "kernels" / "march.cl").write_text(cl)
    fingerprint.code_fingerprint.cache_clear()
    return cache.plan_model(root / "cache", root, "data", "tiny", "ngprt", {}).key


def test_a_source_change_makes_a_new_key_and_a_comment_edit_does_not(sources):
    base = _key(sources, PY, CL)
    assert _key(sources, PY_COMMENTED, CL) == base
    assert _key(sources, PY, CL_COMMENTED) == base
    assert _key(sources, PY_CHANGED, CL) != base
    assert _key(sources, PY, CL_CHANGED) != base
    assert len({_key(sources, PY_CHANGED, CL), _key(sources, PY, CL_CHANGED), base}) == 3


def test_a_missing_source_is_named(sources):
    with pytest.raises(FileNotFoundError, match=r"fingerprinted source .*train.py does not exist"):
        fingerprint.code_fingerprint("ngprt")


def test_every_method_fingerprints_the_files_it_declares():
    for bench in methods.benched().values():
        files = fingerprint._files(bench.sources)
        assert all(path.is_file() for _, path in files)
    shell = {n for n, _ in fingerprint._files(fingerprint.SHELL_SOURCES)}
    ngprt = {n for n, _ in fingerprint._files(methods.bench_of("ngprt").sources)}
    ndrf = {n for n, _ in fingerprint._files(methods.bench_of("ndrf").sources)}
    assert {"data/load.py", "clrender/runs.py", "clrender/camera.py"} <= shell
    assert {"ngprt/train.py", "ngprt/torch_ops.py", "ngprt/fused_grid.cpp"} <= ngprt
    assert {"ndrf/train.py", "ndrf/distill.py", "ngprt/render_cl.py"} <= ndrf
    assert any(n.endswith("/ngprt_march.cl") for n in ndrf)
