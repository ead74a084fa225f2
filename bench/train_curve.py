"""Time-to-quality curve: test PSNR of a method's deployed model against training minutes.

    python -m bench.train_curve                        # NGP-RT, `cpu` and `tiny` presets
    python -m bench.train_curve --method ndrf --preset tiny --out results/
    python -m bench.train_curve --preset cpu --option engine=torch,fast --seeds 3
    python -m bench.train_curve --preset cpu-long --option L=4 --option variant=separate-v,sum
    python -m bench.train_curve --preset cpu --scene data/lego --downscale 4 --test-stride 2

Trains the baseline row of the method's ``curve_table`` (NGP-RT: Table 2's separate-v,
L = 2; NDRF: the full model of its Table 3) from scratch into a fresh run folder
``CACHE/curves/<key>/run`` and, at about 12 steps of the run (the first and the last
included), bakes the in-memory training state (the plug-in's step hook) and renders every
test view with the OpenCL renderer, as the tables do. The x axis counts training time only
(data loading, mesh extraction and distillation views included, evaluations excluded); each
evaluation's time is recorded beside it. A method with a teacher (NDRF) has it trained (or
taken from the model cache) first, and the teacher's test PSNR is drawn as a horizontal
line. ``--option NAME=V1,V2,..`` draws a curve for each value of one of the method's
training options (e.g. NGP-RT's ``engine``), each trained for the same steps and evaluated
after the same ones; more ``--option NAME=V`` of one value each set an option for every
curve (``--option L=4 --option variant=separate-v,sum``: Table 3's comparison along a
run); with ``--seeds N`` >= 2 each value after the first is compared with
the first at every evaluated step, paired by seed: the mean test-PSNR difference and its
95% t interval (:mod:`bench.tables.seeds`). ``--downscale`` reads a dataset folder as the tables
do, ``--test-stride K`` scores every K-th test view (the first included), ``--points N``
evaluates after about N steps instead of :data:`N_POINTS` (the first evaluations, of a
model whose occupancy grid has not pruned empty space yet, are the slowest);
``--iterations N`` trains N steps instead of the preset's (curves of equal minutes for
presets or engines whose steps take different times); ``--x-axis steps`` plots against
steps (a run whose minutes are no timing: paused, or resumed on other threads). Each
evaluation scores PSNR, SSIM and LPIPS-Alex and rewrites ``OUT/train-curve.{csv,png}``, so
a long run shows its curve so far;
``--resume`` continues a run cut short from its last checkpoint (the points measured before
it kept, in the run folder's ``curve.jsonl``).
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import shutil
import sys
import time
from pathlib import Path

from tqdm import tqdm

from bench import options
from bench.modelcache import cache
from bench.modelcache.fingerprint import code_fingerprint
from bench.tables import ablation
from clrender import methods
from clrender.cli import USER_ERRORS, one_line_error
from clrender.cliopts import whole_number
from clrender.atomic import write_atomic

KEY = "train-curve"
TITLE = "time-to-quality: test PSNR vs training minutes (the baseline row of a method's table)"
PRESETS = ("cpu", "tiny")           # default --preset
N_POINTS = 12
COLUMNS = ("method", "preset", "option", "seed", "step", "train_seconds", "eval_seconds",
           "test_psnr", "test_ssim", "test_lpips", "train_psnr", "teacher_test_psnr")
POINTS_FILE = "curve.jsonl"         # a run folder's evaluations so far, one JSON line each


def baseline_row(method: str):
    """The curve's row: the baseline row of the method's ``curve_table`` (its first row
    where it has no baseline)."""
    table_key = methods.bench_of(method).curve_table
    if table_key is None:
        raise ValueError(f"method {method!r} declares no curve_table for {KEY}")
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
    started when the hook is made (just before training), pauses meanwhile. Each point is
    appended to ``points_file`` as it is measured, so a run cut short keeps its curve.

    Args:
        method: the method trained (stamped on each in-memory model, as a loaded one).
        steps: iterations to evaluate after (see :func:`eval_steps`).
        test_set: the :class:`clrender.data.Dataset` test split.
        render_options: the row's render options (``use_G``).
        device: OpenCL device spec.
        points_file: a JSON-lines file the points are appended to (None: kept in memory).
        points, train_seconds: the points and training seconds of an earlier part of the
            run (a resumed one).
        on_point: called with :attr:`points` after each evaluation.
    Attributes:
        points: one dict per evaluation: step, train_seconds (training wall time so far),
            eval_seconds (bake + render), test_psnr, test_ssim, test_lpips (means over test
            views; LPIPS None where it cannot be scored).
    """

    def __init__(self, method: str, steps, test_set, render_options: dict, device=None,
                 points_file=None, points=(), train_seconds: float = 0.0, on_point=None):
        self.method, self.steps, self.test_set = method, set(steps), test_set
        self.render_options, self.device = dict(render_options), device
        self.points_file, self.points = points_file, list(points)
        self.train_seconds, self.on_point = train_seconds, on_point
        self._resumed = time.perf_counter()

    def __call__(self, step, bake) -> None:
        if step not in self.steps:
            return
        from clrender.evaluate import evaluate

        now = time.perf_counter()
        self.train_seconds += now - self._resumed
        model = methods.stamp(bake(), self.method, f"step {step}'s in-memory model")
        result = evaluate(model, self.test_set, device=self.device, lpips=True,
                          **self.render_options)
        self._resumed = time.perf_counter()
        point = {"step": step, "train_seconds": self.train_seconds,
                 "eval_seconds": self._resumed - now, "test_psnr": result["mean"]["psnr"],
                 "test_ssim": result["mean"]["ssim"], "test_lpips": result["mean"]["lpips"]}
        self.points.append(point)
        if self.points_file is not None:
            with open(self.points_file, "a") as f:
                f.write(json.dumps(point) + "\n")
        if self.on_point is not None:
            self.on_point(self.points)
        tqdm.write(f"step {step}: {self.train_seconds / 60:.2f} min, test PSNR "
                   f"{result['mean']['psnr']:.2f} dB (evaluated in {self._resumed - now:.1f} s)")


