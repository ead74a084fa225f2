"""The toy method's plug-in: a sphere of one flat colour (centre 0, radius from the model
options), rendered by ``toy.cl`` (one ray per work-item) with :func:`render_reference` as
its numpy twin. "Training" moves the colour towards the mean of the training pixels the
sphere covers, one random view a step; it uses the shell's run folder like the real methods.

It declares itself as ``METHOD``, a :class:`clrender.contract.MethodSpec`. Only public
clrender APIs are used (contract, runs, bakedfile, camera, device, data): nothing in
clrender names this method.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyopencl as cl
import torch

from clrender import bakedfile, buildlog
from clrender.camera import generate_rays
from clrender.device import event_ms, get_runtime
from clrender.contract import BenchSpec, MethodSpec, Option, Stat
from clrender.runs import RunFolder, pick_device

FORMAT, VERSION = "clrender-toy", 1
PRESETS = ("tiny",)
DEFAULT_PRESET = "tiny"
ITERATIONS, LOG_EVERY, CHECKPOINT_EVERY = {"tiny": 20}, 5, 10
TRAIN_OPTIONS = {"radius": Option(float, 0.6, "sphere radius (scene units)")}
KERNEL = Path(__file__).resolve().parent / "toy.cl"
F32 = np.float32


@dataclass(frozen=True)
class ToyConfig:
    scene: str = "bounded"
    radius: float = 0.6


@dataclass(frozen=True)
class ToyModel:
    """config, and ``colour``: (3,) float32 RGB in [0, 1]."""

    config: ToyConfig
    colour: np.ndarray


def render_reference(model: ToyModel, origins, dirs, background, gain: float = 1.0):
    """(rgb (H, W, 3) float32, hit (H, W) float32 0/1) of rays against the sphere; the numpy
    twin of toy.cl (float32, the kernel's order of operations)."""
    o, d = origins.astype(F32), dirs.astype(F32)
    half_b = d[..., 0] * o[..., 0] + d[..., 1] * o[..., 1] + d[..., 2] * o[..., 2]
    c = (o[..., 0] * o[..., 0] + o[..., 1] * o[..., 1] + o[..., 2] * o[..., 2]) \
        - F32(model.config.radius) * F32(model.config.radius)
    disc = half_b * half_b - c
    hit = (disc >= 0) & (-half_b + np.sqrt(np.maximum(disc, 0)) > 0)
    colour = _shown(model, gain)
    rgb = np.where(hit[..., None], colour, np.asarray(background, F32)).astype(F32)
    return rgb, hit.astype(F32)


def _shown(model: ToyModel, gain: float) -> np.ndarray:
    return np.clip(model.colour * F32(gain), 0, 1).astype(F32)


class Renderer:
    """The OpenCL renderer of a toy model."""

    RENDER_OPTIONS = {"gain": Option(float, 1.0, "colour gain")}
    SCALAR_STATS = {"Hit": Stat("hit", "{:.3f}", "share of pixels on the sphere")}
    TIME_NOTE = "OpenCL kernel time per frame (toy sphere)"
    _programs: dict = {}

    def __init__(self, model: ToyModel, device=None, gain: float = 1.0):
        self.model, self.gain = model, float(gain)
        self.runtime = get_runtime(device)
        ctx = self.runtime.context
        if ctx not in self._programs:
            # Correctly rounded sqrt: the hit test is then numpy's, bit for bit.
            self._programs[ctx] = buildlog.build(ctx, KERNEL.read_text(),
                                                 ["-cl-fp32-correctly-rounded-divide-sqrt"])
        self.kernel = cl.Kernel(self._programs[ctx], "toy_render")

    def render(self, camera, background=None, stats: bool = False) -> dict:
        bg = (1.0, 1.0, 1.0) if background is None else background
        origins, dirs = generate_rays(camera)
        n, mf, q = camera.width * camera.height, cl.mem_flags, self.runtime.queue
        ctx = self.runtime.context
        bufs = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))
                for a in (origins, dirs)]
        rgb_buf = cl.Buffer(ctx, mf.WRITE_ONLY, 12 * n)
        hit_buf = cl.Buffer(ctx, mf.WRITE_ONLY, 4 * n)
        colour = _shown(self.model, self.gain)
        args = [*bufs, *map(F32, (0, 0, 0, self.model.config.radius, *colour, *bg)), np.int32(n),
                rgb_buf, hit_buf]
        event = self.kernel(q, (n,), None, *args)
        ms = event_ms(event)
        rgb = np.empty((camera.height, camera.width, 3), F32)
        hit = np.empty((camera.height, camera.width), F32)
        cl.enqueue_copy(q, rgb, rgb_buf)
        cl.enqueue_copy(q, hit, hit_buf)
        out = {"rgb": rgb, "ms_shade": ms, "ms": ms}
        if stats:
            out["hit"] = hit
        return out


