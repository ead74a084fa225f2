"""A build's compiler-output warning: dropped only where the log is a driver's
informational lines (clrender/buildlog.py), kept for a real compiler warning, on every
implementation in conftest.CL_PLATFORMS."""
import os
import uuid
import warnings

import pyopencl as cl

from clrender import buildlog, device

HINTED = ("__kernel __attribute__((vec_type_hint(float16)))\n"
          "void k(__global float16 *a) { a[0] = a[1] * 2.0f; }")
# A condition that assigns: clang's -Wparentheses, on by default in every implementation here.
WARNS = "__kernel void k(__global int *a) { int i = a[0]; if (i = 1) a[0] = 2; }"
INTEL_LOG = """Compilation started
Compilation done
Linking started
Linking done
Device build started
Options used by backend compiler: -DRAYS=16 -I/kernels
Device build done
warning: kernel "k": Kernel can't be vectorized due to unsupported vec type hint
remark: <unknown>:0:0: loop not vectorized: loop control flow is not understood by vectorizer
remark: <unknown>:0:0: Kernel was 16-way vectorized18 gathers10 scatters
remark: <unknown>:0:0: 543 instructions in function
Kernel "k" was not vectorized
Kernel "j" was successfully vectorized (16)
Done.
"""


def test_intels_progress_and_vectoriser_report_are_informational():
    assert buildlog.informational(INTEL_LOG, HINTED)
    assert buildlog.informational("", HINTED)


def test_a_compiler_warning_is_not_informational():
    log = INTEL_LOG.replace("Device build done\n", "Device build done\n"
                            "1:40: warning: using the result of an assignment as a condition\n")
    assert not buildlog.informational(log, HINTED)


def test_the_hint_notice_is_informational_only_for_a_kernel_that_declares_one():
    plain = "__kernel void k(__global float *a) { a[0] = 1.0f; }"
    assert not buildlog.informational(INTEL_LOG, plain)
    assert not buildlog.informational(INTEL_LOG.replace('kernel "k"', 'kernel "other"'), HINTED)


def _compiler_warnings(source: str) -> list[str]:
    rt = device.get_runtime()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        buildlog.build(rt.context, source)
    return [str(w.message) for w in caught if issubclass(w.category, cl.CompilerWarning)]


def test_a_clean_build_does_not_warn_and_a_real_warning_does(cl_platform, monkeypatch):
    monkeypatch.delenv("PYOPENCL_COMPILER_OUTPUT", raising=False)
    fresh = f"\n// {uuid.uuid4()}"          # a source pyopencl's cache has not seen
    for _ in range(2):                         # built, then served by pyopencl's cache
        assert _compiler_warnings(HINTED + fresh) == []
        assert _compiler_warnings(WARNS + fresh) == [buildlog.GENERIC]
    assert "PYOPENCL_COMPILER_OUTPUT" not in os.environ


def test_a_real_warning_carries_its_log_where_asked(cl_platform, monkeypatch):
    monkeypatch.setenv("PYOPENCL_COMPILER_OUTPUT", "1")
    found = _compiler_warnings(WARNS + f"\n// {uuid.uuid4()}")
    assert len(found) == 1 and "assignment" in found[0]
    assert os.environ["PYOPENCL_COMPILER_OUTPUT"] == "1"
