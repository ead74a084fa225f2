"""Stage timing of a training step (``bench.speed.train_speed``): a clock the step reports to.

The step calls :func:`stage` around each forward stage and :func:`mark` on each stage's
output; both do nothing (one call, no allocation) unless a :class:`StageClock` is active
(``with clock.active():``), so the training path carries no timing cost by default.

Backward times come from gradient hooks: :func:`mark` hooks a stage's output, whose
gradient arrives when autograd starts that stage's backward; the time until the next
stage's output gradient arrives is the stage's backward (autograd on CPU runs one node at
a time, latest first; where two stages' backwards interleave, the time goes to the stage
whose gradient arrived last).

Examples:
    >>> clock = StageClock()
    >>> with clock.active():
    ...     train_step(...)
    >>> clock.forward["fine"], clock.backward["fine"]       # seconds
"""
from __future__ import annotations

import contextlib
import time
from collections import defaultdict

_NULL = contextlib.nullcontext()
_active: "StageClock | None" = None


class StageClock:
    """Seconds per stage, forward and backward, summed over the steps it was active."""

    def __init__(self):
        self.forward: dict[str, float] = defaultdict(float)
        self.backward: dict[str, float] = defaultdict(float)
        self._events: list[tuple[float, str]] = []

    @contextlib.contextmanager
    def active(self):
        global _active
        previous, _active = _active, self
        try:
            yield self
        finally:
            _active = previous

    @contextlib.contextmanager
    def _stage(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.forward[name] += time.perf_counter() - t0

    def _mark(self, x, name: str):
        if x.requires_grad:
            x.register_hook(lambda g: self._events.append((time.perf_counter(), name)))
        return x

    def run_backward(self, loss, first: str = "losses") -> None:
        """``loss.backward()``, its time split by the marked stages (``first`` until the
        first marked gradient arrives)."""
        self._events = [(time.perf_counter(), first)]
        loss.backward()
        self._events.append((time.perf_counter(), None))
        for (t0, name), (t1, _) in zip(self._events, self._events[1:]):
            self.backward[name] += t1 - t0
        self._events = []


def stage(name: str):
    """Context timing the forward stage ``name`` on the active clock (else nothing)."""
    return _NULL if _active is None else _active._stage(name)


def mark(x, name: str):
    """``x``, the output of stage ``name``; with an active clock its gradient's arrival
    starts that stage's backward time."""
    return x if _active is None else _active._mark(x, name)


def backward(loss) -> None:
    """``loss.backward()``, timed by stage on the active clock."""
    if _active is None:
        loss.backward()
    else:
        _active.run_backward(loss)

