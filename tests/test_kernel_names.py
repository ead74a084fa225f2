"""Kernel functions named like their references (docs/ngprt.md "Kernel functions and their
references", the convention; docs/ndrf.md, NDRF's table).

The tables in the two docs are parsed and held to ``kernels/`` and the Python modules: every
device function and entry point of ``kernels/`` is listed under its file, every listed one
exists there, every reference imports, a device function computing a reference whole has its
name (leading underscore dropped), no device function keeps a method prefix, structs are
CamelCase, and no two functions of one program (a ``.cl`` file and the headers it includes)
share a name. Source text only: nothing is built or run.
"""
from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KERNELS = ROOT / "kernels"
# doc -> the packages its references are modules of, tried in order
DOCS = {"ngprt.md": ("clrender.ngprt", "clrender"), "ndrf.md": ("clrender.ndrf", "clrender")}
SECTION = "## Kernel functions and their references"
OLD_PREFIXES = ("v_", "ngp_", "ndrf_")

# A top-level function definition: a line at column 0 with a return type, the name, the
# parameters (no ; { }) and the body's brace. `__attribute__((...))` is not a name.
_DEFINITION = re.compile(r"^[A-Za-z_][\w \t*]*?\b(?!__)(\w+)\s*\(([^;{}]*?)\)\s*\{", re.M | re.S)
_STRUCT = re.compile(r"typedef\s+struct\s*\w*\s*\{[^{}]*\}\s*(\w+)\s*;", re.S)
_INCLUDE = re.compile(r'^#include\s+"([^"]+)"', re.M)


def _source(name: str) -> str:
    """kernels/<name> without its comments."""
    text = (KERNELS / name).read_text()
    return re.sub(r"//[^\n]*", "", re.sub(r"/\*.*?\*/", " ", text, flags=re.S))


def _functions(name: str) -> list[tuple[str, bool]]:
    """(function, is an entry point) of each definition in kernels/<name>, in order."""
    text, out = _source(name), []
    for m in _DEFINITION.finditer(text):
        line_start = text.rfind("\n", 0, m.start(1)) + 1
        previous = text[text.rfind("\n", 0, max(line_start - 1, 0)) + 1:line_start]
        out.append((m.group(1), "__kernel" in previous + text[line_start:m.start(1)]))
    return out


def _kernel_files() -> list[str]:
    return sorted(p.name for p in KERNELS.iterdir() if p.suffix in (".cl", ".h"))


def _rows(doc: str) -> list[dict]:
    """The table of a doc's SECTION: one dict per listed function."""
    text = (ROOT / "docs" / doc).read_text()
    assert text.count(SECTION) == 1, f"docs/{doc}: expected one '{SECTION}' section"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    lines = [ln for ln in section.splitlines() if ln.startswith("|")]
    assert lines[0].replace(" ", "") == "|kernelfunction|file|reference|what|", lines[0]
    rows = []
    for ln in lines[2:]:
        names, file, reference, _what = (c.strip() for c in ln.strip().strip("|").split("|"))
        part = reference.startswith("part of ")
        ref = re.fullmatch(r"(?:part of )?`([\w.]+)`|none", reference)
        assert ref, f"docs/{doc}: reference {reference!r}: expected `module.function`, " \
                    "part of `module.function` or none"
        for name in re.findall(r"`(\w+)`", names):
            rows.append({"doc": doc, "name": name, "file": file.strip("`"),
                         "reference": ref.group(1), "part": part})
    return rows


ROWS = [row for doc in DOCS for row in _rows(doc)]


def _resolve(doc: str, dotted: str):
    """The object a table's `module.attr[.attr]` names, its module under DOCS[doc]."""
    parts = dotted.split(".")
    for package in DOCS[doc]:
        for i in range(len(parts) - 1, 0, -1):
            try:
                obj = importlib.import_module(f"{package}.{'.'.join(parts[:i])}")
            except ModuleNotFoundError:
                continue
            for attr in parts[i:]:
                obj = getattr(obj, attr, None)
            if obj is not None:
                return obj
    return None


def test_every_kernel_function_is_in_a_table_once():
    defined = {(f, name) for f in _kernel_files() for name, _ in _functions(f)}
    listed = [(row["file"], row["name"]) for row in ROWS]
    assert len(listed) == len(set(listed)), "listed twice: " + str(
        sorted({x for x in listed if listed.count(x) > 1}))
    assert not set(listed) - defined, f"listed, not in kernels/: {sorted(set(listed) - defined)}"
    assert not defined - set(listed), ("in kernels/, not in docs/ngprt.md's or docs/ndrf.md's "
                                       f"table: {sorted(defined - set(listed))}")


@pytest.mark.parametrize("row", [r for r in ROWS if r["reference"]],
                         ids=lambda r: f"{r['file']}:{r['name']}")
def test_references_exist_and_give_their_names(row):
    obj = _resolve(row["doc"], row["reference"])
    assert obj is not None, (f"docs/{row['doc']}: {row['name']}'s reference "
                             f"{row['reference']} is not in {' or '.join(DOCS[row['doc']])}")
    entry = dict(_functions(row["file"]))[row["name"]]
    if not row["part"] and not entry:
        ref_name = row["reference"].rsplit(".", 1)[1].lstrip("_")
        assert row["name"] == ref_name, (f"kernels/{row['file']}: {row['name']} computes "
                                         f"{row['reference']}: expected the name {ref_name}")


def test_no_method_prefix_on_device_functions_and_camel_case_structs():
    prefixed = [f"{f}:{name}" for f in _kernel_files() for name, entry in _functions(f)
                if not entry and name.startswith(OLD_PREFIXES)]
    assert not prefixed, f"device functions with a method prefix: {prefixed}"
    structs = [f"{f}:{name}" for f in _kernel_files() for name in _STRUCT.findall(_source(f))
               if not re.fullmatch(r"[A-Z][A-Za-z0-9]*", name)]
    assert not structs, f"structs not CamelCase: {structs}"


@pytest.mark.parametrize("program", [f for f in _kernel_files() if f.endswith(".cl")])
def test_no_two_functions_of_a_program_share_a_name(program):
    seen, todo, names = set(), [program], []
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        names += [name for name, _ in _functions(f)]
        todo += _INCLUDE.findall((KERNELS / f).read_text())
    assert len(names) == len(set(names)), (
        f"kernels/{program}: defined twice: {sorted({n for n in names if names.count(n) > 1})}")
