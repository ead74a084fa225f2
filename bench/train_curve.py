"""Time-to-quality curve: test PSNR of a method's deployed model against training minutes.

    python -m bench.run train-curve                        # NGP-RT, `cpu` and `tiny` presets
    python -m bench.run train-curve --method ndrf --preset tiny --out results/

Trains the baseline row of the method's ``CURVE_TABLE`` (NGP-RT: Table 2's separate-v,
L = 2; NDRF: the full model of its Table 3) from scratch into a fresh run folder
``CACHE/curves/<key>/run`` and, at about 12 steps of the run (the first and the last
included), bakes the in-memory training state (the plug-in's step hook) and renders every
test view with the OpenCL renderer, as the tables do. The x axis counts training time only
(data loading, mesh extraction and distillation views included, evaluations excluded); each
evaluation's time is recorded beside it. A method with a teacher (NDRF) has it trained (or
taken from the model cache) first, and the teacher's test PSNR is drawn as a horizontal
line. Writes ``OUT/train-curve.{csv,png}``.
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
from bench.fingerprint import code_fingerprint
from clrender import methods
from clrender.atomic import write_atomic

KEY = "train-curve"
TITLE = "time-to-quality: test PSNR vs training minutes (the baseline row of a method's table)"
PRESETS = ("cpu", "tiny")           # default --preset
N_POINTS = 12
COLUMNS = ("method", "preset", "seed", "step", "train_seconds", "eval_seconds", "test_psnr",
           "test_ssim", "train_psnr", "teacher_test_psnr")


def baseline_row(method: str):
    """The curve's row: the baseline row of the method's ``CURVE_TABLE`` (its first row
    where it has no baseline)."""
    table_key = methods.get(method).CURVE_TABLE
    if table_key is None:
        raise ValueError(f"method {method!r} declares no CURVE_TABLE for {KEY}")
    table = ablation.load_table(table_key)
    base = table.rows[0].baseline or table.rows[0].name
    return next(r for r in table.rows if r.name == base)


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
    """The ``on_step(step, bake)`` hook of a method's training: at the chosen steps, bake
    the training state in memory and evaluate it on the test views; the training clock,
    started when the hook is made (just before training), pauses meanwhile.

    Args:
        method: the method trained (stamped on each in-memory model, as a loaded one).
        steps: iterations to evaluate after (see :func:`eval_steps`).
        test_set: the :class:`clrender.data.Dataset` test split.
        render_options: the row's render options (``use_G``).
        device: OpenCL device spec.
    Attributes:
        points: one dict per evaluation: step, train_seconds (training wall time so far),
            eval_seconds (bake + render), test_psnr, test_ssim (means over test views).
    """

    def __init__(self, method: str, steps, test_set, render_options: dict, device=None):
        self.method, self.steps, self.test_set = method, set(steps), test_set
        self.render_options, self.device = dict(render_options), device
        self.points, self.train_seconds, self._resumed = [], 0.0, time.perf_counter()

    def __call__(self, step, bake) -> None:
        if step not in self.steps:
            return
        from clrender.evaluate import evaluate

        now = time.perf_counter()
        self.train_seconds += now - self._resumed
        model = methods.stamp(bake(), self.method, f"step {step}'s in-memory model")
        result = evaluate(model, self.test_set, device=self.device, **self.render_options)
        self._resumed = time.perf_counter()
        self.points.append({"step": step, "train_seconds": self.train_seconds,
                            "eval_seconds": self._resumed - now,
                            "test_psnr": result["mean"]["psnr"],
                            "test_ssim": result["mean"]["ssim"]})
        tqdm.write(f"step {step}: {self.train_seconds / 60:.2f} min, test PSNR "
                   f"{result['mean']['psnr']:.2f} dB (evaluated in {self._resumed - now:.1f} s)")


def measure_curve(root: Path, data: Path, fingerprint: str, preset: str, seed: int = 0,
                  device=None, torch_device=None, iterations: int | None = None,
                  n_points: int = N_POINTS, progress: bool = True,
                  method: str | None = None) -> list[dict]:
    """Train the baseline row's model of ``method`` from scratch with ``preset`` and
    evaluate it along the way.

    Args:
        root: the cache folder; the run goes to ``root/curves/<key>/run`` (emptied first);
            a teacher is taken from (or trained into) the model cache.
        data, fingerprint: the dataset folder and :func:`bench.cache.data_fingerprint`.
        iterations: override of the preset's iteration count (quick runs, tests).
    Returns:
        one dict per evaluation, :data:`COLUMNS`; ``train_psnr`` is the training batch's
        PSNR logged at that step; ``teacher_test_psnr`` the teacher's (None without one).
    """
    from clrender.data import load_dataset
    from clrender.evaluate import evaluate
    from clrender.runs import read_log

    method = method or methods.default()
    plugin, row = methods.get(method), baseline_row(method)
    options = dict(row.model)
    teacher_option = plugin.TEACHER and plugin.TEACHER.option
    n_iter, log_every = plugin.train_steps(preset, iterations)
    steps = eval_steps(n_iter, log_every, n_points)
    spec = {"method": method, **plugin.model_spec(preset, **{k: v for k, v in options.items()
                                                             if k != teacher_option}),
            "code": code_fingerprint(method), "iterations": n_iter, "data": fingerprint,
            "seed": seed, "steps": steps}
    test_set, teacher_psnr = load_dataset(data, split="test"), None
    if teacher_option in options:
        teacher = cache.ensure_model(root, data, fingerprint, preset, plugin.TEACHER.method,
                                     options[teacher_option], seed=seed,
                                     torch_device=torch_device)
        teacher_psnr = evaluate(teacher.baked, test_set, device=device)["mean"]["psnr"]
        options[teacher_option], spec["teacher"] = str(teacher.baked), teacher.key
    key = hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]
    run_dir = Path(root) / "curves" / key / "run"
    shutil.rmtree(run_dir, ignore_errors=True)
    hook = Evaluator(method, steps, test_set, row.render, device)
    plugin.train(str(data), run_dir, preset, seed=seed, iterations=n_iter,
                 torch_device=torch_device, progress=progress, on_step=hook, **options)
    logged = {rec["step"]: rec["psnr"] for rec in read_log(run_dir)}
    return [{"method": method, "preset": preset, "seed": seed, **p,
             "train_psnr": logged.get(p["step"]), "teacher_test_psnr": teacher_psnr}
            for p in hook.points]


def _plot(points: list[dict], meta: dict) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for preset in dict.fromkeys(p["preset"] for p in points):
        pts = [p for p in points if p["preset"] == preset]
        line, = ax.plot([p["train_seconds"] / 60 for p in pts], [p["test_psnr"] for p in pts],
                        marker="o", label=f"{preset} (seed {pts[0]['seed']})")
        if pts[0].get("teacher_test_psnr") is not None:
            ax.axhline(pts[0]["teacher_test_psnr"], color=line.get_color(), linestyle="--",
                       label=f"{preset}: teacher")
    ax.set_xlabel("training wall-clock (min, evaluations excluded)")
    ax.set_ylabel("test PSNR (dB), baked model, OpenCL")
    row = f": {meta['row']}" if meta.get("row") else ""
    ax.set_title(f"{points[0]['method']}{row}, {meta['scene']}, git "
                 f"{meta['git_revision']}, {meta['date'][:10]}\n{meta['device']}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def _cell(value, fmt: str = "{:.4f}") -> str:
    return "" if value is None else fmt.format(value)


def write_curve(out_dir: Path, points: list[dict], meta: dict) -> str:
    """Write ``train-curve.csv`` and ``train-curve.png`` (atomically); returns a short
    text table of the points. ``meta``: scene, git_revision, date, device (and the curve's
    ``row`` name, for the plot's title)."""
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(COLUMNS)
    for p in points:
        writer.writerow([p["method"], p["preset"], p["seed"], p["step"],
                         f"{p['train_seconds']:.2f}", f"{p['eval_seconds']:.2f}",
                         f"{p['test_psnr']:.4f}", f"{p['test_ssim']:.4f}",
                         _cell(p["train_psnr"]), _cell(p["teacher_test_psnr"])])
    write_atomic(Path(out_dir) / f"{KEY}.csv", buf.getvalue())
    write_atomic(Path(out_dir) / f"{KEY}.png", _plot(points, meta))
    lines = [f"{'preset':8s} {'step':>6s} {'train min':>9s} {'eval s':>7s} {'test PSNR':>9s} "
             f"{'SSIM':>6s} {'train PSNR':>10s} {'teacher':>8s}"]
    lines += [f"{p['preset']:8s} {p['step']:6d} {p['train_seconds'] / 60:9.2f} "
              f"{p['eval_seconds']:7.1f} {p['test_psnr']:9.2f} {p['test_ssim']:6.3f} "
              f"{_cell(p['train_psnr'], '{:10.2f}') or '       n/a'} "
              f"{_cell(p['teacher_test_psnr'], '{:8.2f}') or '     n/a'}" for p in points]
    return "\n".join(lines)


def run(args, meta: dict) -> str:
    """``python -m bench.run train-curve``: every ``--preset``'s curve (default
    :data:`PRESETS`) of ``--method`` into ``args.out``, the files rewritten after each
    preset; returns the text table."""
    row = baseline_row(args.method)
    scene = args.scene or ablation.load_table(methods.get(args.method).CURVE_TABLE).scene
    data = cache.resolve_scene(scene, args.cache)
    fingerprint = cache.data_fingerprint(data)
    meta = {**meta, "scene": scene, "method": args.method, "row": row.name}
    points, text = [], ""
    for preset in args.presets or PRESETS:
        points += measure_curve(args.cache, data, fingerprint, preset, seed=args.seed,
                                device=args.device, torch_device=args.torch_device,
                                method=args.method)
        text = write_curve(args.out, points, meta)
    return text
