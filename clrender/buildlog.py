"""A program build whose compiler-output warning stands unless the log is only a driver's
informational lines.

pyopencl warns (``CompilerWarning``) whenever a build log is not empty. Intel's CPU runtime
writes a log for every build: its progress ("Compilation started", "Device build done"),
the backend options, the vectoriser's report per kernel and LLVM's optimisation remarks,
and, for a kernel that declares its lanes with ``vec_type_hint`` of a vector type, the
notice that it is not vectorised across work-items, which is what the hint asks for
(docs/explanation/opencl.md, "Each kernel in its own lanes on both"). None of that can be silenced
from the kernel source. :func:`build` drops the warning only where every line of every
log it carries is one of those; any other line (a real compiler warning) keeps it, whole.

Examples:
    >>> program = build(context, source, ["-DRAYS=16"])
    >>> informational(log, source)       # True for Intel's progress and vectoriser lines
"""
from __future__ import annotations

import os
import re
import warnings

# Intel's CPU runtime (the release docs/explanation/opencl.md names): what it writes for a clean build.
_INFO = re.compile("|".join([
    r"(Compilation|Linking|Device build) (started|done)",
    r"Options used by backend compiler: .*",
    r"Kernel \"?\w+\"? was (successfully |not )?vectorized( \(\d+\))?",
    r"remark: .*",
    r"Done\.",
    r"Reload Program Binary Object\.",
]))
OUTPUT = "PYOPENCL_COMPILER_OUTPUT"
GENERIC = ("Non-empty compiler output encountered. Set the environment variable "
           "PYOPENCL_COMPILER_OUTPUT=1 to see more.")     # pyopencl's words without the log
_HINT = re.compile(r"warning: kernel \"(\w+)\": Kernel can't be vectorized due to unsupported "
                   r"vec type hint")


def _declares_lanes(source: str, kernel: str) -> bool:
    """Whether ``kernel`` is declared with a ``vec_type_hint`` attribute in ``source``."""
    return re.search(r"vec_type_hint\s*\(\s*\w+\s*\)\s*\)\s*\)\s*void\s+" + re.escape(kernel)
                     + r"\s*\(", source) is not None


def informational(log: str, source: str) -> bool:
    """Whether every non-blank line of a build ``log`` of ``source`` is a driver's
    informational line (progress, options, the vectoriser's report, remarks, or the
    vec_type_hint notice for a kernel that declares one)."""
    for line in filter(None, (s.strip() for s in log.splitlines())):
        hint = _HINT.fullmatch(line)
        if hint is not None:
            if not _declares_lanes(source, hint.group(1)):
                return False
        elif _INFO.fullmatch(line) is None:
            return False
    return True


def logs(message: str) -> list[str]:
    """The build logs in the text of a pyopencl compiler-output warning, one a device
    ("Build on <device> succeeded, but said:" then the log); [] where there is none."""
    return re.split(r"^Build on <.*> succeeded, but said:$", message, flags=re.M)[1:]


def build(context: "cl.Context", source: str, options: list[str] | tuple = ()) -> "cl.Program":
    """``cl.Program(context, source).build(options=options)``; each ``CompilerWarning`` it
    raised is issued again unless :func:`informational` holds for every log it carries
    (a fresh build's, or the original build's where pyopencl's cache served the program).
    pyopencl is asked for the logs in the warnings' text during the build
    (``PYOPENCL_COMPILER_OUTPUT``); a warning issued again reads as it would have without
    that. Other warnings are issued again unchanged."""
    import pyopencl as cl  # here: clrender.device registers the ICDs before pyopencl loads

    asked = os.environ.get(OUTPUT)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        os.environ[OUTPUT] = "1"
        try:
            program = cl.Program(context, source).build(options=list(options))
        finally:
            if asked is None:
                del os.environ[OUTPUT]
            else:
                os.environ[OUTPUT] = asked
    for w in caught:
        message = w.message
        if issubclass(w.category, cl.CompilerWarning):
            found = logs(str(message))
            if found and all(informational(log, source) for log in found):
                continue
            if (asked or "0").strip().lower() not in ("1", "true", "yes", "on", "y", "t"):
                message = cl.CompilerWarning(GENERIC)
        warnings.warn_explicit(message, w.category, w.filename, w.lineno, source=w.source)
    return program
