"""NGP-RT plugged into the clrender shell: its :class:`clrender.contract.MethodSpec`,
``METHOD``.

Rendering needs numpy and pyopencl only: training and baking (torch) are imported when
called.
"""
from __future__ import annotations

from pathlib import Path

from ..contract import BenchSpec, MethodSpec, Option, PaperSmoke, Stat, preset_steps
from .baked import FORMAT, G_METRICS, load_baked
from .config import ENGINES, GRIDS, PRESETS as _MODEL_PRESETS, VARIANTS
from .marches import MARCHES
from .render_cl import Renderer as _CLRenderer

PRESETS = tuple(_MODEL_PRESETS)
DEFAULT_PRESET = "cpu"
TRAIN_OPTIONS = {
    "variant": Option(str, "separate-v", "feature aggregation (Table 3)", choices=VARIANTS),
    "L": Option(int, 2, "fine hash levels L", flag="--levels", minimum=1),
    "engine": Option(str, "fast", "training engine: fast (fused C++ stages, CPU; elsewhere "
                     "the torch engine) or torch (autograd, the reference)", choices=ENGINES),
    "log2_T": Option(int, None, "fine hash tables of 2^N entries a level (default: the "
                     "preset's; paper 22)", flag="--log2-T", minimum=10),
    "batch": Option(int, None, "samples a training batch aims at, its ray cap scaled alike "
                    "(default: the preset's; paper 2^21 = 2097152)", minimum=1024),
}
BAKE_OPTIONS = {
    "G_metric": Option(str, "box", "what the occupancy distance grid G measures: box (from a "
                       "voxel's closest point: the march with G takes the samples it takes "
                       "without) or centre (the paper's, from the voxel's centre: longer steps)",
                       choices=G_METRICS, flag="--G-metric"),
    "grids": Option(str, "preset", "the empty-space grids: preset (occupancy at the model's "
                    "L_C) or paper (occupancy 512^3 .. 32^3 and G 256^3, culled at 512^3)",
                    choices=GRIDS),
}
ABLATIONS = Path(__file__).resolve().parent / "ablations"
CURVE_TABLE = "table2"
# What trains and bakes a model (bench's cache key, beside the shell's data loaders and
# run folder): model, torch ops, encoding, space, training (its engines and stage clock),
# baking and the baked format.
SOURCES = tuple(Path(__file__).resolve().parent / f for f in (
    "config.py", "model.py", "torch_ops.py", "encoding.py", "space.py", "train.py",
    "engine.py", "fused.py", "fused_grid.cpp", "stages.py", "bake.py", "baked.py"))

__all__ = ["METHOD"]


class Renderer(_CLRenderer):
    """:class:`clrender.ngprt.render_cl.Renderer` with its declared options and statistics;
    renders with ``stats`` count the reads per ray (the counting build, ``count_reads``)."""

    RENDER_OPTIONS = {"use_G": Option(bool, True, "march with the occupancy distance grid G "
                                      "(Table 4)", flag="--no-G"),
                      "march": Option(str, "ours", "the march (Table 4): ours (one exit code "
                                      "a point, the larger skip) or the paper's (levels read "
                                      "coarse to fine, Eq. 9)", choices=MARCHES)}
    SCALAR_STATS = {"Marching": Stat("n_march", "{:.1f}", "marching points per ray"),
                    "Occupied": Stat("n_occ", "{:.1f}", "occupied samples per ray"),
                    "Empty": Stat("n_empty", "{:.1f}", "empty marching points per ray "
                                  "(marching minus occupied)"),
                    "Reads": Stat("n_reads", "{:.1f}", "global-memory reads per ray: "
                                  "occupancy, G, feature corners"),
                    "Skip reads": Stat("n_skip_reads", "{:.1f}",
                                       "occupancy and G reads per ray")}
    TIME_NOTE = "OpenCL kernel time per frame (ray marching + deferred MLP)"

    def __init__(self, model, device=None, **options):
        super().__init__(model, device=device, count_reads=True, **options)


