"""NDRF plugged into the clrender shell (meets :class:`clrender.methods.Method`), including
its own commands: ``clrender ndrf extract`` (duplex meshes from an NGP-RT teacher) and
``clrender ndrf init`` (an untrained model on extracted meshes).

Rendering needs numpy, pyopencl and embreex: training and extraction are imported when
called.
"""
from __future__ import annotations

import json
from pathlib import Path

from ..methods import Option
from .baked import FORMAT, load_baked
from .config import PRESETS as _PRESETS
from .render import Renderer

PRESETS = tuple(_PRESETS)
DEFAULT_PRESET = "cpu"
TRAIN_OPTIONS = {
    "teacher": Option(str, None, "baked NGP-RT teacher (.npz) to distil", required=True),
    "thresholds": Option(float, None, "alpha thresholds of the K meshes, increasing "
                         "(default: the preset's; paper 1e-4 1e-2)", nargs="+"),
    "kernel_size": Option(int, None, "shader conv kernel side (2: the paper's; 1: an MLP)",
                          choices=(1, 2)),
    "distill": Option(bool, True, "first half of training on teacher renderings"),
    "outer_only": Option(bool, False, "only the outer (first) mesh of the thresholds: one "
                         "surface, as NDRF Table 3's single-surface row"),
}
TEACHER = "ngprt"
ABLATIONS = Path(__file__).resolve().parent / "ablations"
CURVE_TABLE = "ndrf-table3"
LEGACY_RUNS = False

__all__ = ["FORMAT", "PRESETS", "DEFAULT_PRESET", "TRAIN_OPTIONS", "TEACHER", "ABLATIONS",
           "CURVE_TABLE", "LEGACY_RUNS", "Renderer", "load_baked", "train", "train_steps",
           "bake_run", "check_model_options", "model_spec", "add_commands"]


def train(data, out, preset: str = DEFAULT_PRESET, *, seed: int = 0,
          iterations: int | None = None, torch_device=None, progress: bool = True,
          on_step=None, downscale: int = 1, teacher=None, **options):
    """Train an NDRF run (:func:`clrender.ndrf.train.train`) from the baked NGP-RT
    ``teacher``; ``on_step(step, bake)`` as :data:`clrender.methods.StepHook`."""
    from .train import train as train_ndrf

    if teacher is None:
        raise ValueError("NDRF training needs a teacher: --teacher TEACHER.npz (a baked "
                         "NGP-RT model), or model option `teacher` in a bench row")
    return train_ndrf(data, out, teacher=teacher, preset=preset, iterations=iterations,
                      seed=seed, device=torch_device, progress=progress, on_step=on_step,
                      downscale=downscale, **options)


def train_steps(preset: str, iterations: int | None = None) -> tuple[int, int]:
    from .train import TRAIN_PRESETS

    tcfg = TRAIN_PRESETS[preset]
    return (tcfg.iterations if iterations is None else int(iterations)), tcfg.log_every


def bake_run(run_dir, out_path):
    from .train import bake_run as bake

    return bake(run_dir, out_path)


def check_model_options(options: dict) -> None:
    """Raise ValueError unless ``options`` are NDRF model options of a bench row (with
    ``teacher`` a dict of NGP-RT model options)."""
    unknown = sorted(set(options) - set(TRAIN_OPTIONS))
    if unknown:
        raise ValueError(f"unknown NDRF model options {unknown}; expected "
                         f"{sorted(TRAIN_OPTIONS)}")
    for name, value in options.items():
        if name == "teacher":
            if not isinstance(value, dict):
                raise ValueError(f"model option 'teacher' takes a table of NGP-RT model "
                                 f"options, got {value!r}")
        else:
            TRAIN_OPTIONS[name].check(name, value)


def model_spec(preset: str, **options) -> dict:
    from .train import model_spec as spec

    return spec(preset, **options)


def _cmd_extract(args) -> int:
    from ..methods import load
    from .mesh import extract_duplex, extract_preset, write_meshes

    teacher = load(args.teacher)
    if getattr(teacher, "method", None) != "ngprt":
        raise ValueError(f"{args.teacher}: a teacher must be a baked NGP-RT model, "
                         f"this is {teacher.method!r}")
    cameras = None
    if args.data:
        from ..data import load_dataset

        cameras = load_dataset(args.data, split="train").cameras
    overrides = {k: v for k, v in (("N", args.grid), ("face_budget", args.faces))
                 if v is not None}
    meshes, report = extract_duplex(teacher, extract_preset(args.preset, **overrides),
                                    thresholds=args.thresholds, cameras=cameras)
    paths = write_meshes(meshes, report, args.out)
    print(json.dumps(report["meshes"], indent=2))
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def _cmd_init(args) -> int:
    from .init import init_model_from_meshes

    path = init_model_from_meshes(args.meshes, args.out, seed=args.seed)
    print(f"wrote {path} (untrained: random features and shader weights)")
    return 0


def add_commands(sub) -> None:
    """``clrender ndrf extract | init``."""
    s = sub.add_parser("ndrf", help="NDRF tools: duplex mesh extraction, model init")
    ss = s.add_subparsers(dest="ndrf_command", required=True)
    e = ss.add_parser("extract", help="duplex meshes from a baked NGP-RT teacher (PLY + report)")
    e.add_argument("teacher", help="baked NGP-RT model (.npz)")
    e.add_argument("--out", required=True, help="folder for mesh_<k>.ply and report.json")
    e.add_argument("--preset", default="cpu", choices=PRESETS)
    e.add_argument("--grid", type=int, default=None, help="N of the N^3 density grid")
    e.add_argument("--thresholds", type=float, nargs="+", default=None,
                   help="alpha thresholds, increasing (paper: 1e-4 1e-2)")
    e.add_argument("--faces", type=int, default=None, help="decimate each mesh to this many faces")
    e.add_argument("--data", default=None, help="training dataset: cull faces no camera sees")
    e.set_defaults(func=_cmd_extract)
    i = ss.add_parser("init", help="an untrained NDRF model on extracted meshes")
    i.add_argument("meshes", help="folder written by `clrender ndrf extract`")
    i.add_argument("--out", required=True)
    i.add_argument("--seed", type=int, default=0)
    i.set_defaults(func=_cmd_init)