def load_baked(path) -> ToyModel:
    manifest, arrays = bakedfile.read(path, FORMAT, VERSION, keys=("config",))
    bakedfile.check_arrays(arrays, {"colour": ((3,), np.dtype(F32))}, str(path))
    return ToyModel(ToyConfig(**manifest["config"]), arrays["colour"])


def save_baked(model: ToyModel, path) -> Path:
    config = {"scene": model.config.scene, "radius": model.config.radius}
    return bakedfile.save(path, {"format": FORMAT, "version": VERSION, "config": config},
                          {"colour": model.colour.astype(F32)})


def train(data, out, preset: str = DEFAULT_PRESET, *, seed: int = 0,
          iterations: int | None = None, torch_device=None, progress: bool = True,
          on_step=None, downscale: int = 1, radius: float = 0.6) -> Path:
    from clrender.runs import training_data

    ds, data_path = training_data(data, downscale)
    n_iter, _ = METHOD.bench.train_steps(preset, iterations)
    config = ToyConfig(ds.scene, float(radius))
    run = RunFolder(out, {"method": "toy", "model": {"scene": ds.scene, "radius": radius},
                          "iterations": n_iter, "preset": preset, "seed": seed,
                          "data": data_path, "downscale": downscale})
    state = run.resume_state(pick_device(torch_device))
    colour = torch.full((3,), 0.5) if state is None else state["colour"]
    start = 0 if state is None else int(state["step"])
    run.write_config()
    for step in run.steps(start, n_iter, LOG_EVERY, CHECKPOINT_EVERY, "toy", progress):
        i = int(np.random.default_rng([seed, step]).integers(len(ds.images)))
        model = ToyModel(config, colour.numpy().astype(F32))
        _, hit = render_reference(model, *generate_rays(ds.cameras[i]), ds.background)
        target = ds.images[i][hit > 0].mean(axis=0) if hit.any() else colour.numpy()
        colour = colour + 0.5 * (torch.as_tensor(target, dtype=torch.float32) - colour)
        rgb, _ = render_reference(ToyModel(config, colour.numpy()), *generate_rays(ds.cameras[i]),
                                  ds.background)
        psnr = -10.0 * math.log10(max(float(np.mean((rgb - ds.images[i]) ** 2)), 1e-10))
        run.after_step(step, lambda: {"psnr": psnr}, lambda: {"colour": colour})
        if on_step is not None:
            on_step(step, lambda: ToyModel(config, colour.numpy().astype(F32)))
    return run.dir


def bake_run(run_dir, out_path) -> Path:
    run = Path(run_dir)
    conf = json.loads((run / "config.json").read_text())
    state = torch.load(run / "checkpoint.pt", weights_only=True)
    model = ToyModel(ToyConfig(**conf["model"]), state["colour"].numpy().astype(F32))
    return save_baked(model, out_path)


def model_spec(preset: str, radius: float = 0.6) -> dict:
    return {"model": {"radius": radius}, "iterations": ITERATIONS[preset]}


def example_model(path) -> Path:
    """A mid-grey sphere of the default radius, baked to ``path``."""
    return save_baked(ToyModel(ToyConfig(), np.full(3, 0.5, F32)), path)


def _cmd_colour(args) -> int:
    print(" ".join(f"{c:.4f}" for c in load_baked(args.model).colour))
    return 0


def add_commands(subparsers) -> None:
    """``clrender toy colour MODEL``: print a toy model's colour."""
    s = subparsers.add_parser("toy", help="toy method tools")
    ss = s.add_subparsers(dest="toy_command", required=True)
    c = ss.add_parser("colour", help="print the model's colour")
    c.add_argument("model")
    c.set_defaults(func=_cmd_colour)


METHOD = MethodSpec(
    format=FORMAT, presets=PRESETS, default_preset=DEFAULT_PRESET, renderer=Renderer,
    load_baked=load_baked, train=train, bake_run=bake_run, train_options=TRAIN_OPTIONS,
    add_commands=add_commands,
    bench=BenchSpec(model_spec, lambda preset: (ITERATIONS[preset], LOG_EVERY),
                    ablations=Path(__file__).resolve().parent / "ablations",
                    curve_table="toy-table", example_model=example_model))
