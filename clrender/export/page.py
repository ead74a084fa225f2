"""Driving an exported page from Python (a selenium WebDriver on it): wait until it is
loaded, render an exact camera through its ``window.clrender`` hook and read back the
float frame. The tests and bench/speed/browser_fps.py use these.

Examples:
    >>> open_page(driver, url)                    # navigate, wait for the hook
    >>> rgb, ms = render_view(driver, camera)     # (H, W, 3) float32, page milliseconds
"""
from __future__ import annotations

import base64
import time

import numpy as np

from .writer import camera_record


class PageError(RuntimeError):
    """The page reported an error (its message) or did not load in time."""


def open_page(driver, url: str, timeout_s: float = 300.0) -> dict:
    """Navigate to ``url`` without waiting for its load event (the page draws its first
    frame while loading, which may take longer than the driver's own timeout on a slow
    software GL), then :func:`wait_ready`."""
    driver.set_script_timeout(timeout_s)        # a frame may take minutes on a software GL
    driver.command_executor.client_config.timeout = timeout_s + 30   # selenium's HTTP read
    driver.execute_script("window.__leaving = true; window.location.href = arguments[0];", url)
    return wait_ready(driver, timeout_s)


def wait_ready(driver, timeout_s: float = 300.0) -> dict:
    """Wait for the page's hook; returns ``{"load_ms", "renderer"}`` (the WebGL renderer
    string). Raises :class:`PageError` with the page's message."""
    end = time.monotonic() + timeout_s
    while True:
        state = driver.execute_script(            # the page left behind is not ready
            "const h = window.clrender; return h && !window.__leaving ? "
            "[h.ready, h.error, h.loadMs] : [false, null, 0];")
        if state[1]:
            raise PageError(f"the page failed: {state[1]}")
        if state[0]:
            return {"load_ms": float(state[2])}
        if time.monotonic() > end:
            raise PageError(f"the page was not ready within {timeout_s:.0f} s")
        time.sleep(0.1)


def render_view(driver, camera) -> tuple[np.ndarray, float]:
    """Draw ``camera`` (a :class:`clrender.camera.Camera`) on the page and read its float
    frame: ``(rgb (H, W, 3) float32, ms the page took)``."""
    ms = driver.execute_script("return window.clrender.renderView(arguments[0]);",
                               camera_record(camera, "probe"))
    out = driver.execute_script("return window.clrender.readFloat();")
    rgba = np.frombuffer(base64.b64decode(out["data"]), np.float32)
    rgba = rgba.reshape(out["height"], out["width"], 4)
    if (out["width"], out["height"]) != (camera.width, camera.height):
        raise PageError(f"the page drew {out['width']}x{out['height']}, asked "
                        f"{camera.width}x{camera.height}")
    return rgba[..., :3].copy(), float(ms)
