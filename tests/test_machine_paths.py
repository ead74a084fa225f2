"""No absolute path of the machine that made a page or a run: the README, docs/**/*.md,
the committed runs (docs/results/*.json) and the docstrings of clrender/ and bench/ name a
folder as a user types it (relative to the working directory, ``~/...``, a public scene's
name). System folders (/etc, /usr, /dev, /proc, /opt, /sys), temporary folders (/tmp,
/var/tmp) and a cluster's shared folders given as examples (/mnt, /nfs, /shared) are
allowed: the pattern names only a machine's user and work folders."""
import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# /root, /home/<user>, /Users/<user>, /work: a user's or a work machine's folders.
MACHINE = re.compile(r"(?<![\w.~$/-])/(?:root|work|home/[\w.-]+|Users/[\w.-]+)(?![\w.-])")


def machine_paths(text: str) -> list[str]:
    """The machine paths in ``text``, each with the rest of its line."""
    return [text[m.start():].split("\n", 1)[0][:80] for m in MACHINE.finditer(text)]


def _docstrings(path: Path) -> str:
    tree = ast.parse(path.read_text(), str(path))
    nodes = [tree] + [n for n in ast.walk(tree)
                      if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))]
    return "\n".join(ast.get_docstring(n, clean=False) or "" for n in nodes)


def _files():
    yield from [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")),
                *sorted((ROOT / "docs" / "results").glob("*.json"))]


@pytest.mark.parametrize("text, found", [
    ("scene /work/data/lego here", ["/work/data/lego here"]),
    ("cache at /root/.cache/clrender", ["/root/.cache/clrender"]),
    ('"/home/alice/x"', ['/home/alice/x"']), ("/Users/bob", ["/Users/bob"]),
    ("/work", ["/work"]),
    ("/etc/OpenCL/vendors, /usr/lib, /dev/dri, /tmp/x, /mnt/shared/cache, /nfs/c", []),
    ("~/work/data, data/work, ./work, $HOME/work, /workspace, /rooted, a/root/b", []),
])
def test_the_pattern_finds_user_and_work_folders_only(text, found):
    assert machine_paths(text) == found


@pytest.mark.parametrize("path", list(_files()), ids=lambda p: str(p.relative_to(ROOT)))
def test_pages_and_runs_name_no_machine_path(path):
    assert machine_paths(path.read_text()) == [], f"{path.relative_to(ROOT)}: machine paths"


@pytest.mark.parametrize("package", ["clrender", "bench"])
def test_docstrings_name_no_machine_path(package):
    found = {str(p.relative_to(ROOT)): hits for p in sorted((ROOT / package).rglob("*.py"))
             if (hits := machine_paths(_docstrings(p)))}
    assert found == {}
