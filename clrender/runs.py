"""A training run folder, the same for every method: ``config.json`` (written atomically,
compared to decide whether to resume), ``checkpoint.pt`` (atomic; torch tensors only, read
with ``weights_only=True``), ``log.jsonl`` (one JSON line per logged step) and the
progress loop that writes them, with every method's guard against steps that are not
finite: a method skips its optimiser step where :func:`finite_step` is False (so a run is
never poisoned) and tells :meth:`RunFolder.count_step`, which counts the step (``skipped``
in the log and the checkpoint), saves the first one to ``nonfinite-step-N.pt`` to
reproduce it, and stops the run after :data:`MAX_NONFINITE_IN_A_ROW` in a row.

Examples:
    >>> run = RunFolder("/tmp/run", {"method": "ngprt", "model": {...}, "seed": 0})
    >>> state = run.resume_state("cpu")            # None: start afresh
    >>> run.write_config()
    >>> for step in run.steps(0, 1000, log_every=25, checkpoint_every=250, desc="train"):
    ...     loss = ...; loss.backward()
    ...     finite = finite_step(loss, model.parameters())
    ...     if finite:
    ...         opt.step()
    ...     run.count_step(step, finite, lambda: {"model": model.state_dict()})
    ...     run.after_step(step, lambda: {"loss": loss}, lambda: {"model": model.state_dict()})
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Callable, Iterator

import torch

from .atomic import atomic_write


MAX_NONFINITE_IN_A_ROW = 50     # skipped steps in a row after which a run stops


def pick_device(device=None) -> torch.device:
    """The torch device ``device``, or cuda when present, else cpu."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def training_data(data, downscale: int = 1):
    """(the train split, its folder for the run's config or None): ``data`` is a dataset
    folder (read at ``downscale``) or an already loaded :class:`clrender.data.Dataset`."""
    if hasattr(data, "images"):
        return data, None
    from .data import load_dataset

    return load_dataset(data, split="train", downscale=downscale), str(Path(data).resolve())


def set_lr(opt: torch.optim.Optimizer, lr: float) -> None:
    for group in opt.param_groups:
        group["lr"] = lr


def mse_psnr(mse: float) -> float:
    """PSNR in dB of a mean squared error of images in [0, 1] (floored at 1e-10)."""
    return -10.0 * math.log10(max(mse, 1e-10))


def finite_step(loss: torch.Tensor, params) -> bool:
    """Whether ``loss`` and the gradients of ``params`` are all finite: one fused norm over
    the gradients, a single read of each (its cost: docs/guides/training.md, "Steps that are not
    finite"); a norm that overflows float32 counts as not finite."""
    grads = [p.grad for p in params if p.grad is not None]
    return bool(torch.isfinite(loss)) and bool(
        torch.isfinite(torch.nn.utils.get_total_norm(grads, foreach=True)))


