"""The suite's shell tests pass with a third-party plug-in installed (the toy method, as
``CLRENDER_TEST_WITH_TOY=1`` registers it for the whole run and its child processes): the
registry, CLI, viewer controls, bench harness and device check iterate whatever methods
are installed and name none."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHELL_TESTS = ["tests/test_shell.py", "tests/test_cliopts.py", "tests/test_bench_run.py",
               "tests/test_bench_report.py", "tests/test_device_check.py",
               "tests/test_bench_fingerprint.py"]


@pytest.mark.slow
def test_shell_tests_pass_with_a_third_party_plugin_installed():
    env = {**os.environ, "CLRENDER_TEST_WITH_TOY": "1"}
    check = "from clrender import methods; assert 'toy' in methods.names(), methods.names()"
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider",
                           "-m", "not slow", *SHELL_TESTS], cwd=REPO, env=env,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert " passed" in proc.stdout.splitlines()[-1]
    env["PYTHONPATH"] = ""
    probe = subprocess.run([sys.executable, "-c", "import conftest; conftest.pytest_configure("
                            f"None); {check}"], cwd=REPO / "tests", env=env,
                           capture_output=True, text=True)
    assert probe.returncode == 0, probe.stderr[-2000:]
