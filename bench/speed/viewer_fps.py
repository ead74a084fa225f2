"""Frames a second the viewer delivers to a page (render + JPEG encode + send) while the
camera moves, measured with a real headless chromium (:mod:`bench.tools.browser`).

The viewer draws every frame at full size (``preview_scale`` 1), ``--size`` x ``--size``
pixels in a page of that size (``?fixedDpr=1``: viser's adaptive pixel ratio off); a drag
on the page's canvas keeps the camera moving for ``--seconds``. Counted: the JPEG frames
the page received (:func:`bench.tools.browser.jpeg_image_times`), between the first and the last,
beside the frames the server sent and the renderer alone (same model, camera and size, no
browser). The browser (WebGL on SwiftShader) shares the CPU with
the renderer, as it does when someone views a model on this machine.

Examples:
    python -m bench.speed.viewer_fps model.npz                     # 400x400, 10 s of dragging
    python -m bench.speed.viewer_fps ndrf.npz --size 400 --seconds 5
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from clrender import methods
from clrender.renderer import Renderer
from clrender.viewer import Viewer

from bench.tools import browser

def renderer_fps(model, camera, seconds: float) -> tuple[float, float]:
    """(frames a second of the renderer alone, median kernel ms) at ``camera``."""
    renderer = Renderer(model)
    renderer.render(camera)                          # build and first-launch costs
    kernel_ms, start = [], time.perf_counter()
    while time.perf_counter() - start < seconds:
        kernel_ms.append(renderer.render(camera)["ms"])
    return len(kernel_ms) / (time.perf_counter() - start), float(np.median(kernel_ms))


def _drag(driver, seconds: float, rate_hz: float = 60.0) -> int:
    """Drag across the page's canvas, back and forth, for about ``seconds``: the left button
    held and the pointer moved 4 CSS pixels at a time, at most ``rate_hz`` moves a second
    (a mouse reports at 60-1000 Hz), each sent with DevTools' ``Input.dispatchMouseEvent``,
    which returns once the page has taken the event. Returns the moves sent.

    Not selenium's ActionChains: its pointer actions are paced by the driver, and on these
    cores they arrived ~3.5 a second (11 s for 40 moves, with the server sending no frames
    at all), so they, not the viewer, set the frame rate."""
    rect = driver.execute_script(
        "const r = document.querySelector('canvas').getBoundingClientRect();"
        "return [r.left + r.width / 2, r.top + r.height / 2];")
    x0, y = float(rect[0]), float(rect[1])

    def mouse(kind: str, x: float, **extra) -> None:
        driver.execute_cdp_cmd("Input.dispatchMouseEvent", {
            "type": kind, "x": x, "y": y, "button": "left", **extra})

    def x(move: int) -> float:                      # a triangle wave of +-40 px
        return x0 + 4.0 * (10 - abs(move % 40 - 20))

    mouse("mousePressed", x(0), clickCount=1, buttons=1)
    moves, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        due = time.monotonic() + 1.0 / rate_hz
        moves += 1
        mouse("mouseMoved", x(moves), buttons=1)
        time.sleep(max(0.0, due - time.monotonic()))
    mouse("mouseReleased", x(moves), clickCount=1)
    return moves


def measure(model, size: int, seconds: float) -> dict:
    """Page-delivered, server-sent and renderer-only frame rates at ``size`` pixels."""
    viewer = Viewer(model, port=0, max_size=size, preview_scale=1.0)
    driver = browser.chromium(size, size)
    browser.record_jpeg_images(driver)
    try:
        driver.get(viewer.url + "?fixedDpr=1")
        browser.wait_for(lambda: viewer.frames_sent >= 1, 120, "first frame")
        time.sleep(1.0)
        before = len(browser.jpeg_image_times(driver))
        sent, start = viewer.frames_sent, time.perf_counter()
        moves = _drag(driver, seconds)
        wall = time.perf_counter() - start
        sent = viewer.frames_sent - sent
        camera = viewer.last_frame[0]
        stats = viewer.stats
        time.sleep(1.0)                              # frames still on their way
        images = browser.jpeg_image_times(driver)[before:]
    finally:
        driver.quit()
        viewer.stop()
    page_fps = (len(images) - 1) / (images[-1] - images[0]) if len(images) > 1 else 0.0
    alone_fps, kernel_ms = renderer_fps(model, camera, min(seconds, 5.0))
    return {"size": f"{camera.width}x{camera.height}", "page_fps": page_fps,
            "page_frames": len(images), "moves_per_s": moves / wall,
            "sent_fps": sent / wall, "sent_frames": sent, "renderer_fps": alone_fps,
            "kernel_ms": kernel_ms, "last_stats": stats}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.speed.viewer_fps", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", help="a baked model (.npz), any method")
    p.add_argument("--size", type=int, default=400, help="frame width and height, pixels")
    p.add_argument("--seconds", type=float, default=10.0, help="how long the camera moves")
    args = p.parse_args(argv)
    reason = browser.missing()
    if reason:
        print(f"bench.speed.viewer_fps: {reason}", file=sys.stderr)
        return 2
    model = methods.load(args.model)
    r = measure(model, args.size, args.seconds)
    print(f"{args.model} ({model.method}), {r['size']} frames:")
    print(f"  delivered to the page  {r['page_fps']:6.1f} fps ({r['page_frames']} frames)")
    print(f"  sent by the server     {r['sent_fps']:6.1f} fps ({r['sent_frames']} frames)")
    print(f"  pointer moves          {r['moves_per_s']:6.1f} a second")
    print(f"  renderer alone         {r['renderer_fps']:6.1f} fps "
          f"(kernel {r['kernel_ms']:.1f} ms median)")
    print(f"  last GUI stats: {r['last_stats']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
