"""Training NDRF (PyTorch, CPU or CUDA): per-vertex features and the conv shader on fixed
duplex meshes, distilled from a baked NGP-RT teacher.

The K meshes are extracted once from the teacher (culled with the training cameras) into
``RUN/meshes/``; every view's rays are cast into them once (Embree) and the hits kept in
memory, or, beyond a memory budget (``view_budget``: by default half the memory available,
:func:`clrender.ndrf.view_memory.view_budget`), in memory-mapped files in the run folder
that are freed when the training ends (:meth:`ViewSet.build`; the same results). A step
takes one view (a full image or a random patch), gathers the vertex features by
barycentric weights, runs :class:`NDRFShader` (the torch twin of
:func:`clrender.ndrf.shader_ref.shade_reference`, docs/ndrf.md) and minimises the MSE.
The first half of the iterations uses teacher renderings of distillation views, the second
half the training images (``distill=False``: training images only). Adam, learning rate
decaying exponentially from 1e-3 to 1e-5 (the paper; the short CPU presets from 1e-2 to
1e-4).

A run folder (:class:`clrender.runs.RunFolder`) holds ``config.json`` (``"method":
"ndrf"``, the NDRF, training and extraction configs, data and teacher, seed),
``meshes/``, ``distill.npz``,
``checkpoint.pt`` (features, conv weights, optimiser state, step, steps skipped) and
``log.jsonl``. A step whose loss or gradients are not finite is skipped, as in every
method (:mod:`clrender.runs`); its ``nonfinite-step-N.pt`` holds the model, the phase,
the view and its window (y0, x0, height, width).

Examples:
    >>> run = train("/tmp/scn_b", "/tmp/ndrf_b", teacher="/tmp/teacher.npz", preset="cpu")
    >>> bake_run(run, "/tmp/ndrf_b.npz")

References: NDRF (Wan et al., CVPR 2023) §3.3, §4.1 "Optimization Details"; supplement §2.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..device import select_device
from ..runs import RunFolder, finite_step, mse_psnr, pick_device, set_lr
from .baked import NDRFModel, save_baked, validate
from .config import NDRFConfig, preset as ndrf_preset
from .init import initial_model, load_meshes
from .mesh import extract_preset
from .shader_torch import NDRFShader, ViewSet
from .view_memory import view_budget as resolve_view_budget

F32 = np.float32

# The options a benchmark row may set, and their types.
MODEL_OPTIONS = {"thresholds": list, "kernel_size": int, "distill": bool, "outer_only": bool}


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (§3.3, §4.1); presets change sizes, never the method.

    Attributes:
        iterations: optimiser steps (paper: 200k).
        distill: first ``distill_fraction`` of the steps on teacher renderings of
            ``n_distill`` distillation views, the rest on the training images; False:
            training images only (the "no distillation" ablation).
        n_distill: distillation views (paper: 1000).
        distill_fraction: share of the iterations on distillation views (paper: half).
        patch: side of the random square patch a step shades; 0, or a patch that covers
            the image: the full image.
        lr, lr_final: Adam learning rate, decaying exponentially from lr to lr_final.
        betas, eps: Adam's.
        extract: the mesh extraction preset (:data:`clrender.ndrf.mesh.PRESETS`).
        face_budget: faces per mesh after decimation; None: the extraction preset's.
        checkpoint_every, log_every: in iterations.
    """

    iterations: int = 200_000
    distill: bool = True
    n_distill: int = 1000
    distill_fraction: float = 0.5
    patch: int = 0
    lr: float = 1e-3
    lr_final: float = 1e-5
    betas: tuple = (0.9, 0.999)
    eps: float = 1e-8
    extract: str = "paper"
    face_budget: int | None = None
    checkpoint_every: int = 5000
    log_every: int = 100


# Short runs take ten times larger steps, decaying over the same two decades (why:
# docs/guides/training.md, "NDRF training").
TRAIN_PRESETS: dict[str, TrainConfig] = {
    "paper": TrainConfig(),
    # Full 200x200 frames, a duplex run in minutes on 2 CPU cores; 60k faces per mesh, as
    # good as more at this resolution and step count for less time a step
    # (docs/guides/training.md, "NDRF training"). Larger captures (lego at 800x800) shade a random
    # 200x200 window a step, the paper's "local patches", at the same cost a step.
    "cpu": TrainConfig(iterations=5000, n_distill=200, patch=200, lr=1e-2, lr_final=1e-4,
                       extract="cpu", face_budget=60_000, checkpoint_every=500, log_every=25),
    # CI: the whole run, extraction included, in well under a minute on 2 cores.
    "tiny": TrainConfig(iterations=1500, n_distill=100, lr=1e-2, lr_final=1e-4,
                        extract="tiny", checkpoint_every=1500, log_every=25),
}