def resumed_points(run_dir: Path) -> tuple[list[dict], float]:
    """The points of an interrupted curve run that its checkpoint keeps, and the training
    seconds to resume the clock at.

    Points measured after the checkpoint's step are dropped (they are measured again).
    The steps trained between the last point kept and the checkpoint were not timed: they
    are counted at the mean step time of the points kept. Returns ``([], 0.0)`` where the
    run has no checkpoint or no point.
    """
    import torch

    ckpt, points_path = run_dir / "checkpoint.pt", run_dir / POINTS_FILE
    if not (ckpt.is_file() and points_path.is_file()):
        return [], 0.0
    start = int(torch.load(ckpt, map_location="cpu", weights_only=True)["step"])
    points = [json.loads(line) for line in points_path.read_text().splitlines() if line]
    points = [p for p in points if p["step"] < start]
    if not points:
        return [], 0.0
    last = points[-1]
    per_step = last["train_seconds"] / (last["step"] + 1)
    return points, last["train_seconds"] + per_step * (start - 1 - last["step"])


def option_values(method: str, text: str) -> tuple[str, list]:
    """``NAME=V1,V2,..`` (``--option``) as the name of one of ``method``'s training options
    and its values, each converted to the option's type and checked; ValueError otherwise."""
    declared = methods.get(method).train_options
    name, sep, values = text.partition("=")
    opt = declared.get(name)
    if not sep or opt is None or not values or opt.nargs:
        raise ValueError(f"--option {text!r}: expected NAME=V1[,V2..] with NAME one of "
                         f"{method}'s training options of one value: "
                         f"{', '.join(k for k, o in declared.items() if not o.nargs)}")
    convert = (lambda v: v.lower() in ("1", "true", "yes")) if opt.type is bool else opt.type
    out = []
    for v in values.split(","):
        try:
            out.append(convert(v))
        except ValueError:
            raise ValueError(f"--option {text!r}: {v!r} is not a {opt.type.__name__}") from None
        opt.check(name, out[-1])
    return name, out


