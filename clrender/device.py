"""OpenCL device choice, program building and caching.

The device is chosen by ``CLRENDER_DEVICE`` (or the ``device=`` argument of the
public functions):

* ``gpu`` / ``cpu`` / ``accelerator``: the best-ranked device of that type;
* an integer ``N`` or ``P:D``: the N-th device in :func:`list_devices` order, or
  device D of platform P;
* anything else: a case-insensitive substring of the platform's name or version
  ("intel", "pocl"), else of "platform name / device name".

With nothing set, the best-ranked device that builds a trivial kernel (:func:`rank`): a
discrete GPU, then an integrated one, then a CPU, then an accelerator; within a kind the
most compute units; then a system driver before a runtime clrender registered from pip
(clrender/icd.py: Intel's CPU runtime is found without root or exported variables); then
the platforms' order. :func:`choice_reason` says why. When nothing matches, the error
lists the devices that exist.

Programs are built from ``kernels/*.cl`` with ``-D`` specialisation and cached per
(source text, options, device); kernels are fetched from a built program once. Each
program has two builds: the exact one (:func:`exact_options`, what the tests compare with
the numpy references) and the fast one (:data:`FAST_OPTIONS`, for rendering). On the
Oclgrind simulator both also get ``-D OCLGRIND`` (:func:`platform_defines`). A build's
compiler-output warning stands unless its log is only a driver's informational lines
(clrender/buildlog.py).
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from importlib import resources

import numpy as np

from . import buildlog, icd

icd.register()  # before the first platform query (see clrender/icd.py)
import pyopencl as cl  # noqa: E402

# Identical float results to the numpy references: no fused multiply-add (the kernels'
# FP_CONTRACT OFF), correctly rounded division and sqrt (the references use IEEE float32
# throughout); -D FAST_MATH=0. The option is passed only where the device reports
# CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT (the spec allows it nowhere else): exact_options.
CORRECTLY_ROUNDED = "-cl-fp32-correctly-rounded-divide-sqrt"
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
            exact: the exact build (:func:`exact_options`, ``-D FAST_MATH=0``), compared
                with the numpy references in tests (DeviceError where the device cannot
                give IEEE float32 division and sqrt); False: the fast build
                (:data:`FAST_OPTIONS`, ``-D FAST_MATH=1``) for rendering.
            source_dir: a folder to take the source and its headers from instead of the
                installed ``kernels/`` (benchmarks compare kernel versions with it).
        """
        defines = {**(defines or {}), "FAST_MATH": not exact, **platform_defines(self.device)}
        opts = tuple(f"-D{k}={_define_value(v)}" for k, v in sorted(defines.items()))
        base = exact_options(self.device) if exact else FAST_OPTIONS
        return _build(self, source_name, base + opts,
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


def platform_defines(device: cl.Device) -> dict:
    """``{"OCLGRIND": 1}`` on the Oclgrind simulator (platform name "Oclgrind"), else
    ``{}``: kernels keep their workarounds for Oclgrind 21.10 behind ``#ifdef OCLGRIND``,
    so real devices build the faster forms."""
    return {"OCLGRIND": 1} if device.platform.name.strip() == "Oclgrind" else {}


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
    """The devices on one line (an error's tail), by index."""
    if not devices:
        return ("no OpenCL platform found: install Debian's pocl-opencl-icd, pip's "
                "intel-opencl-rt or a vendor driver")
    return "; ".join(f"[{i}] {d.platform.name.strip()} / {d.name.strip()} "
                     f"({device_type_name(d)})" for i, d in enumerate(devices))


def _kind(device: cl.Device) -> tuple[int, str]:
    """(rank, name) of the device's kind: discrete GPU 0, integrated GPU 1 (it shares
    the host's memory), CPU 2, accelerator 3, other 4."""
    t = device_type_name(device)
    if t == "GPU":
        return (1, "integrated GPU") if device.host_unified_memory else (0, "discrete GPU")
    return {"CPU": (2, "CPU"), "ACCELERATOR": (3, "accelerator")}.get(t, (4, "other"))


def rank(devices: list[cl.Device]) -> list[cl.Device]:
    """``devices`` best first: by kind (:func:`_kind`), then more compute units, then a
    system driver before a runtime registered from pip (:mod:`clrender.icd`), then the
    platforms' order."""
    order = {id(d): i for i, d in enumerate(devices)}
    return sorted(devices, key=lambda d: (_kind(d)[0], -d.max_compute_units,
                                          icd.from_pip(d.platform.name) is not None,
                                          order[id(d)]))


def choice_reason(device: cl.Device, devices: list[cl.Device] | None = None) -> str:
    """Why the default choice (no ``CLRENDER_DEVICE``) is ``device``: the rule that set
    it apart from the runner-up, for ``clrender info``."""
    ranked = [d for d in rank(devices if devices is not None else list_devices())
              if d == device or _compiles(d)]
    kind = _kind(device)[1]
    others = [d for d in ranked if d != device]
    if not others:
        return f"the only device that builds kernels ({kind})"
    nxt = others[0]
    name = f"{nxt.platform.name.strip()} / {nxt.name.strip()}"
    if _kind(nxt)[0] != _kind(device)[0]:
        why = f"kind: {kind} before {_kind(nxt)[1]}"
    elif nxt.max_compute_units != device.max_compute_units:
        why = f"more compute units ({device.max_compute_units} against {nxt.max_compute_units})"
    elif (icd.from_pip(nxt.platform.name) is None) != (icd.from_pip(device.platform.name) is None):
        why = (f"same kind and compute units: the system's driver before "
               f"{icd.from_pip(nxt.platform.name)} from pip")
    else:
        why = "same kind and compute units: the first in platform order"
    skipped = [d for d in rank(devices or list_devices()) if d != device and not _compiles(d)]
    note = (f"; skipped, cannot build kernels: "
            + ", ".join(f"{d.platform.name.strip()} / {d.name.strip()}" for d in skipped)
            if skipped else "")
    return f"{why}; next: {name}{note}"


def _matching(key: str, devices: list[cl.Device]) -> list[cl.Device]:
    """Devices whose platform name or version contains ``key``, else whose
    "platform / device" name does (lower-case ``key``)."""
    on_platform = [d for d in devices
                   if key in f"{d.platform.name} {d.platform.version}".lower()]
    return on_platform or [d for d in devices if key in f"{d.platform.name} / {d.name}".lower()]


def select_device(spec: str | None = None) -> cl.Device:
    """The device named by ``spec`` (or ``$CLRENDER_DEVICE``), see the module doc."""
    spec = spec if spec is not None else os.environ.get("CLRENDER_DEVICE", "")
    spec = spec.strip()
    devices = list_devices()
    if not devices:
        raise DeviceError("no OpenCL device found: " + _describe(devices))
    types = {"gpu": cl.device_type.GPU, "cpu": cl.device_type.CPU,
             "accelerator": cl.device_type.ACCELERATOR}
    if not spec:
        return next((d for d in rank(devices) if _compiles(d)), devices[0])
    key = spec.lower()
    if key in types:
        match = rank([d for d in devices if d.type & types[key]])
    elif key.isdigit():
        match = [devices[int(key)]] if int(key) < len(devices) else []
    elif ":" in key and all(part.isdigit() for part in key.split(":", 1)):
        p, i = (int(part) for part in key.split(":", 1))
        platforms = cl.get_platforms()
        match = ([platforms[p].get_devices()[i]]
                 if p < len(platforms) and i < len(platforms[p].get_devices()) else [])
    else:
        match = _matching(key, devices)
    if not match:
        raise DeviceError(f"no OpenCL device matches {spec!r}; devices that exist: "
                          + _describe(devices))
    return match[0]


@functools.lru_cache(maxsize=None)
def _compiles(device: cl.Device) -> bool:
    """Whether ``device`` builds a trivial kernel. A driver can list a device it cannot
    compile for (pip's PoCL 3.0 on a CPU its LLVM does not know: "unknown target CPU
    'generic'"); the default choice skips such a device rather than failing later."""
    try:
        ctx = cl.Context([device])
        buildlog.build(ctx, "__kernel void k(__global float *a) { a[0] = 1.0f; }")
        return True
    except cl.Error:
        return False


_PROBE = """
__kernel void probe(__global const float *a, __global const float *b, __global float *out)
{
    const int i = get_global_id(0);
    out[2 * i] = a[i] / b[i];
    out[2 * i + 1] = sqrt(a[i]);
}
"""


def _probe_inputs(n: int = 1 << 16) -> tuple[np.ndarray, np.ndarray]:
    """Positive float32 pairs over exponents -60..60 (normal results), fixed seed."""
    rng = np.random.default_rng(0)
    a = (rng.uniform(1, 2, n) * np.exp2(rng.integers(-60, 61, n))).astype(np.float32)
    b = (rng.uniform(1, 2, n) * np.exp2(rng.integers(-60, 61, n))).astype(np.float32)
    return a, b


@functools.lru_cache(maxsize=None)
def _divide_sqrt_mismatches(device: cl.Device) -> int:
    """Probe results of ``a / b`` and ``sqrt(a)`` (built without any option) on
    :func:`_probe_inputs` that differ from IEEE float32 (numpy's)."""
    a, b = _probe_inputs()
    ctx = cl.Context([device])
    queue = cl.CommandQueue(ctx)
    mf = cl.mem_flags
    bufs = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x) for x in (a, b)]
    out = cl.Buffer(ctx, mf.WRITE_ONLY, 2 * a.nbytes)
    kernel = cl.Kernel(buildlog.build(ctx, _PROBE), "probe")
    kernel(queue, a.shape, None, *bufs, out)
    got = np.empty(2 * len(a), np.float32)
    cl.enqueue_copy(queue, got, out)
    queue.finish()
    return int(np.count_nonzero(got[0::2] != a / b) + np.count_nonzero(got[1::2] != np.sqrt(a)))


