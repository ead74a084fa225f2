"""NDRF plugged into the clrender shell (the hooks of :mod:`clrender.methods`), including
its own commands: ``clrender ndrf extract`` (duplex meshes from an NGP-RT teacher) and
``clrender ndrf init`` (an untrained model on extracted meshes).

Rendering needs numpy, pyopencl and embreex: training and extraction are imported when
called.
"""
from __future__ import annotations

import json

from .baked import FORMAT, load_baked
from .config import PRESETS as _PRESETS
from .render import Renderer

PRESETS = tuple(_PRESETS)

__all__ = ["FORMAT", "PRESETS", "Renderer", "load_baked", "add_train_arguments",
           "train_from_args", "bake_run", "check_model_options", "model_spec",
           "train_for_bench", "add_commands"]


def add_train_arguments(parser) -> None:
    """NDRF's options of ``clrender train``."""
    g = parser.add_argument_group("NDRF (--method ndrf)")
    g.add_argument("--teacher", default=None, help="baked NGP-RT teacher (.npz) to distil")


def train_from_args(args):
    from .train import train

    if not args.teacher:
        raise ValueError("--method ndrf needs --teacher TEACHER.npz (a baked NGP-RT model)")
    return train(args.data, args.out, teacher=args.teacher, preset=args.preset,
                 iterations=args.iterations, seed=args.seed, device=args.torch_device,
                 downscale=args.downscale)


def bake_run(run_dir, out_path):
    from .train import bake_run as bake

    return bake(run_dir, out_path)


def check_model_options(options: dict) -> None:
    """Raise ValueError unless ``options`` are NDRF model/training options."""
    from .train import MODEL_OPTIONS

    unknown = sorted(set(options) - set(MODEL_OPTIONS) - {"teacher"})
    if unknown:
        raise ValueError(f"unknown NDRF model options {unknown}; expected "
                         f"{sorted(MODEL_OPTIONS)} and teacher")


def model_spec(preset: str, **options) -> dict:
    from .train import model_spec as spec

    return spec(preset, **options)


def train_for_bench(data, out, preset: str, seed: int = 0, torch_device=None, teacher=None,
                    downscale: int = 1, **options):
    from .train import train

    if teacher is None:
        raise ValueError("an NDRF row needs model option `teacher` (NGP-RT model options)")
    return train(str(data), str(out), teacher=teacher, preset=preset, seed=seed,
                 device=torch_device, downscale=downscale, **options)


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