def configs(preset: str, iterations: int | None = None, train_config: TrainConfig | None = None,
            **options):
    """``(NDRFConfig, TrainConfig, mesh.ExtractConfig)`` of ``preset`` with the model options
    (``thresholds``, ``kernel_size``, ``distill``, ``outer_only``: the thresholds' first,
    outer, one alone) and an iteration count applied; ``train_config`` replaces the
    preset's training config."""
    unknown = sorted(set(options) - set(MODEL_OPTIONS))
    if unknown:
        raise ValueError(f"unknown NDRF options {unknown}; expected {sorted(MODEL_OPTIONS)}")
    if preset not in TRAIN_PRESETS:
        raise ValueError(f"unknown preset {preset!r}; presets: {sorted(TRAIN_PRESETS)}")
    cfg = ndrf_preset(preset, **{k: options[k] for k in ("thresholds", "kernel_size")
                                 if options.get(k) is not None})
    if options.get("outer_only"):
        cfg = replace(cfg, thresholds=cfg.thresholds[:1])
    tcfg = train_config or TRAIN_PRESETS[preset]
    if options.get("distill") is not None:
        tcfg = replace(tcfg, distill=bool(options["distill"]))
    if iterations is not None:
        tcfg = replace(tcfg, iterations=int(iterations))
    budget = {} if tcfg.face_budget is None else {"face_budget": tcfg.face_budget}
    return cfg, tcfg, extract_preset(tcfg.extract, **budget)


def model_spec(preset: str, **options) -> dict:
    """Everything but data, seed and teacher that determines a trained model (a cache key)."""
    cfg, tcfg, ecfg = configs(preset, **options)
    return {"model": cfg.to_dict(), "train": json.loads(json.dumps(asdict(tcfg))),
            "extract": asdict(ecfg)}


def learning_rate(step: int, tcfg: TrainConfig) -> float:
    """lr * (lr_final / lr) ** (step / iterations): exponential decay (§4.1)."""
    return tcfg.lr * (tcfg.lr_final / tcfg.lr) ** (step / max(1, tcfg.iterations))


# -- the torch shader (docs/ndrf.md; tested equal to shader_ref.shade_reference) ------------

def _teacher_info(teacher):
    """(loaded NGP-RT model, JSON-ready identity of the teacher file)."""
    from ..methods import load

    if hasattr(teacher, "method"):
        model, ident = teacher, {"path": None}
    else:
        path = Path(teacher).resolve()
        model = load(path)
        st = path.stat()
        ident = {"path": str(path), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns}
    if model.method != "ngprt":
        raise ValueError(f"teacher {ident['path']}: a teacher must be a baked NGP-RT model, "
                         f"this is {model.method!r}")
    return model, ident


def _meshes(out: Path, reuse: bool, teacher, cfg, ecfg, cameras, progress):
    """K (vertices, faces) from ``out/meshes`` (``reuse``) or freshly extracted there."""
    from .mesh import extract_duplex, write_meshes

    mesh_dir = out / "meshes"
    if not (reuse and (mesh_dir / "report.json").is_file()):
        meshes, report = extract_duplex(teacher, ecfg, thresholds=cfg.thresholds,
                                        cameras=cameras, progress=progress)
        empty = [k for k, m in enumerate(meshes) if len(m.faces) == 0]
        if empty:
            raise ValueError(f"NDRF extraction: meshes {empty} (thresholds "
                             f"{[cfg.thresholds[k] for k in empty]}) have no face left "
                             f"after culling; report: {report['meshes']}")
        write_meshes(meshes, report, mesh_dir)
    thresholds, meshes = load_meshes(mesh_dir)
    if thresholds != cfg.thresholds:
        raise ValueError(f"{mesh_dir}: meshes at thresholds {thresholds}, the config has "
                         f"{cfg.thresholds}")
    return meshes


