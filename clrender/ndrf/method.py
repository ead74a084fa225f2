"""NDRF plugged into the clrender shell: its :class:`clrender.contract.MethodSpec`,
``METHOD``, including its own commands: ``clrender ndrf extract`` (duplex meshes from an
NGP-RT teacher) and ``clrender ndrf init`` (an untrained model on extracted meshes).

Rendering needs numpy and pyopencl (embreex for the Embree hit path, imported when it casts):
training and extraction are imported when called.
"""
from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from ..contract import BenchSpec, MethodSpec, Option, PaperSmoke, Teacher, preset_steps
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
TEACHER = Teacher("teacher", "ngprt")
ABLATIONS = Path(__file__).resolve().parent / "ablations"
CURVE_TABLE = "ndrf-table3"
LIBRARIES = ("embreex", "trimesh", "fast-simplification", "scikit-image")
_PACKAGE = Path(__file__).resolve().parent.parent
# What trains and bakes a model (bench's cache key, beside the shell's data loaders and
# run folder): all of NDRF, and, since distillation views are rendered by NGP-RT's OpenCL
# renderer, that renderer and the kernels. (A teacher's own code keys the teacher, whose
# key is in ours.)
SOURCES = (Path(__file__).resolve().parent,
           *(_PACKAGE / "ngprt" / f for f in ("render_cl.py", "baked.py", "config.py",
                                              "space.py", "marches.py")),
           Path(str(resources.files("clrender.kernels"))), _PACKAGE / "device.py")

__all__ = ["METHOD"]


def train(data, out, preset: str = DEFAULT_PRESET, *, seed: int = 0,
          iterations: int | None = None, torch_device=None, progress: bool = True,
          on_step=None, downscale: int = 1, teacher=None, **options):
    """Train an NDRF run (:func:`clrender.ndrf.train.train`) from the baked NGP-RT
    ``teacher``; ``on_step(step, bake)`` as :data:`clrender.contract.StepHook`."""
    from .train import train as train_ndrf

    if teacher is None:
        raise ValueError("NDRF training needs a teacher: --teacher TEACHER.npz (a baked "
                         "NGP-RT model), or model option `teacher` in a bench row")
    return train_ndrf(data, out, teacher=teacher, preset=preset, iterations=iterations,
                      seed=seed, device=torch_device, progress=progress, on_step=on_step,
                      downscale=downscale, **options)


def bake_run(run_dir, out_path):
    from .train import bake_run as bake

    return bake(run_dir, out_path)


def model_spec(preset: str, **options) -> dict:
    from .train import model_spec as spec

    return spec(preset, **options)


def example_model(path) -> Path:
    """A random model (the default config, K = 2, seed 0) baked to ``path``."""
    from .baked import save_baked
    from .config import NDRFConfig
    from .random_model import random_ndrf_model

    return save_baked(random_ndrf_model(NDRFConfig(), seed=0), path)


def _paper_smoke(*args) -> dict:
    from .paper_smoke import run

    return run(*args)


PAPER_SMOKE = PaperSmoke(
    {"distill_views": Option(int, 4, "distillation views (the paper's: 1000)"),
     "extract_N": Option(int, None, "extraction grid N (default: the paper preset's, 512)",
                         flag="--extract-N")},
    _paper_smoke)


def _cmd_extract(args) -> int:
    from ..extras import require

    require("train", "`clrender ndrf extract`")
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
    from ..extras import require

    require("train", "`clrender ndrf init`", modules=("trimesh",))
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


METHOD = MethodSpec(
    format=FORMAT, presets=PRESETS, default_preset=DEFAULT_PRESET, renderer=Renderer,
    load_baked=load_baked, train=train, bake_run=bake_run, train_options=TRAIN_OPTIONS,
    add_commands=add_commands,
    bench=BenchSpec(model_spec, preset_steps(f"{__package__}.train"), sources=SOURCES,
                    libraries=LIBRARIES, teacher=TEACHER, ablations=ABLATIONS,
                    curve_table=CURVE_TABLE, example_model=example_model,
                    paper_smoke=PAPER_SMOKE))
