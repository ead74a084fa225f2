"""``clrender view`` (clrender/viewer.py): the camera conversion, the render-option controls,
the preview/full-size loop, the training frustums, and the page in a real headless browser.

Outside CI a missing viser, selenium or Debian chromium skips with the reason; under CI
(``CI=true``) it fails.
"""
from __future__ import annotations

import importlib
import os
import time
from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest

from clrender import methods
from clrender.camera import Camera, generate_rays, look_at
from clrender.paths import ORBIT
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model

UNDER_CI = os.environ.get("CI") == "true"


def need(reason_missing: str | None):
    """Skip (outside CI) or fail (under CI) when ``reason_missing`` names what is absent."""
    if reason_missing is None:
        return
    if UNDER_CI:
        pytest.fail(f"CI=true: {reason_missing}")
    pytest.skip(reason_missing, allow_module_level=True)


def need_module(name: str):
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        need(f"{name} is not installed ({exc}); bash .ci/install installs it")


viewer = need_module("clrender.viewer")
vtf = need_module("viser.transforms")


@pytest.fixture(scope="module")
def model():
    return random_baked_model(preset("tiny"), seed=1)


def _viser_state(rng):
    wxyz = rng.normal(size=4)
    return wxyz / np.linalg.norm(wxyz), rng.normal(size=3), rng.uniform(0.4, 1.4)


@pytest.mark.parametrize("seed", range(4))
def test_viser_camera_looks_down_its_z_with_y_down(seed):
    """viser's camera (OpenCV axes) -> clrender's: the centre ray along viser's +z, the top
    edge toward viser's -y (up) at half the vertical fov, the right edge toward +x."""
    wxyz, position, fov_y = _viser_state(np.random.default_rng(seed))
    R = vtf.SO3(wxyz).as_matrix()
    cam = viewer.viser_to_camera(position, wxyz, fov_y, aspect=151 / 101, height=101)
    assert (cam.width, cam.height) == (151, 101)     # odd: pixel (75, 50)'s centre is (cx, cy)
    origins, dirs = generate_rays(cam)
    np.testing.assert_allclose(origins[0, 0], position, atol=1e-6)
    np.testing.assert_allclose(dirs[50, 75], R[:, 2], atol=1e-6)
    t = 50 / 50.5 * np.tan(fov_y / 2)               # top pixel centre: tan of its angle
    np.testing.assert_allclose(dirs[0, 75], (R[:, 2] - t * R[:, 1]) / np.hypot(1.0, t),
                               atol=1e-6)
    t = 75 / 75.5 * (151 / 101) * np.tan(fov_y / 2)  # right pixel centre, square pixels
    np.testing.assert_allclose(dirs[50, -1], (R[:, 2] + t * R[:, 0]) / np.hypot(1.0, t),
                               atol=1e-6)


def test_camera_to_viser_inverts_viser_to_camera():
    cam = Camera.from_fov(0.7, 80, 60, look_at([2.0, -1.0, 1.5], target=[0.1, 0.2, 0.0]))
    wxyz, position, fov_y = viewer.camera_to_viser(cam)
    R = vtf.SO3(wxyz).as_matrix()
    forward = np.array([0.1, 0.2, 0.0]) - [2.0, -1.0, 1.5]
    np.testing.assert_allclose(R[:, 2], forward / np.linalg.norm(forward), atol=1e-12)
    back = viewer.viser_to_camera(position, wxyz, fov_y, cam.width / cam.height, cam.height)
    np.testing.assert_allclose(back.c2w, cam.c2w, atol=1e-12)
    np.testing.assert_allclose((back.fx, back.fy, back.cx, back.cy),
                               (cam.fx, cam.fy, cam.cx, cam.cy), rtol=1e-12)


def test_option_specs_are_the_declared_options():
    ngprt = methods.get("ngprt").renderer
    use_g, march = ngprt.RENDER_OPTIONS["use_G"], ngprt.RENDER_OPTIONS["march"]
    assert viewer.option_specs(ngprt) == [
        viewer.OptionSpec("use_G", bool, True, None, use_g.help),
        viewer.OptionSpec("march", str, "ours", march.choices, march.help)]
    hits = methods.get("ndrf").renderer.RENDER_OPTIONS["hits"]
    assert viewer.OptionSpec("hits", str, hits.default, hits.choices, hits.help) in \
        viewer.option_specs(methods.get("ndrf").renderer)