def curve_options(method: str, texts) -> list[dict | None]:
    """The training options of each curve from the ``--option`` texts (``NAME=V1,V2,..``,
    :func:`option_values`): an option of one value holds for every curve, the one option
    of several values (at most one) gives a curve per value; ``[None]`` without options.
    ValueError on a repeated name or on two options of several values."""
    if not texts:
        return [None]
    fixed, varied = {}, None
    for text in texts:
        name, values = option_values(method, text)
        if name in fixed or (varied and name == varied[0]):
            raise ValueError(f"--option {name} is given twice")
        if len(values) == 1:
            fixed[name] = values[0]
        elif varied is None:
            varied = (name, values)
        else:
            raise ValueError(f"--option {text!r}: only one option may take several values "
                             f"({varied[0]} does)")
    if varied is None:
        return [fixed]
    return [{**fixed, varied[0]: v} for v in varied[1]]


def test_views(data: Path, downscale: int = 1, stride: int = 1):
    """The test split of ``data`` (:func:`clrender.data.load_dataset`), every ``stride``-th
    view from the first."""
    from dataclasses import replace

    from clrender.data import load_dataset

    if stride < 1:
        raise ValueError(f"--test-stride must be >= 1, got {stride}")
    ds = load_dataset(data, split="test", downscale=downscale)
    if stride == 1:
        return ds
    keep = list(range(0, len(ds.cameras), stride))
    return replace(ds, images=ds.images[keep], cameras=[ds.cameras[i] for i in keep],
                   alpha=None if ds.alpha is None else ds.alpha[keep])


