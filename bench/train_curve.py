"""Time-to-quality curve: test PSNR of the deployed NGP-RT model against training minutes.

    python -m bench.run train-curve                        # the `cpu` and `tiny` presets
    python -m bench.run train-curve --preset tiny --out results/

Trains the Table 2 baseline row's model (separate-v, L = 2) from scratch into a fresh run
folder ``CACHE/curves/<key>/run`` and, at about 12 steps of the run (the first and the last
included), bakes the in-memory training state and renders every test view with the OpenCL
renderer, as the tables do. The x axis counts training time only (data loading included,
evaluations excluded); each evaluation's time is recorded beside it. Writes
``OUT/train-curve.{csv,png}``.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import shutil
import time
from pathlib import Path

from tqdm import tqdm

from bench import ablation, cache
from clrender.atomic import write_atomic

KEY = "train-curve"
TITLE = "time-to-quality: test PSNR vs training minutes (Table 2's L=2 row)"
PRESETS = ("cpu", "tiny")           # default --preset
N_POINTS = 12
COLUMNS = ("preset", "seed", "step", "train_seconds", "eval_seconds", "test_psnr", "test_ssim",
           "train_psnr")


def baseline_row():
    """Table 2's baseline row (NGP-RT, separate-v, L = 2, rendered with G): the curve's model."""
    table = ablation.load_table("table2")
    return next(r for r in table.rows if r.name == table.rows[0].baseline)


def eval_steps(iterations: int, log_every: int, n_points: int = N_POINTS) -> list[int]:
    """Iterations (0-based, as ``log.jsonl``) after which the model is evaluated.

    Quadratically spaced (denser early, where PSNR moves fastest), snapped to the log's
    steps so each has a training PSNR, first (0) and last (``iterations - 1``) included;
    fewer than ``n_points`` when snapping merges some.
    """
    last = iterations - 1
    raw = [last * (i / (n_points - 1)) ** 2 for i in range(n_points)]
    return sorted({min(last, log_every * round(s / log_every)) for s in raw} | {0, last})


class Evaluator:
    """The ``on_step`` hook of NGP-RT training: at the chosen steps, bake the training
    state and evaluate it on the test views; the training clock, started when the hook is
    made (just before training), pauses meanwhile.

    Args:
        steps: iterations to evaluate after (see :func:`eval_steps`).
        train_set, test_set: :class:`clrender.data.Dataset` splits (culling; metrics).
        render_options: the row's render options (``use_G``).
        device: OpenCL device spec.
    Attributes:
        points: one dict per evaluation: step, train_seconds (training wall time so far),
            eval_seconds (bake + render), test_psnr, test_ssim (means over test views).
    """

    def __init__(self, steps, train_set, test_set, render_options: dict, device=None):
        self.steps, self.train_set, self.test_set = set(steps), train_set, test_set
        self.render_options, self.device = dict(render_options), device
        self.points, self.train_seconds, self._resumed = [], 0.0, time.perf_counter()

    def __call__(self, step, model, occ, gamma) -> None:
        if step not in self.steps:
            return
        from clrender.evaluate import evaluate
        from clrender.ngprt.bake import bake_state
        from clrender.ngprt.baked import validate

        now = time.perf_counter()
        self.train_seconds += now - self._resumed
        baked = bake_state(model, occ.binary, gamma, self.train_set)
        validate(baked, f"step {step}")
        result = evaluate(baked, self.test_set, device=self.device, **self.render_options)
        self._resumed = time.perf_counter()
        self.points.append({"step": step, "train_seconds": self.train_seconds,
                            "eval_seconds": self._resumed - now,
                            "test_psnr": result["mean"]["psnr"],
                            "test_ssim": result["mean"]["ssim"]})
        tqdm.write(f"step {step}: {self.train_seconds / 60:.2f} min, test PSNR "
                   f"{result['mean']['psnr']:.2f} dB (evaluated in {self._resumed - now:.1f} s)")


def measure_curve(root: Path, data: Path, fingerprint: str, preset: str, seed: int = 0,
                  device=None, torch_device=None, iterations: int | None = None,
                  n_points: int = N_POINTS, progress: bool = True) -> list[dict]:
    """Train the baseline row's model from scratch with ``preset`` and evaluate it along
    the way.

    Args:
        root: the cache folder; the run goes to ``root/curves/<key>/run`` (emptied first).
        data, fingerprint: the dataset folder and :func:`bench.cache.data_fingerprint`.
        iterations: override of the preset's iteration count (quick runs, tests).
    Returns:
        one dict per evaluation, :data:`COLUMNS`; ``train_psnr`` is the training batch's
        PSNR logged at that step.
    """
    from dataclasses import replace

    from clrender.data import load_dataset
    from clrender.ngprt.method import model_spec
    from clrender.ngprt.train import TRAIN_PRESETS, train

    row = baseline_row()
    tcfg = TRAIN_PRESETS[preset]
    if iterations is not None:
        tcfg = replace(tcfg, iterations=int(iterations))
    steps = eval_steps(tcfg.iterations, tcfg.log_every, n_points)
    spec = {**model_spec(preset, **row.model), "iterations": tcfg.iterations, "data": fingerprint,
            "seed": seed, "steps": steps}
    key = hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]
    run_dir = Path(root) / "curves" / key / "run"
    shutil.rmtree(run_dir, ignore_errors=True)
    hook = Evaluator(steps, load_dataset(data, split="train"), load_dataset(data, split="test"),
                     row.render, device)
    train(str(data), run_dir, preset=preset, iterations=tcfg.iterations, seed=seed,
          device=torch_device, progress=progress, on_step=hook, **row.model)
    logged = {rec["step"]: rec["psnr"] for rec in map(json.loads, (run_dir / "log.jsonl")
                                                      .read_text().splitlines())}
    return [{"preset": preset, "seed": seed, **p, "train_psnr": logged.get(p["step"])}
            for p in hook.points]


def _plot(points: list[dict], meta: dict) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for preset in dict.fromkeys(p["preset"] for p in points):
        pts = [p for p in points if p["preset"] == preset]
        ax.plot([p["train_seconds"] / 60 for p in pts], [p["test_psnr"] for p in pts],
                marker="o", label=f"{preset} (seed {pts[0]['seed']})")
    ax.set_xlabel("training wall-clock (min, evaluations excluded)")
    ax.set_ylabel("test PSNR (dB), baked model, OpenCL")
    ax.set_title(f"NGP-RT L=2 separate-v, {meta['scene']}, git {meta['git_revision']}, "
                 f"{meta['date'][:10]}\n{meta['device']}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def write_curve(out_dir: Path, points: list[dict], meta: dict) -> str:
    """Write ``train-curve.csv`` and ``train-curve.png`` (atomically); returns a short
    text table of the points."""
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(COLUMNS)
    for p in points:
        writer.writerow([p["preset"], p["seed"], p["step"], f"{p['train_seconds']:.2f}",
                         f"{p['eval_seconds']:.2f}", f"{p['test_psnr']:.4f}",
                         f"{p['test_ssim']:.4f}",
                         "" if p["train_psnr"] is None else f"{p['train_psnr']:.4f}"])
    write_atomic(Path(out_dir) / f"{KEY}.csv", buf.getvalue())
    write_atomic(Path(out_dir) / f"{KEY}.png", _plot(points, meta))
    lines = [f"{'preset':8s} {'step':>6s} {'train min':>9s} {'eval s':>7s} {'test PSNR':>9s} "
             f"{'SSIM':>6s} {'train PSNR':>10s}"]
    lines += [f"{p['preset']:8s} {p['step']:6d} {p['train_seconds'] / 60:9.2f} "
              f"{p['eval_seconds']:7.1f} {p['test_psnr']:9.2f} {p['test_ssim']:6.3f} "
              + ("       n/a" if p["train_psnr"] is None else f"{p['train_psnr']:10.2f}")
              for p in points]
    return "\n".join(lines)


def run(args, meta: dict) -> str:
    """``python -m bench.run train-curve``: every ``--preset``'s curve (default
    :data:`PRESETS`) into ``args.out``, the files rewritten after each preset; returns the
    text table."""
    scene = args.scene or ablation.load_table("table2").scene
    data = cache.resolve_scene(scene, args.cache)
    fingerprint = cache.data_fingerprint(data)
    meta = {**meta, "scene": scene}
    points, text = [], ""
    for preset in args.presets or PRESETS:
        points += measure_curve(args.cache, data, fingerprint, preset, seed=args.seed,
                                device=args.device, torch_device=args.torch_device)
        text = write_curve(args.out, points, meta)
    return text
