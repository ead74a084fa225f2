"""Optional test dependencies (the Oclgrind simulator, the LPIPS weights): a missing one
skips its tests on a developer's machine, and fails them under CI (``CI=true``), where
.ci/install provides everything and a silent skip would hide a broken setup."""
from __future__ import annotations

import os

import pytest


def require(available: bool, what: str) -> None:
    """Skip the calling test unless ``available``; under ``CI=true`` fail it instead."""
    if available:
        return
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"{what} is missing under CI (CI=true): .ci/install provides it", pytrace=False)
    pytest.skip(f"{what} is not installed")