def _config_json(ds, data_path, cfg, tcfg, ecfg, teacher_id, preset, seed, downscale) -> dict:
    conf = {"method": "ndrf", "model": cfg.to_dict(), "train": asdict(tcfg),
            "extract": asdict(ecfg), "data": data_path, "downscale": downscale,
            "teacher": teacher_id, "preset": preset, "seed": int(seed),
            "background": [float(v) for v in np.asarray(ds.background).reshape(3)]}
    return json.loads(json.dumps(conf))


def _bounded_train_set(data, downscale: int):
    """The training split of ``data`` (folder or loaded Dataset), refused before its pixels
    are read when the scene is unbounded: NDRF's meshes come from a bounded grid."""
    from ..data import read_views, scan_dataset

    if hasattr(data, "images"):
        scene, where, views = data.scene, data.path, None
    else:
        views = scan_dataset(data, "train", downscale)
        scene, where = views.scene, f"{views.root} ({views.format})"
    if scene != "bounded":
        raise ValueError(f"{where}: an {scene} scene; NDRF is bounded-only (its duplex meshes "
                         "are extracted inside [-1, 1]^3): train NGP-RT on it instead")
    return data if views is None else read_views(views)


def train(data, out, teacher, preset: str = "cpu", iterations: int | None = None,
          seed: int = 0, device=None, progress: bool = True,
          train_config: TrainConfig | None = None, downscale: int = 1, on_step=None,
          view_budget=None, **options) -> Path:
    """Train an NDRF model on the dataset ``data`` (folder or loaded train Dataset) from the
    baked NGP-RT ``teacher`` (path or loaded model) into the run folder ``out``.

    Args:
        preset: "tiny", "cpu" or "paper" (:data:`TRAIN_PRESETS`, extraction preset).
        iterations: overrides the preset's count.
        train_config: replaces the preset's :class:`TrainConfig`.
        device: torch device; default cuda when present.
        downscale: the dataset's ``images_{downscale}/`` or its images shrunk that many
            times; recorded in ``config.json``.
        on_step: called as ``on_step(step, bake)`` after every iteration ``step`` (0-based,
            as ``log.jsonl``; its log line and checkpoint written where due); ``bake()``
            returns the training state as an in-memory :class:`NDRFModel`
            (:func:`bake_shader`).
        view_budget: bytes (or text as "12G") the views' hits and targets may hold in
            memory, the training and distillation views together (on a CUDA device, GPU
            memory); views beyond it are disk-backed: memory-mapped files made in ``out``
            and unlinked at once, their space freed when the training ends (or dies).
            Default: ``$CLRENDER_NDRF_VIEW_BUDGET``, else half the memory available
            (:func:`clrender.ndrf.view_memory.view_budget`). Not part of the run's config:
            it changes neither the results nor whether a run resumes.
        **options: :data:`MODEL_OPTIONS` (thresholds, kernel_size, distill, outer_only).
    An existing run with the same config.json is resumed (meshes, distillation views and
    checkpoint reused). Returns the run folder.
    """
    dev = pick_device(device)
    torch.manual_seed(seed)
    ds = _bounded_train_set(data, downscale)
    data_path = None if hasattr(data, "images") else str(Path(data).resolve())
    cfg, tcfg, ecfg = configs(preset, iterations, train_config, **options)
    if tcfg.distill:
        select_device()       # the teacher renders on it: checked before the run folder is made
    teacher_model, teacher_id = _teacher_info(teacher)
    run = RunFolder(out, _config_json(ds, data_path, cfg, tcfg, ecfg, teacher_id, preset, seed,
                                       downscale))
    if not run.resumable:
        run.forget(run.dir / "meshes" / "report.json")
    meshes = _meshes(run.dir, run.resumable, teacher_model, cfg, ecfg, ds.cameras, progress)
    run.write_config()

    bg = np.asarray(ds.background, np.float32).reshape(3)
    shader = NDRFShader.from_model(initial_model(cfg, meshes, seed, bg)).to(dev)
    budget = resolve_view_budget(dev, view_budget)
    train_cameras = ds.cameras
    views = {"train": ViewSet.build(meshes, train_cameras, ds.images, dev, budget, run.dir)}
    del ds      # read here from a folder: its images are not held beside disk-backed views
    if tcfg.distill and tcfg.n_distill > 0:
        from .distill import cached_distillation

        cams, images = cached_distillation(run.dir, teacher_model, train_cameras,
                                           tcfg.n_distill, seed, bg,
                                           json.dumps(teacher_id, sort_keys=True),
                                           progress=progress)
        views["distill"] = ViewSet.build(meshes, cams, images, dev,
                                         max(0, budget - views["train"].resident_bytes),
                                         run.dir)
        del images  # disk-backed distillation views: the targets live in their file only
    opt = torch.optim.Adam(shader.parameters(), lr=tcfg.lr, betas=tuple(tcfg.betas),
                           eps=tcfg.eps)
    state = run.resume(shader, opt, dev)
    start = 0 if state is None else int(state["step"])
    hook = None if on_step is None else \
        (lambda step: on_step(step, lambda: bake_shader(shader, bg)))
    _loop(shader, opt, views, torch.as_tensor(bg, device=dev), start, tcfg, seed, run, progress,
          hook)
    return run.dir


