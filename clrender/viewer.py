"""``clrender view``: a live browser viewer (viser) for a baked model of any method.

The persistent :class:`clrender.Renderer` renders each connected browser's camera: at
``preview_scale`` of the full size while the camera moves, at the full size (the browser's
canvas, its long side capped at ``max_size`` pixels) once it has rested ``rest_s`` seconds.
The GUI panel shows the frame time (render + encode + send) and the method's stage times
(the ``ms_*`` keys of the render result) and offers the method's render options as controls,
built from its ``RENDER_OPTIONS`` (a change rebuilds the renderer); with a dataset its
training cameras are drawn as frustums.

viser's camera has OpenCV axes (it looks down +z, +y points down, ``wxyz`` rotates camera to
world, ``fov`` is vertical); clrender's (:mod:`clrender.camera`) has NeRF/Blender axes (looks
down -z, +y up): the two differ by a rotation of pi about the camera's x axis.

Examples:
    >>> viewer = Viewer("model.npz", data="scenes/bounded", port=0)   # 127.0.0.1, a free port
    >>> print(viewer.url)
    http://127.0.0.1:40123
    >>> viewer.stop()
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
import viser
import viser.transforms as vtf

from . import methods
from .camera import Camera
from .export.serve import DEFAULT_PORT   # viser moves on to the next free port when taken
from .paths import ORBIT
from .renderer import Renderer
from .video import to_uint8

CV_FROM_GL = np.diag([1.0, -1.0, -1.0])  # camera axes: NeRF/Blender <-> OpenCV (its own inverse)
THUMBNAIL = 64               # long side of a training frustum's image, pixels


def vertical_fov(fov_x: float, aspect: float) -> float:
    """The vertical field of view (radians) of a horizontal ``fov_x`` at ``aspect`` (W / H)."""
    return float(2.0 * np.arctan(np.tan(0.5 * fov_x) / aspect))


def thumbnail(file) -> np.ndarray:
    """(h, w, 3) uint8: an image file shrunk to :data:`THUMBNAIL` pixels on its long side
    (JPEGs decoded at a reduced size), transparent pixels on white."""
    from PIL import Image

    with Image.open(file) as im:
        im.draft("RGB", (THUMBNAIL, THUMBNAIL))
        im.thumbnail((THUMBNAIL, THUMBNAIL))
        rgba = im.convert("RGBA")
    white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
    return np.asarray(Image.alpha_composite(white, rgba).convert("RGB"))


def viser_to_camera(position, wxyz, fov_y: float, aspect: float, height: int) -> Camera:
    """A clrender camera for a viser camera state.

    Args:
        position: (3,) camera centre in world space.
        wxyz: (4,) unit quaternion, viser's camera-to-world rotation (OpenCV camera axes).
        fov_y: vertical field of view in radians.
        aspect: image width / height.
        height: image height in pixels (the width is ``round(height * aspect)``).
    Returns:
        a centred pinhole :class:`Camera` with square pixels, NeRF/Blender ``c2w``.
    """
    c2w = np.eye(4)
    c2w[:3, :3] = vtf.SO3(np.asarray(wxyz, np.float64)).as_matrix() @ CV_FROM_GL
    c2w[:3, 3] = position
    height = max(1, int(height))
    width = max(1, round(height * aspect))
    f = 0.5 * height / np.tan(0.5 * fov_y)
    return Camera(f, f, width / 2.0, height / 2.0, width, height, c2w)


def camera_to_viser(camera: Camera) -> tuple[np.ndarray, np.ndarray, float]:
    """viser's (wxyz (4,), position (3,), vertical fov in radians) of a clrender camera."""
    R = camera.c2w[:3, :3] @ CV_FROM_GL
    fov_y = 2.0 * np.arctan(0.5 * camera.height / camera.fy)
    return vtf.SO3.from_matrix(R).wxyz, camera.c2w[:3, 3].copy(), float(fov_y)


@dataclass(frozen=True)
class OptionSpec:
    """One render option of a method: a GUI control and a ``Renderer`` keyword."""

    name: str
    type: type
    default: object
    choices: tuple | None = None
    help: str = ""


def option_specs(renderer_cls) -> list[OptionSpec]:
    """The render options a method's renderer class declares in ``RENDER_OPTIONS``
    (:class:`clrender.contract.Option`, as the method contract requires)."""
    return [OptionSpec(name, opt.type, opt.default, opt.choices, opt.help)
            for name, opt in renderer_cls.RENDER_OPTIONS.items()]


def _add_control(gui, spec: OptionSpec):
    """A GUI control for one option; returns (handle, function: handle value -> option value)."""
    hint = spec.help or None
    if spec.choices:
        by_label = {str(c): c for c in spec.choices}
        handle = gui.add_dropdown(spec.name, tuple(by_label), initial_value=str(spec.default),
                                  hint=hint)
        return handle, by_label.__getitem__
    if spec.type is bool:
        return gui.add_checkbox(spec.name, bool(spec.default), hint=hint), bool
    if spec.type in (int, float):
        return gui.add_number(spec.name, spec.type(spec.default), hint=hint), spec.type
    return gui.add_text(spec.name, str(spec.default), hint=hint), spec.type


