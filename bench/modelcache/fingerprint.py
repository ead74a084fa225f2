"""Which code trained a model: a hash of the normalised text of a method's training sources
(its bench spec's ``sources``), so the model cache serves a model only to the code that
would train it again (bench/modelcache/cache.py).

Normalised: Python by its syntax tree without docstrings (comments, blank lines, line breaks
and docstrings do not count), OpenCL C with its comments removed and runs of white space as
one; any other file by its bytes. A comment edit keeps every key; any change to what runs
makes new ones.

Examples:
    >>> code_fingerprint("ngprt")        # 16 hex digits: its sources and torch's version
"""
from __future__ import annotations

import ast
import functools
import hashlib
import re
from pathlib import Path

from clrender import methods

C_COMMENT = re.compile(r"//[^\n]*|/\*.*?\*/", re.S)
_CLRENDER = Path(methods.__file__).resolve().parent
# What every method's training runs of the shell: the data loaders, cameras, the run folder.
SHELL_SOURCES = (_CLRENDER / "data", _CLRENDER / "camera.py", _CLRENDER / "runs.py")


def normalised(path: Path) -> bytes:
    """The text of one source file as it counts for the fingerprint."""
    text = path.read_bytes()
    if path.suffix == ".py":
        tree = ast.parse(text, filename=str(path))
        for node in ast.walk(tree):
            body = getattr(node, "body", None)
            if (isinstance(body, list) and body and isinstance(body[0], ast.Expr)
                    and isinstance(body[0].value, ast.Constant)
                    and isinstance(body[0].value.value, str)):
                node.body = body[1:] or [ast.Pass()]
        return ast.dump(tree).encode()
    if path.suffix in (".cl", ".h"):
        return " ".join(C_COMMENT.sub(" ", text.decode()).split()).encode()
    return text


def _files(sources) -> list[tuple[str, Path]]:
    """(name, path) of every file of ``sources`` (files, or folders read recursively for
    .py/.cl/.h files), sorted; the name is the path from the source's parent folder
    (``ngprt/train.py``, ``kernels/ngprt_march.cl``)."""
    found = {}
    for src in map(Path, sources):
        if not src.exists():
            raise FileNotFoundError(f"fingerprinted source {src} does not exist")
        files = ([src] if src.is_file() else
                 [f for f in src.rglob("*") if f.suffix in (".py", ".cl", ".h")])
        for f in files:
            found[str(f.relative_to(src.parent.parent if src.is_file() else src.parent))] = f
    return sorted(found.items())


def source_fingerprint(sources) -> str:
    """sha256 (16 hex digits) over the names and normalised text of ``sources``."""
    h = hashlib.sha256()
    for name, path in _files(sources):
        h.update(name.encode() + b"\0" + normalised(path) + b"\0")
    return h.hexdigest()[:16]


@functools.lru_cache(maxsize=None)
def code_fingerprint(method: str) -> str:
    """The fingerprint of what trains a model of ``method``: its declared ``sources``, the
    shell's :data:`SHELL_SOURCES` and the torch version (cached per process: the sources do
    not change under a run)."""
    import torch

    sources = (*methods.bench_of(method).sources, *SHELL_SOURCES)
    return hashlib.sha256(f"{source_fingerprint(sources)} torch={torch.__version__}"
                          .encode()).hexdigest()[:16]