class RunFolder:
    """The run folder ``out`` of a training with config ``config`` (a JSON-ready dict that
    names its ``method``; normalised through JSON so it compares equal to its file).

    Attributes:
        dir, config_path, checkpoint_path, log_path: the folder and its files.
        skipped: the steps skipped as not finite so far (restored on resuming).
        resumable: ``config.json`` exists and equals ``config`` but for the keys in
            ``free`` (settings a run may resume under another value of, e.g. the
            training engine; ``config.json`` then records the new one).
    """

    def __init__(self, out, config: dict, free: tuple = ()):
        if "method" not in config:
            raise ValueError(f"{out}: a run's config must name its method")
        self.dir = Path(out)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.config = json.loads(json.dumps(config))
        self.config_path = self.dir / "config.json"
        self.checkpoint_path = self.dir / "checkpoint.pt"
        self.log_path = self.dir / "log.jsonl"
        fixed = lambda d: {k: v for k, v in d.items() if k not in free}   # noqa: E731
        self.resumable = self.config_path.is_file() and \
            fixed(json.loads(self.config_path.read_text())) == fixed(self.config)
        self._log, self._t0 = None, 0.0
        self.skipped, self._in_a_row = 0, 0

    def write_config(self) -> None:
        self.config_path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(self.config_path,
                     lambda tmp: tmp.write_text(json.dumps(self.config, indent=2)))

    def forget(self, *stale) -> None:
        """Remove the config, the checkpoint and ``stale`` paths (a run that starts afresh)."""
        for path in (self.config_path, self.checkpoint_path, *stale):
            Path(path).unlink(missing_ok=True)

    def resume_state(self, device) -> dict | None:
        """The checkpoint's state dict when the run is resumable and has one, else None
        (its count of skipped steps becomes :attr:`skipped`)."""
        if not (self.resumable and self.checkpoint_path.is_file()):
            return None
        state = torch.load(self.checkpoint_path, map_location=device, weights_only=True)
        self.skipped = int(state.get("skipped", 0))
        return state

    def resume(self, model: torch.nn.Module, opt: torch.optim.Optimizer, device) -> dict | None:
        """When resumable, load the checkpoint's ``model`` and ``optimizer`` entries into
        ``model`` and ``opt``; returns the whole state (``step`` and the method's own
        entries), or None to start afresh."""
        state = self.resume_state(device)
        if state is not None:
            model.load_state_dict(state["model"])
            opt.load_state_dict(state["optimizer"])
        return state

    def save_checkpoint(self, state: dict) -> None:
        """Atomic: written to a temporary file, then moved over ``checkpoint.pt``."""
        atomic_write(self.checkpoint_path, lambda tmp: torch.save(state, tmp))

    def steps(self, start: int, iterations: int, log_every: int, checkpoint_every: int,
              desc: str = "train", progress: bool = True) -> Iterator[int]:
        """Steps ``start .. iterations - 1`` under a tqdm bar, with ``log.jsonl`` open
        (appended to when resuming, started afresh otherwise) for :meth:`after_step`."""
        from tqdm import tqdm

        self._iterations, self._log_every = iterations, log_every
        self._checkpoint_every, self._t0 = checkpoint_every, time.time()
        self.bar = tqdm(range(start, iterations), initial=start, total=iterations,
                        disable=not progress, desc=desc, dynamic_ncols=True)
        with open(self.log_path, "a" if start else "w") as self._log:
            yield from self.bar
        self._log = None

    def count_step(self, step: int, finite: bool, reproduce: Callable[[], dict]) -> None:
        """After ``step``'s backward: where it was not ``finite`` (the method skipped its
        optimiser step), count it and, the first time, save ``{"step": step,
        **reproduce()}`` to ``nonfinite-step-{step}.pt``, read back with
        ``torch.load(path, weights_only=True)``; ``reproduce()`` returns torch tensors and
        numbers: the model the step left unchanged and what else it needs to be replayed.

        Raises:
            RuntimeError: the :data:`MAX_NONFINITE_IN_A_ROW`-th skipped step in a row.
        """
        if finite:
            self._in_a_row = 0
            return
        self.skipped, self._in_a_row = self.skipped + 1, self._in_a_row + 1
        if self.skipped == 1:
            path = self.dir / f"nonfinite-step-{step}.pt"
            atomic_write(path, lambda tmp: torch.save({"step": step, **reproduce()}, tmp))
            self.bar.write(f"step {step}: loss or gradients not finite, step skipped (the "
                           f"count is logged as 'skipped'; reproduce it from {path})")
        if self._in_a_row >= MAX_NONFINITE_IN_A_ROW:
            raise RuntimeError(
                f"{self.dir}: {self._in_a_row} training steps in a row up to step {step} had "
                "a loss or gradients that were not finite, each skipped; the checkpoint "
                "holds the last finite model")

    def after_step(self, step: int, record: Callable[[], dict],
                   state: Callable[[], dict]) -> None:
        """At the end of ``step``: a log line ``{"step", **record(), "skipped", "seconds"}``
        every ``log_every`` steps and at the last one; the checkpoint ``state()`` (plus
        ``"skipped"`` and ``"step": step + 1``) every ``checkpoint_every`` steps and at the
        last one."""
        last = step == self._iterations - 1
        if step % self._log_every == 0 or last:
            line = {"step": step, **record(), "skipped": self.skipped,
                    "seconds": time.time() - self._t0}
            self._log.write(json.dumps(line) + "\n")
            self._log.flush()
        if (step + 1) % self._checkpoint_every == 0 or last:
            self.save_checkpoint({**state(), "skipped": self.skipped, "step": int(step + 1)})


def read_log(run_dir) -> list[dict]:
    """The records of a run's ``log.jsonl``."""
    return [json.loads(line) for line in (Path(run_dir) / "log.jsonl").read_text().splitlines()]
