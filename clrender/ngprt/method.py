"""NGP-RT plugged into the clrender shell (the hooks of :mod:`clrender.methods`).

Rendering needs numpy and pyopencl only: training and baking (torch) are imported when
called.
"""
from __future__ import annotations

from .baked import FORMAT, load_baked
from .config import PRESETS as _MODEL_PRESETS, VARIANTS
from .render_cl import Renderer

PRESETS = tuple(_MODEL_PRESETS)

__all__ = ["FORMAT", "PRESETS", "Renderer", "load_baked", "add_train_arguments",
           "train_from_args", "bake_run", "check_model_options", "model_spec", "train_for_bench"]


def add_train_arguments(parser) -> None:
    """NGP-RT's options of ``clrender train``."""
    g = parser.add_argument_group("NGP-RT (--method ngprt)")
    g.add_argument("--variant", default="separate-v", choices=VARIANTS,
                   help="feature aggregation (Table 3)")
    g.add_argument("--levels", type=int, default=2, help="fine hash levels L")


def train_from_args(args):
    from .train import train

    return train(args.data, args.out, preset=args.preset, variant=args.variant, L=args.levels,
                 iterations=args.iterations, seed=args.seed, device=args.torch_device,
                 downscale=args.downscale)


def bake_run(run_dir, out_path):
    from .bake import bake_run as bake

    return bake(run_dir, out_path)


def check_model_options(options: dict) -> None:
    """Raise ValueError unless ``options`` are NGP-RT model options (``variant``, ``L``)."""
    unknown = sorted(set(options) - {"variant", "L"})
    if unknown:
        raise ValueError(f"unknown NGP-RT model options {unknown}; expected variant, L")
    if options.get("variant", "separate-v") not in VARIANTS:
        raise ValueError(f"variant {options.get('variant')!r} is not one of {VARIANTS}")
    L = options.get("L", 2)
    if not isinstance(L, int) or isinstance(L, bool) or L < 1:
        raise ValueError(f"L must be an integer >= 1, got {L!r}")


def model_spec(preset: str, variant: str = "separate-v", L: int = 2) -> dict:
    """Everything but data and seed that determines a trained model (the cache key)."""
    from dataclasses import asdict

    from .config import preset as model_preset
    from .train import TRAIN_PRESETS

    return {"model": model_preset(preset, variant=variant, L=L).to_dict(),
            "train": asdict(TRAIN_PRESETS[preset])}


def train_for_bench(data, out, preset: str, seed: int = 0, torch_device=None, teacher=None,
                    variant: str = "separate-v", L: int = 2, downscale: int = 1):
    """Train one benchmark row's model into the run folder ``out``."""
    from .train import train

    return train(str(data), str(out), preset=preset, variant=variant, L=L, seed=seed,
                 device=torch_device, downscale=downscale)
