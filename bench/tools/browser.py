"""Debian's chromium, headless, driven by selenium: the viewer's test and its benchmark.

viser draws with WebGL (three.js); a headless chromium on a machine without a GPU gets it
from its software GL, ANGLE on SwiftShader (``--use-angle=swiftshader``; newer chromium
versions only fall back to it with ``--enable-unsafe-swiftshader``). Nothing is downloaded:
the browser and its driver are Debian's ``chromium`` and ``chromium-driver``.

Examples:
    >>> reason = missing()                  # None when chromium, its driver and selenium exist
    >>> driver = chromium(400, 400)         # a 400x400 CSS-pixel viewport
    >>> driver.get(url); webgl_renderer(driver)
    'ANGLE (Google, Vulkan 1.3.0 (SwiftShader Device (Subzero) ...'
    >>> driver.quit()
"""
from __future__ import annotations

import shutil
import time

BROWSERS = ("chromium", "chromium-browser")
FLAGS = ("--headless=new", "--no-sandbox", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--mute-audio", "--disable-extensions")


def _browser() -> str | None:
    return next((p for p in map(shutil.which, BROWSERS) if p), None)


def missing() -> str | None:
    """Why the browser cannot run here (None when it can)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (bash .ci/install installs it)"
    if _browser() is None:
        return "no chromium executable (apt-get install chromium chromium-driver)"
    if shutil.which("chromedriver") is None:
        return "no chromedriver executable (apt-get install chromium-driver)"
    return None


def chromium(width: int, height: int):
    """A headless chromium (selenium WebDriver) with a ``width`` x ``height`` viewport."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = _browser()
    for flag in FLAGS:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=options)
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
        "width": int(width), "height": int(height), "deviceScaleFactor": 1, "mobile": False})
    return driver


def webgl_renderer(driver) -> str | None:
    """The page's WebGL2 renderer string (e.g. SwiftShader's), None without WebGL2."""
    return driver.execute_script(
        "const gl = document.createElement('canvas').getContext('webgl2');"
        "if (!gl) return null;"
        "const info = gl.getExtension('WEBGL_debug_renderer_info');"
        "return info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : 'webgl2';")


def record_jpeg_images(driver) -> None:
    """From the next page load on, note when the page receives each JPEG image (viser hands
    a frame to three.js as a ``Blob`` of type image/jpeg through ``URL.createObjectURL``;
    the WebSocket lives in a worker, out of reach of the page's network log)."""
    driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": """
        window.__jpegTimes = [];
        const create = URL.createObjectURL;
        URL.createObjectURL = function (obj) {
            if (obj instanceof Blob && obj.type === "image/jpeg")
                window.__jpegTimes.push(performance.now());
            return create.call(URL, obj);
        };"""})


def jpeg_image_times(driver) -> list[float]:
    """Page times (seconds) of the JPEG images received so far (:func:`record_jpeg_images`)."""
    return [t / 1e3 for t in driver.execute_script("return window.__jpegTimes || [];")]


def wait_for(predicate, timeout_s: float, what: str, poll_s: float = 0.05):
    """Poll ``predicate`` until it returns a true value (returned); TimeoutError naming
    ``what`` after ``timeout_s`` seconds."""
    end = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > end:
            raise TimeoutError(f"no {what} within {timeout_s:.0f} s")
        time.sleep(poll_s)