def exact_options(device: cl.Device) -> tuple[str, ...]:
    """Build options of the exact build on ``device``: :data:`CORRECTLY_ROUNDED` where the
    device reports CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT; none where it does not but its
    plain division and sqrt gave IEEE float32 results on every probe value (Intel's CPU
    runtime: hardware divps / sqrtps); else DeviceError, as its builds cannot match the
    numpy references."""
    if device.single_fp_config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT:
        return (CORRECTLY_ROUNDED,)
    bad = _divide_sqrt_mismatches(device)
    if bad:
        raise DeviceError(
            f"{device.platform.name.strip()} / {device.name.strip()}: cannot match the numpy "
            f"references (exact build): it does not report correctly rounded division and sqrt "
            f"(CL_DEVICE_SINGLE_FP_CONFIG) and {bad} of {2 * len(_probe_inputs()[0])} probe "
            f"results differ from IEEE float32; render with the fast build (exact=False)")
    return ()


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
        program = buildlog.build(runtime.context, source, opts)  # Intel's log: clrender/buildlog.py
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
        "registered_by": (f"clrender (pip {icd.from_pip(device.platform.name)})"
                          if icd.from_pip(device.platform.name) else "the ICD loader"),
        "exact_build": _exact_build_note(device),
    }


def _exact_build_note(device: cl.Device) -> str:
    """How the exact build gets IEEE division and sqrt on ``device`` (or why it cannot)."""
    if not _compiles(device):
        return "unavailable: the device builds no kernel"
    try:
        opts = exact_options(device)
    except DeviceError:
        return "refused: division / sqrt not IEEE float32 (see exact_options)"
    return ("-cl-fp32-correctly-rounded-divide-sqrt (reported)" if opts
            else "no option: not reported, IEEE on every probe value")