def test_first_camera_gets_the_orbits_horizontal_fov_and_thumbnails_are_small(tmp_path):
    assert viewer.vertical_fov(0.8, 1.0) == pytest.approx(0.8)
    fov_y = viewer.vertical_fov(0.8, 16 / 9)
    assert np.tan(fov_y / 2) * 16 / 9 == pytest.approx(np.tan(0.4))
    camera = SimpleNamespace(aspect=2.0, fov=None)
    viewer.Viewer.first_camera(SimpleNamespace(model=SimpleNamespace(
        config=SimpleNamespace(scene="bounded"))), camera)
    assert camera.fov == pytest.approx(viewer.vertical_fov(ORBIT["bounded"]["fov_x"], 2.0))
    rgba = np.zeros((300, 200, 4), np.uint8)
    rgba[:150, :, :3], rgba[:150, :, 3] = (10, 200, 30), 255       # top half opaque green
    iio.imwrite(tmp_path / "view.png", rgba)
    thumb = viewer.thumbnail(tmp_path / "view.png")
    assert thumb.shape == (64, 43, 3) and thumb.dtype == np.uint8
    np.testing.assert_array_equal(thumb[5, 5], (10, 200, 30))
    np.testing.assert_array_equal(thumb[-5, 5], (255, 255, 255))   # transparent: white


def test_client_loop_previews_while_moving_then_draws_full_size():
    draws, moves = [], []
    fake = SimpleNamespace(rest_s=0.3, preview_scale=0.25,
                           draw=lambda client, scale: draws.append((time.monotonic(), scale)),
                           first_camera=lambda camera: None)
    callbacks = []
    client = SimpleNamespace(client_id=7, camera=SimpleNamespace(on_update=callbacks.append))
    loop = viewer._ClientLoop(fake, client)
    loop.start()
    try:
        for _ in range(25):                        # 0.5 s of camera messages every 20 ms
            moves.append(time.monotonic())
            callbacks[0](client.camera)
            time.sleep(0.02)
        time.sleep(1.0)
    finally:
        loop.stopped.set()
        loop.wake.set()
        loop.join(5)
    scales = [s for _, s in draws]
    assert 0.25 in scales and scales[-1] == 1.0, scales
    assert draws[-1][0] - moves[-1] >= 0.3, "full size drawn before the camera rested"
    assert scales.count(1.0) == 1, f"the resting view drawn more than once: {scales}"


def test_client_loop_shows_a_failed_frame_and_serves_on():
    calls, errors = [], []

    def draw(client, scale):
        calls.append(scale)
        if len(calls) == 1:
            raise RuntimeError("device lost")

    fake = SimpleNamespace(rest_s=0.05, preview_scale=0.5, draw=draw, show_error=errors.append,
                           first_camera=lambda camera: None)
    callbacks = []
    client = SimpleNamespace(client_id=1, camera=SimpleNamespace(on_update=callbacks.append))
    loop = viewer._ClientLoop(fake, client)
    loop.refresh()                                   # no camera yet: nothing to draw
    loop.start()
    try:
        time.sleep(0.3)
        assert calls == []
        callbacks[0](client.camera)
        deadline = time.monotonic() + 10
        while len(calls) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        loop.stopped.set()
        loop.wake.set()
        loop.join(5)
    assert errors == ["frame failed: RuntimeError('device lost')"] and len(calls) >= 2


def test_option_control_rebuilds_the_renderer(model):
    v = viewer.Viewer(model, port=0)
    try:
        handles = {name: handle for name, handle, _ in v._options}
        assert list(handles) == ["use_G", "march"] and handles["march"].value == "ours"
        handle = handles["use_G"]
        assert handle.value is True and v.renderer.impl.use_G
        before = v.renderer
        handle.value = False                        # what a click in the page does
        assert v.renderer is not before and not v.renderer.impl.use_G
    finally:
        v.stop()


def test_ndrf_model_gets_its_declared_option_controls():
    from clrender import methods
    from clrender.ndrf.config import NDRFConfig
    from clrender.ndrf.random_model import random_ndrf_model

    model = random_ndrf_model(NDRFConfig(thresholds=(1e-4, 1e-2)), seed=0)
    v = viewer.Viewer(model, port=0)
    try:
        declared = [s.name for s in viewer.option_specs(methods.of_model(model).renderer)]
        assert [name for name, _, _ in v._options] == declared
        assert v.renderer.method is methods.get("ndrf")
    finally:
        v.stop()


def test_choice_controls_map_labels_back_to_values():
    made = {}

    class FakeGui:
        def add_dropdown(self, label, options, initial_value, hint):
            made[label] = (options, initial_value, hint)
            return label

    spec = viewer.OptionSpec("levels", int, 2, (1, 2, 4), "how many")
    handle, convert = viewer._add_control(FakeGui(), spec)
    assert made["levels"] == (("1", "2", "4"), "2", "how many")
    assert convert("4") == 4 and isinstance(convert("4"), int)


