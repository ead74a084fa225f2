"""Write files and folders so that readers never see them half-written: a temporary one in
the same folder, then a rename onto the target (atomic on one file system)."""
from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Callable


# atomic_write's temporary names: "." + target name + "." + mkstemp's 8 characters + suffix.
_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}(?P<suffix>\.[^.]*)?$")


def atomic_write(path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp)`` on a temporary path beside ``path``, then move it into place.

    The temporary file keeps ``path``'s suffix (writers that pick a format by suffix, like
    imageio, see the right one) and is removed if ``write`` fails. The result is readable
    like a normal file (0644; mkstemp creates 0600). Missing parent folders are created.
    Returns ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix,
                               dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_folder(path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp)`` on a temporary folder beside ``path`` (``.<name>.<random>``),
    then rename it to ``path``, which must not exist or be empty (no rename replaces a
    folder with content: remove it first, under a lock where others may read it). The
    temporary folder is removed if ``write`` or the rename fails (OSError where ``path``
    appeared meanwhile). Returns ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        os.chmod(tmp, 0o755)
        write(tmp)
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def write_atomic(path, data: bytes | str) -> Path:
    """Write bytes or text (UTF-8) to ``path`` atomically; see :func:`atomic_write`."""
    raw = data.encode() if isinstance(data, str) else data
    return atomic_write(path, lambda tmp: tmp.write_bytes(raw))


def remove_leftovers(folder) -> list[Path]:
    """Delete the temporary files :func:`atomic_write` left in ``folder`` (not below it)
    when its process was killed mid-write; returns them. Only safe while no other process
    writes to ``folder`` (hold its lock)."""
    folder, removed = Path(folder), []
    for f in sorted(folder.iterdir()) if folder.is_dir() else ():
        m = _TEMPORARY.match(f.name)
        if m and f.is_file() and (m["suffix"] or "") == Path(m["name"]).suffix:
            f.unlink()
            removed.append(f)
    return removed