def measure_curve(root: Path, data: Path, fingerprint: str, preset: str, seed: int = 0,
                  device=None, torch_device=None, iterations: int | None = None,
                  n_points: int = N_POINTS, progress: bool = True,
                  method: str | None = None, option: dict | None = None,
                  downscale: int = 1, test_stride: int = 1, resume: bool = False,
                  on_point=None) -> list[dict]:
    """Train the baseline row's model of ``method`` from scratch with ``preset`` and
    evaluate it along the way.

    Args:
        root: the cache folder; the run goes to ``root/curves/<key>/run`` (emptied first);
            a teacher is taken from (or trained into) the model cache.
        data, fingerprint: the dataset folder and :func:`bench.modelcache.cache.data_fingerprint`
            (of ``downscale``).
        iterations: override of the preset's iteration count (quick runs, tests).
        option: training options set over the row's (``{"engine": "fast"}``).
        downscale, test_stride: the dataset's scale and the test views' stride
            (:func:`test_views`).
        resume: continue the run folder's training from its checkpoint, keeping the
            points measured before it (:func:`resumed_points`), instead of starting afresh.
        on_point: called with this curve's points so far after each evaluation.
    Returns:
        one dict per evaluation, :data:`COLUMNS`; ``train_psnr`` is the training batch's
        PSNR logged at that step; ``teacher_test_psnr`` the teacher's (None without one);
        ``option`` the ``option`` given, as ``name=value``.
    """
    from clrender.evaluate import evaluate
    from clrender.runs import read_log

    method = method or methods.default()
    plugin, bench, row = methods.get(method), methods.bench_of(method), baseline_row(method)
    options = {**row.model, **(option or {})}
    teacher_option = bench.teacher and bench.teacher.option
    n_iter, log_every = bench.train_steps(preset, iterations)
    steps = eval_steps(n_iter, log_every, n_points)
    spec = {"method": method, **bench.model_spec(preset, **{k: v for k, v in options.items()
                                                            if k != teacher_option}),
            "code": code_fingerprint(method), "iterations": n_iter, "data": fingerprint,
            "seed": seed, "steps": steps, "test_stride": test_stride}
    test_set, teacher_psnr = test_views(data, downscale, test_stride), None
    if teacher_option in options:
        teacher = cache.ensure_model(root, data, fingerprint, preset, bench.teacher.method,
                                     options[teacher_option], seed=seed,
                                     torch_device=torch_device, downscale=downscale)
        teacher_psnr = evaluate(teacher.baked, test_set, device=device)["mean"]["psnr"]
        options[teacher_option], spec["teacher"] = str(teacher.baked), teacher.key
    key = hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]
    run_dir = Path(root) / "curves" / key / "run"
    earlier, seconds = resumed_points(run_dir) if resume else ([], 0.0)
    if earlier:
        tqdm.write(f"resuming {run_dir} with {len(earlier)} points measured "
                   f"(training minutes after step {earlier[-1]['step']} estimated)")
    else:
        shutil.rmtree(run_dir, ignore_errors=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(run_dir / POINTS_FILE, "".join(json.dumps(p) + "\n" for p in earlier))
    label = ",".join(f"{k}={v}" for k, v in (option or {}).items())

    def rows(points: list[dict]) -> list[dict]:
        logged = {rec["step"]: rec["psnr"] for rec in read_log(run_dir)}
        return [{"method": method, "preset": preset, "option": label, "seed": seed, **p,
                 "train_psnr": logged.get(p["step"]), "teacher_test_psnr": teacher_psnr}
                for p in points]

    hook = Evaluator(method, steps, test_set, row.render, device,
                     points_file=run_dir / POINTS_FILE, points=earlier, train_seconds=seconds,
                     on_point=on_point and (lambda points: on_point(rows(points))))
    plugin.train(str(data), run_dir, preset, seed=seed, iterations=n_iter,
                 torch_device=torch_device, progress=progress, on_step=hook,
                 downscale=downscale, **options)
    return rows(hook.points)


PANELS = (("test_psnr", "test PSNR (dB)"), ("test_ssim", "test SSIM"),
          ("test_lpips", "test LPIPS-Alex (lower is better)"))
# The plot's x axis (--x-axis): a point's x value and the axis label.
X_AXES = {"minutes": (lambda p: p["train_seconds"] / 60,
                      "training wall-clock (min, evaluations excluded)"),
          "steps": (lambda p: p["step"], "training step")}


def _plot(points: list[dict], meta: dict) -> bytes:
    """PSNR, SSIM and LPIPS (where scored) against training minutes (or steps:
    ``meta["x_axis"]``, a key of :data:`X_AXES`), one panel each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(k, label) for k, label in PANELS
              if any(p.get(k) is not None for p in points)]
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.2), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    groups = list(dict.fromkeys((p["preset"], p.get("option", "")) for p in points))
    x_value, x_label = X_AXES[meta.get("x_axis", "minutes")]
    for ax, (key, label) in zip(axes[0], panels):
        for g, (preset, option) in enumerate(groups):
            name = f"{preset} {option}".strip()
            mine = [p for p in points if (p["preset"], p.get("option", "")) == (preset, option)]
            seeds = list(dict.fromkeys(p["seed"] for p in mine))
            for i, seed in enumerate(seeds):      # one colour a curve, one line a seed
                pts = [p for p in mine if p["seed"] == seed and p.get(key) is not None]
                ax.plot([x_value(p) for p in pts], [p[key] for p in pts],
                        marker="o", color=colours[g % len(colours)],
                        alpha=1.0 if i == 0 else 0.55,
                        label=f"{name} (seed{'s' if len(seeds) > 1 else ''} "
                              f"{', '.join(map(str, seeds))})" if i == 0 else None)
            if key == "test_psnr" and mine[0].get("teacher_test_psnr") is not None:
                ax.axhline(mine[0]["teacher_test_psnr"], color=colours[g % len(colours)],
                           linestyle="--", label=f"{name}: teacher")
        ax.set_xlabel(x_label)
        ax.set_ylabel(f"{label}, baked model, OpenCL")
        ax.grid(alpha=0.3)
    axes[0][0].legend()
    row = f": {meta['row']}" if meta.get("row") else ""
    fig.suptitle(f"{points[0]['method']}{row}, {meta['scene']}, git "
                 f"{meta['git_revision']}, {meta['date'][:10]}\n{meta['device']}", fontsize=9)
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
    ``row`` name, for the plot's title; ``x_axis``, see :func:`_plot`)."""
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(COLUMNS)
    for p in points:
        writer.writerow([p["method"], p["preset"], p.get("option", ""), p["seed"], p["step"],
                         f"{p['train_seconds']:.2f}", f"{p['eval_seconds']:.2f}",
                         f"{p['test_psnr']:.4f}", f"{p['test_ssim']:.4f}",
                         _cell(p.get("test_lpips")), _cell(p["train_psnr"]),
                         _cell(p["teacher_test_psnr"])])
    write_atomic(Path(out_dir) / f"{KEY}.csv", buf.getvalue())
    write_atomic(Path(out_dir) / f"{KEY}.png", _plot(points, meta))
    w = max([13] + [len(p.get("option", "")) for p in points])
    lines = [f"{'preset':8s} {'option':{w}s} {'seed':>4s} {'step':>6s} {'train min':>9s} "
             f"{'eval s':>7s} {'test PSNR':>9s} {'SSIM':>6s} {'LPIPS':>6s} {'train PSNR':>10s} "
             f"{'teacher':>8s}"]
    lines += [f"{p['preset']:8s} {p.get('option', ''):{w}s} {p['seed']:4d} {p['step']:6d} "
              f"{p['train_seconds'] / 60:9.2f} "
              f"{p['eval_seconds']:7.1f} {p['test_psnr']:9.2f} {p['test_ssim']:6.3f} "
              f"{_cell(p.get('test_lpips'), '{:6.3f}') or '   n/a'} "
              f"{_cell(p['train_psnr'], '{:10.2f}') or '       n/a'} "
              f"{_cell(p['teacher_test_psnr'], '{:8.2f}') or '     n/a'}" for p in points]
    return "\n".join(lines)


def compare_options(points: list[dict]) -> list[dict]:
    """Per preset, each ``option`` value after the first against the first at every step
    both evaluated, paired by seed (two or more): ``{preset, option, against, step, n,
    mean, lo, hi}``, the mean test-PSNR difference (dB) and its 95% t interval."""
    from bench.tables import seeds

    out = []
    for preset in dict.fromkeys(p["preset"] for p in points):
        mine = [p for p in points if p["preset"] == preset]
        options = list(dict.fromkeys(p.get("option", "") for p in mine))
        psnr = {(p.get("option", ""), p["seed"], p["step"]): p["test_psnr"] for p in mine}
        for option in options[1:]:
            for step in sorted({p["step"] for p in mine}):
                pairs = [(psnr[option, s, step], psnr[options[0], s, step])
                         for s in sorted({p["seed"] for p in mine})
                         if (option, s, step) in psnr and (options[0], s, step) in psnr]
                if len(pairs) < 2:
                    continue
                mean, std = seeds.paired_delta(*zip(*pairs))
                lo, hi = seeds.interval(mean, std, len(pairs))
                out.append({"preset": preset, "option": option, "against": options[0],
                            "step": step, "n": len(pairs), "mean": mean, "lo": lo, "hi": hi})
    return out


def _comparison_text(rows: list[dict]) -> str:
    if not rows:
        return ""
    lines = ["", "test PSNR difference at equal steps, paired by seed (95% t interval):"]
    lines += [f"{r['preset']:8s} {r['option']} - {r['against']} step {r['step']:6d}: "
              f"{r['mean']:+.2f} dB [{r['lo']:+.2f}, {r['hi']:+.2f}] (n = {r['n']}), "
              f"{'0 inside' if r['lo'] <= 0 <= r['hi'] else 'differs'}" for r in rows]
    return "\n".join(lines)


def run(args, meta: dict) -> str:
    """``python -m bench.train_curve``: every ``--preset``'s curve (default
    :data:`PRESETS`) of ``--method``, for each ``--option`` value and seed, into
    ``args.out``, the files rewritten after each curve; returns the text table (with the
    options' comparison, :func:`compare_options`)."""
    row = baseline_row(args.method)
    scene = args.scene or ablation.load_table(methods.bench_of(args.method).curve_table).scene
    data = cache.resolve_scene(scene, args.cache)
    fingerprint = cache.data_fingerprint(data, args.downscale)
    curves = curve_options(args.method, args.option)
    name = row.name if curves == [None] else f"{row.name} with the legend's options"
    meta = {**meta, "scene": options.shown_scene(scene, args.downscale), "method": args.method,
            "row": name if args.test_stride == 1
            else f"{name}, every {args.test_stride}th test view", "x_axis": args.x_axis}
    points, text = [], ""
    for preset in args.presets or PRESETS:
        # Seed outermost: a run cut short still holds whole pairs to compare.
        for seed in range(args.seed, args.seed + args.seeds):
            for option in curves:
                done = list(points)     # the files are rewritten after each evaluation
                points = done + measure_curve(
                    args.cache, data, fingerprint, preset, seed=seed, device=args.device,
                    torch_device=args.torch_device, method=args.method, option=option,
                    downscale=args.downscale, test_stride=args.test_stride,
                    n_points=args.points, iterations=args.iterations, resume=args.resume,
                    on_point=lambda mine: write_curve(args.out, done + mine, meta))
                text = write_curve(args.out, points, meta)
    return text + _comparison_text(compare_options(points))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench.train_curve", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", dest="presets", choices=methods.all_presets(), action="append",
                   default=None, help=f"repeatable (default: {' and '.join(PRESETS)})")
    p.add_argument("--method", default=None, choices=methods.names(),
                   help=f"the method whose curve is measured (default {methods.default()})")
    p.add_argument("--option", action="append", default=None, metavar="NAME=V1,V2",
                   help="a curve for each value of one of the method's training options (e.g. "
                        "engine=torch,fast), compared with the first at equal steps when "
                        "--seeds >= 2; repeated, options of one value hold for every curve "
                        "(--option L=4 --option variant=separate-v,sum)")
    p.add_argument("--test-stride", type=whole_number("test stride"), default=1, metavar="K",
                   help="score every K-th test view (default 1: all)")
    p.add_argument("--points", type=whole_number("points"), default=N_POINTS, metavar="N",
                   help=f"evaluations along a run, the first and last step included "
                        f"(default {N_POINTS})")
    p.add_argument("--iterations", type=whole_number("iterations"), default=None, metavar="N",
                   help="train N steps instead of the preset's (a budget of equal minutes for "
                        "presets or engines of different step times)")
    p.add_argument("--x-axis", choices=tuple(X_AXES), default="minutes",
                   help="the plot's x axis: training minutes (default) or steps (a run whose "
                        "minutes are not a timing: paused, resumed on other threads)")
    p.add_argument("--resume", action="store_true",
                   help="continue each curve's run folder from its checkpoint (a run cut "
                        "short), keeping the points measured before it, instead of afresh")
    options.add_common(p)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    args.method = args.method or methods.default()
    args.cache = args.cache or cache.cache_root()
    try:
        print(run(args, options.run_meta(args.device)))
    except USER_ERRORS as exc:
        return one_line_error("bench.train_curve", exc)
    print(f"results written to {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
