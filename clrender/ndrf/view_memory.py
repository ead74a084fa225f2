"""How much memory NDRF training's views may hold, and disk-backed arrays for those beyond it.

A view's hits and target take (K x 12 + 3 x itemsize) bytes a pixel (23 MB at 800x800 with
K = 2); the paper's 1000 distillation views would exhaust a 24 GB machine.
:func:`view_budget` says how many bytes the views may keep in memory (an argument,
``$CLRENDER_NDRF_VIEW_BUDGET``, else half the memory available now, a container's limit
included); :func:`disk_arrays` makes the memory-mapped arrays
:meth:`clrender.ndrf.shader_torch.ViewSet.build` uses past it.

Examples:
    >>> view_budget()                     # bytes, e.g. 11.5e9 on a 24 GB machine
    >>> view_budget(budget="12G")         # 12000000000
"""
from __future__ import annotations

import errno
import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import torch

VIEW_MEMORY_FRACTION = 0.5      # of the available memory: the default budget of the views
VIEW_BUDGET_ENV = "CLRENDER_NDRF_VIEW_BUDGET"
_UNITS = {"": 1, "k": 10 ** 3, "m": 10 ** 6, "g": 10 ** 9, "t": 10 ** 12}
# A disk-backed view's resident bytes: its packed camera (16 float32) and coverage box (4 int64).
DISK_BACKED_VIEW_BYTES = 16 * 4 + 4 * 8


def parse_bytes(text) -> int:
    """A byte count: an int, or text as ``"12e9"``, ``"12G"``, ``"500MB"``, ``"0"`` (decimal
    units k, M, G, T, as the docs' MB and GB); a ValueError that names the text otherwise."""
    if isinstance(text, (int, np.integer)):
        value = int(text)
    else:
        m = re.fullmatch(r"\s*([0-9.]+(?:e[0-9]+)?)\s*([kmgt]?)b?\s*", str(text).lower())
        try:
            value = int(float(m[1]) * _UNITS[m[2]])
        except (TypeError, ValueError):
            raise ValueError(f"byte count {text!r}: expected e.g. 12G, 500M or 12e9") from None
    if value < 0:
        raise ValueError(f"byte count {text!r} is negative")
    return value


def _cgroup_headroom() -> int | None:
    """Bytes left under this process's cgroup memory limits (v2: its cgroup and every
    parent; v1: its memory controller's), None where none is set or readable. A container's
    limit is not in /proc/meminfo, which shows the host's memory."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    root, room = Path("/sys/fs/cgroup"), []
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if controllers == "":                                      # cgroup v2
            own = root / path.lstrip("/")
            dirs, names = [d for d in (own, *own.parents) if d.is_relative_to(root)], \
                ("memory.max", "memory.current")
        elif "memory" in controllers.split(","):                   # cgroup v1
            dirs = [root / "memory" / path.lstrip("/"), root / "memory"]
            names = ("memory.limit_in_bytes", "memory.usage_in_bytes")
        else:
            continue
        for d in dirs:
            try:
                limit, used = ((d / name).read_text().strip() for name in names)
            except OSError:
                continue
            if limit.isdigit() and int(limit) < 1 << 60:           # v1's "no limit": ~2^63
                room.append(max(0, int(limit) - int(used)))
    return min(room) if room else None


def available_memory(device="cpu") -> int:
    """Bytes free for new arrays where ``device``'s tensors live: a CUDA device's free memory
    (``torch.cuda.mem_get_info``); else the host's ``MemAvailable`` (/proc/meminfo: free
    pages and the caches the kernel can reclaim; elsewhere ``SC_AVPHYS_PAGES`` x
    ``SC_PAGE_SIZE``, free pages only; 0 where neither is readable), and no more than the
    process's cgroup (container) leaves."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return int(torch.cuda.mem_get_info(dev)[0])
    free = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                free = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    if free is None:
        try:
            free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, ValueError, OSError):
            free = 0
    room = _cgroup_headroom()
    return free if room is None else min(free, room)


def view_budget(device="cpu", budget=None) -> int:
    """The bytes a training's views may hold in memory (host, or the GPU's for a CUDA
    device): ``budget`` when given (bytes or :func:`parse_bytes` text), else
    ``$CLRENDER_NDRF_VIEW_BUDGET`` when set, else :data:`VIEW_MEMORY_FRACTION` of
    :func:`available_memory` of ``device``, measured now. Views over it are disk-backed
    (:meth:`ViewSet.build`); it never changes a result, only where the views are kept."""
    if budget is None:
        budget = os.environ.get(VIEW_BUDGET_ENV) or None
    if budget is not None:
        return parse_bytes(budget)
    return int(VIEW_MEMORY_FRACTION * available_memory(device))


def disk_arrays(folder, specs: dict) -> dict:
    """``{name: np.memmap}`` of ``specs`` ``{name: (shape, dtype)}``: ``.npy`` files
    (``np.lib.format.open_memmap``) made in a fresh folder under ``folder`` (None: the
    temporary directory, ``$TMPDIR``), their disk space reserved at once (a full disk is an
    OSError here, not a SIGBUS mid-training), then their names removed: the mappings keep
    the files' data (POSIX) until the last array using them is freed, when the system
    releases the space, also when the process is killed: nothing is left behind."""
    tmp = Path(tempfile.mkdtemp(prefix=".ndrf-views-", dir=folder))
    arrays = {}
    try:
        for name, (shape, dtype) in specs.items():
            path = tmp / f"{name}.npy"
            arrays[name] = np.lib.format.open_memmap(path, "w+", dtype, shape)
            with open(path, "r+b") as f:
                _reserve(f.fileno())
    except OSError as e:
        if e.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        need = sum(int(np.prod(s)) * np.dtype(d).itemsize for s, d in specs.values())
        raise OSError(e.errno, f"NDRF views: {need / 1e9:.2f} GB of disk-backed views do "
                               f"not fit in {tmp.parent}: {e.strerror}") from e
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return arrays


def _reserve(fd: int) -> None:
    """Allocate the blocks of the (sparse) file ``fd`` where the system can: an OSError
    ENOSPC (or EDQUOT) when the disk is too full; other refusals (a file system without
    ``fallocate``) leave the file sparse."""
    if not hasattr(os, "posix_fallocate"):
        return
    try:
        os.posix_fallocate(fd, 0, os.fstat(fd).st_size)
    except OSError as e:
        if e.errno in (errno.ENOSPC, errno.EDQUOT):
            raise
