"""Write files so that readers never see them half-written: a temporary file in the same
folder, then a rename over the target (``os.replace`` is atomic on one file system)."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable


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


def write_atomic(path, data: bytes | str) -> Path:
    """Write bytes or text (UTF-8) to ``path`` atomically; see :func:`atomic_write`."""
    raw = data.encode() if isinstance(data, str) else data
    return atomic_write(path, lambda tmp: tmp.write_bytes(raw))
