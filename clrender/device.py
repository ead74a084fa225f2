"""OpenCL device choice, program building and caching.

The device is chosen by ``CLRENDER_DEVICE`` (or the ``device=`` argument of the
public functions):

* ``gpu`` / ``cpu`` / ``accelerator``: the first device of that type;
* an integer ``N`` or ``P:D``: the N-th device in :func:`list_devices` order, or
  device D of platform P;
* anything else: a case-insensitive substring of "platform name / device name".

With nothing set, a GPU is preferred, then a CPU, then whatever exists (under
Oclgrind the only device is the simulator); a device that cannot build a trivial kernel is
passed over. When nothing matches, the error lists
the devices that exist.

Programs are built from ``kernels/*.cl`` with ``-D`` specialisation and cached per
(source text, options, device); kernels are fetched from a built program once. Each
program has two builds: the exact one (:data:`EXACT_OPTIONS`, what the tests compare with
the numpy references) and the fast one (:data:`FAST_OPTIONS`, for rendering).
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from importlib import resources

import numpy as np
import pyopencl as cl

# Identical float results to the numpy references: no fused multiply-add, correctly
# rounded division and sqrt (the references use IEEE float32 throughout); -D FAST_MATH=0.
EXACT_OPTIONS = ("-cl-fp32-correctly-rounded-divide-sqrt",)
# For rendering: the driver may contract a * b + c into a fused multiply-add and divide
# and take sqrt within the OpenCL ulp bounds; -D FAST_MATH=1 lets a kernel use native_*
# functions. Kernels that place positions or cells keep FP_CONTRACT OFF, so geometry is
# the same in both builds. Not -cl-fast-relaxed-math: it implies finite-math-only, and
# the kernels rely on inf and NaN (rays parallel to an axis).
FAST_OPTIONS = ("-cl-mad-enable", "-cl-no-signed-zeros")


class DeviceError(RuntimeError):
    """No OpenCL device matches the request."""


@dataclass(frozen=True)
class Runtime:
    """A chosen device with its context and a profiling-enabled in-order queue."""

    device: cl.Device
    context: cl.Context
    queue: cl.CommandQueue

    @property
    def name(self) -> str:
        return f"{self.device.platform.name.strip()} / {self.device.name.strip()}"

    def program(self, source_name: str, defines: dict | None = None,
                exact: bool = True, source_dir: str | None = None) -> "Program":
        """The program ``kernels/<source_name>`` built with ``-D`` defines (cached).

        Args:
            source_name: a file of ``kernels/``.
            defines: ``{name: value}`` passed as ``-D`` (bools as 0/1, floats as float32).
            exact: the exact build (:data:`EXACT_OPTIONS`, ``-D FAST_MATH=0``), compared
                with the numpy references in tests; False: the fast build
                (:data:`FAST_OPTIONS`, ``-D FAST_MATH=1``) for rendering.
            source_dir: a folder to take the source and its headers from instead of the
                installed ``kernels/`` (benchmarks compare kernel versions with it).
        """
        defines = {**(defines or {}), "FAST_MATH": not exact}
        opts = tuple(f"-D{k}={_define_value(v)}" for k, v in sorted(defines.items()))
        return _build(self, source_name, (EXACT_OPTIONS if exact else FAST_OPTIONS) + opts,
                      None if source_dir is None else str(source_dir))


class Program:
    """A built program whose kernel objects are fetched once and reused."""

    def __init__(self, program: cl.Program):
        self._program = program
        self._kernels: dict[str, cl.Kernel] = {}

    def kernel(self, name: str) -> cl.Kernel:
        if name not in self._kernels:
            self._kernels[name] = getattr(self._program, name)
        return self._kernels[name]


def _define_value(v) -> str:
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return repr(float(np.float32(v))) + "f"
    return str(v)


def list_devices() -> list[cl.Device]:
    """All OpenCL devices of all platforms, in platform order."""
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    devices = []
    for p in platforms:
        try:
            devices.extend(p.get_devices())
        except cl.Error:
            continue
    return devices


def device_type_name(device: cl.Device) -> str:
    """"GPU", "CPU", "ACCELERATOR" or "OTHER" (device.type is a bit field)."""
    for name in ("GPU", "CPU", "ACCELERATOR"):
        if device.type & getattr(cl.device_type, name):
            return name
    return "OTHER"


def _describe(devices: list[cl.Device]) -> str:
    if not devices:
        return "  (no OpenCL platform found: install pocl-binary-distribution or a vendor driver)"
    lines = []
    for i, d in enumerate(devices):
        lines.append(f"  [{i}] {d.platform.name.strip()} / {d.name.strip()} "
                     f"({device_type_name(d)})")
    return "\n".join(lines)


def select_device(spec: str | None = None) -> cl.Device:
    """The device named by ``spec`` (or ``$CLRENDER_DEVICE``), see the module doc."""
    spec = spec if spec is not None else os.environ.get("CLRENDER_DEVICE", "")
    spec = spec.strip()
    devices = list_devices()
    if not devices:
        raise DeviceError("no OpenCL device found:\n" + _describe(devices))
    types = {"gpu": cl.device_type.GPU, "cpu": cl.device_type.CPU,
             "accelerator": cl.device_type.ACCELERATOR}
    if not spec:
        for t in (cl.device_type.GPU, cl.device_type.CPU):
            for d in devices:
                if d.type & t and _compiles(d):
                    return d
        return devices[0]
    key = spec.lower()
    if key in types:
        match = [d for d in devices if d.type & types[key]]
    elif key.isdigit():
        match = [devices[int(key)]] if int(key) < len(devices) else []
    elif ":" in key and all(part.isdigit() for part in key.split(":", 1)):
        p, i = (int(part) for part in key.split(":", 1))
        platforms = cl.get_platforms()
        match = ([platforms[p].get_devices()[i]]
                 if p < len(platforms) and i < len(platforms[p].get_devices()) else [])
    else:
        match = [d for d in devices
                 if key in f"{d.platform.name} / {d.name}".lower()]
    if not match:
        raise DeviceError(f"no OpenCL device matches {spec!r}; devices that exist:\n"
                          + _describe(devices))
    return match[0]


@functools.lru_cache(maxsize=None)
def _compiles(device: cl.Device) -> bool:
    """Whether ``device`` builds a trivial kernel. A driver can list a device it cannot
    compile for (pip's PoCL 3.0 on a CPU its LLVM does not know: "unknown target CPU
    'generic'"); the default choice skips such a device rather than failing later."""
    try:
        ctx = cl.Context([device])
        cl.Program(ctx, "__kernel void k(__global float *a) { a[0] = 1.0f; }").build()
        return True
    except cl.Error:
        return False


@functools.lru_cache(maxsize=None)
def _runtime_for(device: cl.Device) -> Runtime:
    context = cl.Context([device])
    queue = cl.CommandQueue(context, properties=cl.command_queue_properties.PROFILING_ENABLE)
    return Runtime(device, context, queue)


def get_runtime(device: "str | Runtime | None" = None) -> Runtime:
    """A cached :class:`Runtime` for ``device`` (a spec string, a Runtime, or None)."""
    if isinstance(device, Runtime):
        return device
    return _runtime_for(select_device(device))


def kernel_source(name: str) -> str:
    """The text of ``kernels/<name>`` as installed with the package."""
    return resources.files("clrender.kernels").joinpath(name).read_text()


def _kernel_dir() -> str:
    return str(resources.files("clrender.kernels"))


@functools.lru_cache(maxsize=None)
def _build(runtime: Runtime, source_name: str, options: tuple[str, ...],
           source_dir: str | None = None) -> Program:
    if source_dir is None:
        source, where, include = kernel_source(source_name), f"kernels/{source_name}", _kernel_dir()
    else:
        path = os.path.join(source_dir, source_name)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: kernel source not found")
        with open(path) as f:
            source, where, include = f.read(), path, source_dir
    opts = list(options) + [f"-I{include}"]
    try:
        program = cl.Program(runtime.context, source).build(options=opts)
    except cl.RuntimeError as exc:
        raise RuntimeError(f"{where}: build failed with {' '.join(options)}:\n{exc}") from exc
    return Program(program)


def work_group_size(kernel: cl.Kernel, device: cl.Device, global_size: tuple[int, ...],
                    target: int = 64) -> tuple[int, ...]:
    """A local size for ``kernel`` derived from the device: the first axis a multiple of
    the kernel's preferred work-group size multiple (the SIMD or warp width), the group
    about ``target`` work-items (at least one multiple) and no larger than the kernel's
    maximum work-group size or the global size (padded up to it by :func:`padded`).

    Args:
        global_size: work-items per axis (1 or 2 axes), before padding.
    Returns:
        local size, one entry per axis.
    """
    info = cl.kernel_work_group_info
    limit = max(1, kernel.get_work_group_info(info.WORK_GROUP_SIZE, device))
    multiple = max(1, kernel.get_work_group_info(info.PREFERRED_WORK_GROUP_SIZE_MULTIPLE, device))
    multiple = min(multiple, limit)
    lx = min(multiple * max(1, min(target, limit) // multiple),
             multiple * -(-global_size[0] // multiple))
    if len(global_size) == 1:
        return (lx,)
    ly = max(1, min(limit // lx, target // lx, global_size[1]))
    return (lx, ly)


def padded(global_size: tuple[int, ...], local_size: tuple[int, ...]) -> tuple[int, ...]:
    """``global_size`` rounded up to a multiple of ``local_size`` per axis."""
    return tuple(-(-g // l) * l for g, l in zip(global_size, local_size))


def check_allocation(device: cl.Device, what: str, nbytes: int) -> None:
    """Raise ValueError naming ``what`` unless one buffer of ``nbytes`` bytes fits the
    device's largest allocation (``CL_DEVICE_MAX_MEM_ALLOC_SIZE``)."""
    limit = int(device.max_mem_alloc_size)
    if nbytes > limit:
        raise ValueError(f"{what}: needs {nbytes / 2**20:.1f} MiB in one buffer, more than "
                         f"the {limit / 2**20:.0f} MiB {device.name.strip()} allocates")


def event_ms(event: cl.Event) -> float:
    """Kernel time of a finished profiling event, in milliseconds."""
    event.wait()
    return (event.profile.end - event.profile.start) * 1e-6


def device_info(device: cl.Device) -> dict:
    """Key limits of a device, for ``clrender info``."""
    return {
        "platform": device.platform.name.strip(),
        "platform_version": device.platform.version.strip(),
        "device": device.name.strip(),
        "type": device_type_name(device),
        "compute_units": device.max_compute_units,
        "max_work_group_size": device.max_work_group_size,
        "global_mem_MiB": device.global_mem_size >> 20,
        "max_alloc_MiB": device.max_mem_alloc_size >> 20,
        "local_mem_KiB": device.local_mem_size >> 10,
        "version": device.version.strip(),
    }