def _stats_markdown(out: dict, frame_ms: float, width: int, height: int) -> str:
    stages = ", ".join(f"{k[3:]} {v:.1f}" for k, v in out.items()
                       if k.startswith("ms_") and np.isscalar(v))
    return (f"**frame** {frame_ms:.1f} ms ({1e3 / max(frame_ms, 1e-3):.1f} fps) at "
            f"{width}x{height}  \n**render** {out['ms']:.1f} ms" + (f": {stages}" if stages else ""))


class _ClientLoop(threading.Thread):
    """Renders one browser's camera whenever it changed: a preview while it moves, the full
    size once it rests."""

    def __init__(self, viewer: "Viewer", client):
        super().__init__(daemon=True, name=f"clrender-view-{client.client_id}")
        self.viewer, self.client = viewer, client
        self.wake, self.stopped = threading.Event(), threading.Event()
        self._lock = threading.Lock()
        self.version, self.moved_at = 0, 0.0
        self.shown = (0, 1.0)       # (camera version, scale) of the last frame sent
        client.camera.on_update(self._moved)

    def _moved(self, camera) -> None:
        if self.version == 0:
            self.viewer.first_camera(camera)
        with self._lock:
            self.version += 1
            self.moved_at = time.monotonic()
        self.wake.set()

    def refresh(self) -> None:
        """Render again at the current camera (options or sizes changed), once the browser
        has sent one."""
        with self._lock:
            self.version += 1 if self.version else 0
        self.wake.set()

    def run(self) -> None:
        while not self.stopped.is_set():
            self.wake.wait(self.viewer.rest_s)
            self.wake.clear()
            with self._lock:
                version, moved_at = self.version, self.moved_at
            resting = time.monotonic() - moved_at >= self.viewer.rest_s
            scale = 1.0 if resting else self.viewer.preview_scale
            if version == self.shown[0] and scale <= self.shown[1]:
                continue
            try:
                self.viewer.draw(self.client, scale)
            except Exception as exc:  # noqa: BLE001 - shown in the panel; the loop serves on
                self.viewer.show_error(f"frame failed: {exc!r}")
            self.shown = (version, scale)