def _phase(step: int, tcfg: TrainConfig, views: dict) -> str:
    if "distill" in views and step < int(round(tcfg.distill_fraction * tcfg.iterations)):
        return "distill"
    return "train"


def _loop(shader, opt, views, bg, start, tcfg, seed, run, progress, on_step=None):
    for step in run.steps(start, tcfg.iterations, tcfg.log_every, tcfg.checkpoint_every,
                          "ndrf", progress):
        # One generator per step: the same views and patches whether resumed or not.
        rng = np.random.default_rng([seed, step])
        phase = _phase(step, tcfg, views)
        vs = views[phase]
        i = int(rng.integers(len(vs)))
        ph, pw = (vs.height, vs.width) if tcfg.patch <= 0 else \
            (min(tcfg.patch, vs.height), min(tcfg.patch, vs.width))
        y0, x0 = int(rng.integers(vs.height - ph + 1)), int(rng.integers(vs.width - pw + 1))
        lr = learning_rate(step, tcfg)
        set_lr(opt, lr)
        if (ph, pw) == (vs.height, vs.width):
            rgb = vs.frame(shader, i, bg)
        else:
            rgb = shader(*vs.window(i, y0, x0, ph, pw, shader.config.kernel_size - 1),
                         background=bg)
        target = vs.target(i, y0, x0, ph, pw)
        loss = F.mse_loss(rgb, target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        finite = finite_step(loss, shader.parameters())
        if finite:
            opt.step()
        run.count_step(step, finite, lambda: {"model": shader.state_dict(), "phase": phase,
                                              "view": i, "window": [y0, x0, ph, pw]})
        mse = float(loss.detach())
        psnr = mse_psnr(mse)
        run.bar.set_postfix(phase=phase, psnr=f"{psnr:.2f}")
        run.after_step(step, lambda: {"phase": phase, "loss": mse, "psnr": psnr, "lr": lr,
                                      "view": i},
                       lambda: {"model": shader.state_dict(), "optimizer": opt.state_dict()})
        if on_step is not None:
            on_step(step)


def load_run(run_dir, device=None) -> tuple[NDRFShader, dict]:
    """The trained shader of a run folder (on ``device``, default cpu) and its config.json."""
    run_dir = Path(run_dir)
    conf_path = run_dir / "config.json"
    conf = json.loads(conf_path.read_text())
    if conf.get("method") != "ndrf":
        raise ValueError(f"{conf_path}: method is {conf.get('method')!r}, expected 'ndrf'")
    cfg = NDRFConfig.from_dict(conf["model"], where=str(conf_path))
    _, meshes = load_meshes(run_dir / "meshes")
    bg = np.asarray(conf["background"], np.float32)
    shader = NDRFShader.from_model(initial_model(cfg, meshes, 0, bg))
    state = torch.load(run_dir / "checkpoint.pt", map_location="cpu", weights_only=True)
    shader.load_state_dict(state["model"])
    return shader.to(pick_device(device or "cpu")).eval(), conf


def bake_run(run_dir, out_path) -> Path:
    """Bake the checkpoint of ``run_dir`` into an NDRF file at ``out_path`` (atomically;
    conv weights transposed to [dy, dx, in, out] as docs/ndrf.md). Returns the path."""
    shader, conf = load_run(run_dir)
    model = bake_shader(shader, conf["background"])
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    trained_on = {"data": conf.get("data"), "downscale": conf.get("downscale", 1)}
    return save_baked(model, out_path, trained_on=trained_on)


def bake_shader(shader: NDRFShader, background) -> NDRFModel:
    """The in-memory baked model of a shader (training's or a run's), validated."""
    model = NDRFModel(shader.config, shader.to_arrays(background))
    validate(model, "in-memory NDRF model")
    return model