def test_training_cameras_drawn_as_frustums(model, tmp_path):
    from clrender.data import load_dataset
    from clrender.data.scene import make_scene

    data = make_scene("bounded", tmp_path / "scene", n_train=3, n_test=1, width=16, height=12)
    v = viewer.Viewer(model, data=data, port=0)
    try:
        cams = load_dataset(data, "train").cameras
        assert len(v.frustums) == len(cams) == 3
        for frustum, cam in zip(v.frustums, cams):
            wxyz, position, fov_y = viewer.camera_to_viser(cam)
            np.testing.assert_allclose(frustum.position, position, atol=1e-6)
            assert abs(abs(np.dot(frustum.wxyz, wxyz)) - 1.0) < 1e-6   # q and -q: one rotation
            assert frustum.fov == pytest.approx(fov_y) and frustum.aspect == pytest.approx(16 / 12)
    finally:
        v.stop()


def test_view_command_listens_on_localhost_by_default():
    from clrender.cli import build_parser

    args = build_parser().parse_args(["view", "m.npz"])
    assert (args.host, args.port, args.data) == ("127.0.0.1", 8080, None)
    args = build_parser().parse_args(["view", "m.npz", "--host", "0.0.0.0", "--port", "0"])
    assert (args.host, args.port) == ("0.0.0.0", 0)


def _screenshot(driver) -> np.ndarray:
    import imageio.v3 as iio

    return iio.imread(driver.get_screenshot_as_png())[..., :3].astype(np.float64)


def _central(image: np.ndarray) -> np.ndarray:
    """The part of the page no GUI covers: below the control panel (top right) and the
    notices (top left), right of the axes gizmo (bottom left)."""
    h, w = image.shape[:2]
    return image[int(0.45 * h):int(0.85 * h), int(0.15 * w):int(0.85 * w)]


def _resting_frame(v, client, previous=None):
    """Wait for the full-size frame of a camera at rest (other than ``previous``'s) and
    return it, (Camera, uint8 image)."""
    from bench.tools.browser import wait_for

    seen = {"count": -1, "since": 0.0}

    def rested():
        frame, count = v.last_frame, v.frames_sent
        if count != seen["count"]:
            seen.update(count=count, since=time.monotonic())
            return None
        if frame is None or time.monotonic() - seen["since"] < 1.0:
            return None
        if frame[0].width != client.camera.image_width:
            return None
        if previous is not None and np.allclose(frame[0].c2w, previous[0].c2w):
            return None
        return frame

    return wait_for(rested, 120, "full-size frame at rest")


def _page_error(shot: np.ndarray, frame) -> float:
    """Mean absolute difference (0-255) between the page and the frame the server sent,
    over the central region."""
    from skimage.transform import resize

    # viser lowers the canvas's pixel ratio when WebGL is slow (SwiftShader): the frame is
    # then smaller than the page and stretched over it.
    image = resize(frame[1].astype(np.float64), shot.shape, order=1, anti_aliasing=False)
    return float(np.abs(_central(shot) - _central(image)).mean())


def test_page_draws_frames_and_a_drag_moves_the_camera(model):
    """A real browser: the page shows the rendered frame, a drag on its canvas moves the
    camera, and the page then shows the new view, rendered at full size once it rests."""
    from bench.tools import browser

    need(browser.missing())
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    v = viewer.Viewer(model, port=0, max_size=2048, rest_s=0.3)
    driver = browser.chromium(640, 480)
    try:
        driver.get(v.url)
        assert browser.webgl_renderer(driver), "no WebGL2 in the headless browser"
        client = browser.wait_for(lambda: next(iter(v.server.get_clients().values()), None),
                                  60, "browser connection")
        first = _resting_frame(v, client)
        assert first[0].width / first[0].height == pytest.approx(640 / 480, abs=0.01)
        time.sleep(0.5)                              # the page paints what it received
        shot_a = _screenshot(driver)
        sent_before = v.frames_sent

        canvas = driver.find_element(By.TAG_NAME, "canvas")
        drag = ActionChains(driver).move_to_element(canvas).click_and_hold()
        for _ in range(10):
            drag = drag.move_by_offset(15, 3).pause(0.05)
        drag.release().perform()

        second = _resting_frame(v, client, previous=first)
        time.sleep(0.5)
        shot_b = _screenshot(driver)
        err_a, err_b = _page_error(shot_a, first), _page_error(shot_b, second)
        change = float(np.abs(_central(shot_a) - _central(shot_b)).mean())
        assert v.frames_sent - sent_before >= 2, "no preview frame while the camera moved"
        assert max(err_a, err_b) < 6.0, f"page differs from the frames sent: {err_a}, {err_b}"
        assert change > 3 * max(err_a, err_b, 1.0), f"the view hardly changed: {change}"
    finally:
        driver.quit()
        v.stop()
