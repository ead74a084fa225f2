"""The exported page in headless Chromium, for the export tests: one browser per test
module and a helper drawing a folder's page at given cameras."""
from __future__ import annotations

import os

import numpy as np
import pytest

from clrender.export import serve

UNDER_CI = os.environ.get("CI") == "true"


@pytest.fixture(scope="module")
def browser():
    """A 320x240 headless Chromium (skipped where it is missing, a failure under CI)."""
    from bench.tools.browser import chromium, missing

    reason = missing()
    if reason is not None:
        if UNDER_CI:
            pytest.fail(f"CI=true: {reason}")
        pytest.skip(reason)
    driver = chromium(320, 240)
    yield driver
    driver.quit()


def page_frames(browser, folder, cameras) -> list[np.ndarray]:
    """The page of ``folder`` drawing each camera: float frames (H, W, 3). The page's own
    first frame, of its first camera, is drawn at a quarter of that camera's size
    (``?scale=0.25``): on a software GL it costs seconds, and the cameras drawn here are
    the test's."""
    from clrender.export.page import open_page, render_view

    url, server = serve(folder)
    try:
        open_page(browser, url + "?scale=0.25")
        return [render_view(browser, cam)[0] for cam in cameras]
    finally:
        server.shutdown()
        server.server_close()