def train(data, out, preset: str = DEFAULT_PRESET, *, seed: int = 0,
          iterations: int | None = None, torch_device=None, progress: bool = True,
          on_step=None, downscale: int = 1, variant: str = "separate-v", L: int = 2,
          engine: str = "fast", log2_T: int | None = None, batch: int | None = None):
    """Train an NGP-RT run (:func:`clrender.ngprt.train.train`); ``on_step(step, bake)`` as
    :data:`clrender.contract.StepHook` (``bake()``: the training state baked in memory)."""
    from .train import train as train_ngprt

    return train_ngprt(data, out, preset=preset, variant=variant, L=L, iterations=iterations,
                       seed=seed, device=torch_device, progress=progress, downscale=downscale,
                       engine=engine, log2_T=log2_T, batch=batch,
                       on_step=None if on_step is None else _step_hook(data, on_step, downscale))


def _step_hook(data, on_step, downscale: int = 1):
    """NGP-RT's ``on_step(step, model, occ, gamma)`` as ``on_step(step, bake)``: ``bake()``
    bakes the training state in memory, culled with the training cameras as ``bake_run``."""
    from ..data import load_dataset
    from .bake import bake_state
    from .baked import validate

    train_set = data if hasattr(data, "images") else load_dataset(data, split="train",
                                                                  downscale=downscale)

    def bake(model, occ, gamma):
        baked = bake_state(model, occ.binary, gamma, train_set)
        validate(baked, "in-memory NGP-RT model")
        return baked

    return lambda step, model, occ, gamma: on_step(step, lambda: bake(model, occ, gamma))


def bake_run(run_dir, out_path, **options):
    """Bake a run folder; ``options``: :data:`BAKE_OPTIONS`."""
    from .bake import bake_run as bake

    return bake(run_dir, out_path, **options)


def model_spec(preset: str, variant: str = "separate-v", L: int = 2,
               engine: str = "fast", log2_T: int | None = None,
               batch: int | None = None) -> dict:
    """Everything but data and seed that determines a trained model (the cache key, which
    names the training engine)."""
    from dataclasses import asdict

    from .train import sized

    cfg, tcfg = sized(preset, variant, L, log2_T=log2_T, batch=batch)
    return {"model": cfg.to_dict(), "train": asdict(tcfg), "engine": engine}


def example_model(path) -> Path:
    """A random `cpu`-preset model (separate-v, L = 2, seed 0) baked to ``path``."""
    from .baked import save_baked
    from .config import preset
    from .random_model import random_baked_model

    return save_baked(random_baked_model(preset("cpu", variant="separate-v", L=2), seed=0), path)


def _paper_smoke(*args) -> dict:
    from .paper_smoke import run

    return run(*args)


PAPER_SMOKE = PaperSmoke(
    {"occ_fraction": Option(float, 2.0 ** -12, "share of the occupancy grid's cells "
                            "re-evaluated per update (no warm-up)"),
     "cull_rays": Option(int, 1 << 10, "training rays of the bake's visibility culling"),
     "batch_samples": Option(int, [1 << 14, 1 << 16], "two batch sizes (samples) whose peak "
                             "memory difference gives the training memory per sample",
                             nargs=2)},
    _paper_smoke)


METHOD = MethodSpec(
    format=FORMAT, presets=PRESETS, default_preset=DEFAULT_PRESET, renderer=Renderer,
    load_baked=load_baked, train=train, bake_run=bake_run, train_options=TRAIN_OPTIONS,
    bake_options=BAKE_OPTIONS,
    bench=BenchSpec(model_spec, preset_steps(f"{__package__}.train"), sources=SOURCES,
                    ablations=ABLATIONS, curve_table=CURVE_TABLE, example_model=example_model,
                    paper_smoke=PAPER_SMOKE))