class Viewer:
    """A viser server showing ``model`` to every browser that opens :attr:`url`.

    Args:
        model: a loaded model (``clrender.load``) or the path of a baked file, any method.
        data: a dataset folder whose training cameras are drawn as frustums, or None.
        host, port: where the server listens (port 0: any free port; a taken port: the
            next free one).
        device: OpenCL device spec (default ``$CLRENDER_DEVICE``).
        max_size: cap on the long side of a full-size frame, pixels.
        preview_scale: size of the frames drawn while the camera moves, relative to full.
        rest_s: seconds without camera change after which the full size is drawn.
        jpeg_quality: quality of the JPEG frames sent to the browser (1-100).

    Attributes:
        renderer: the :class:`clrender.Renderer` in use (rebuilt when an option changes).
        frustums: viser handles of the training-camera frustums (empty without ``data``).
        frames_sent: frames sent to browsers so far.
        last_frame: (Camera, (H, W, 3) uint8 image) of the last frame sent, or None.
    """

    def __init__(self, model, data=None, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 device=None, max_size: int = 800, preview_scale: float = 0.4,
                 rest_s: float = 0.3, jpeg_quality: int = 90):
        from .bakedfile import trained_downscale

        loaded = hasattr(model, "method")
        self.downscale = 1 if loaded else trained_downscale(model)
        self.model = model if loaded else methods.load(model)
        self.device, self.jpeg_quality, self.rest_s = device, int(jpeg_quality), float(rest_s)
        self.renderer = Renderer(self.model, device=device)
        self.frames_sent, self.last_frame = 0, None
        self._render_lock, self._loops = threading.Lock(), {}
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.scene.set_up_direction("+z")
        self._initial_camera()
        self._build_gui(max_size, preview_scale)
        self.frustums = []
        if data is not None:
            self._draw_training_cameras(data)
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    @property
    def stats(self) -> str:
        """The GUI's text: frame time, size and stage times of the last frame (markdown)."""
        return self._stats.content

    @property
    def max_size(self) -> int:
        return int(self._max_size.value)

    @property
    def preview_scale(self) -> float:
        return float(self._preview.value)

    def _initial_camera(self) -> None:
        orbit = ORBIT[self.model.config.scene]
        el, r = np.deg2rad(orbit["elevation_deg"]), orbit["radius"]
        cam = self.server.initial_camera
        cam.position = (r * np.cos(el), 0.0, r * np.sin(el))
        cam.look_at = (0.0, 0.0, 0.0)
        cam.up = (0.0, 0.0, 1.0)
        # viser's fov is vertical; the orbit's is horizontal: this holds it for a square
        # canvas, and each browser's first camera gets its own aspect's (_ClientLoop).
        cam.fov = orbit["fov_x"]

    def first_camera(self, camera) -> None:
        """A browser's first camera state: its vertical fov set to give the orbit's
        horizontal one at that browser's aspect."""
        camera.fov = vertical_fov(ORBIT[self.model.config.scene]["fov_x"], camera.aspect)

    def _build_gui(self, max_size: int, preview_scale: float) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="medium")
        self._stats = gui.add_markdown("waiting for a frame")
        self._max_size = gui.add_slider("max size", 64, 2048, 16, int(max_size),
                                        hint="long side of a resting frame, pixels")
        self._preview = gui.add_slider("moving scale", 0.1, 1.0, 0.05, float(preview_scale),
                                       hint="frame size while the camera moves, relative")
        for handle in (self._max_size, self._preview):
            handle.on_update(lambda _event: self._refresh_all())
        self._options = []
        for spec in option_specs(methods.of_model(self.model).renderer):
            handle, convert = _add_control(gui, spec)
            handle.on_update(lambda _event: self._rebuild())
            self._options.append((spec.name, handle, convert))

    def _rebuild(self) -> None:
        """A new renderer with the controls' option values (the old one kept on error)."""
        options = {name: convert(handle.value) for name, handle, convert in self._options}
        try:
            renderer = Renderer(self.model, device=self.device, **options)
        except (ValueError, RuntimeError) as exc:
            self.show_error(f"options {options} refused: {exc}")
            return
        with self._render_lock:
            self.renderer = renderer
        self._refresh_all()

    def show_error(self, message: str) -> None:
        """Show ``message`` in the GUI panel in place of the frame statistics."""
        self._stats.content = f"**{message}**"

    def _refresh_all(self) -> None:
        for loop in list(self._loops.values()):
            loop.refresh()

    def _draw_training_cameras(self, data) -> None:
        """The training cameras as frustums, each with a thumbnail: the files are scanned
        (at the model's training downscale) and each image shrunk on its own, never all
        decoded at full size."""
        from .data import scan_dataset

        views = scan_dataset(data, "train", self.downscale)
        cameras = views.final_cameras()
        centres = np.stack([c.origin for c in cameras])
        scale = 0.03 * float(np.median(np.linalg.norm(centres - centres.mean(0), axis=1)) or 1.0)
        for i, (camera, file) in enumerate(zip(cameras, views.files)):
            wxyz, position, fov_y = camera_to_viser(camera)
            self.frustums.append(self.server.scene.add_camera_frustum(
                f"/train/{i:04d}", fov=fov_y, aspect=camera.width / camera.height, scale=scale,
                wxyz=wxyz, position=position, image=thumbnail(file)))

    def _connect(self, client) -> None:
        loop = _ClientLoop(self, client)
        self._loops[client.client_id] = loop
        loop.start()

    def _disconnect(self, client) -> None:
        loop = self._loops.pop(client.client_id, None)
        if loop is not None:
            loop.stopped.set()
            loop.wake.set()

    def frame_camera(self, client, scale: float) -> Camera:
        """The clrender camera of a client's view at ``scale`` of the full frame size."""
        cam = client.camera
        full = min(1.0, self.max_size / max(cam.image_width, cam.image_height))
        return viser_to_camera(cam.position, cam.wxyz, cam.fov, cam.aspect,
                               round(cam.image_height * full * scale))

    def draw(self, client, scale: float) -> None:
        """Render a client's view at ``scale`` of the full size and send it (JPEG)."""
        camera = self.frame_camera(client, scale)
        start = time.perf_counter()
        with self._render_lock:
            out = self.renderer.render(camera)
        image = to_uint8(out["rgb"])
        client.scene.set_background_image(image, format="jpeg", jpeg_quality=self.jpeg_quality)
        client.flush()
        self.frames_sent, self.last_frame = self.frames_sent + 1, (camera, image)
        frame_ms = 1e3 * (time.perf_counter() - start)
        self._stats.content = _stats_markdown(out, frame_ms, camera.width, camera.height)

    def stop(self) -> None:
        """Stop the client loops (each finishes its frame) and the server."""
        loops = [self._loops.pop(client_id) for client_id in list(self._loops)]
        for loop in loops:
            loop.stopped.set()
            loop.wake.set()
        for loop in loops:
            loop.join(10.0)
        self.server.stop()


def serve(model, data=None, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
          device=None, max_size: int = 800) -> None:
    """Run a :class:`Viewer` until Ctrl-C (``clrender view``)."""
    viewer = Viewer(model, data=data, host=host, port=port, device=device, max_size=max_size)
    print(f"clrender view: {viewer.url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
