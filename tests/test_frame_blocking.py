"""A rendered frame waits for the device only in its final read-back (NGP-RT, and NDRF with
the rasteriser's hits), and an NDRF frame that overflows the rasteriser's tile list is
redone with the same hits as one with room.

pyopencl is wrapped and every call logged in order: kernel launches and copies that do not
wait ("enqueue"); blocking reads of a device buffer into a host array ("read"); calls that
wait for the device ("wait"): enqueue_copy from the host with is_blocking true or not
given, Event.wait, CommandQueue.finish, wait_for_events, and reading an event's profile
(it fails on an incomplete event, so code reading it has waited first). A copy between
device buffers never blocks. One wait is invisible to the wrapper: pyopencl's event of a
non-blocking copy from or to the host (a NannyEvent) waits for the copy when it is
deleted, in C++; so at the frame's first read each such event must still be held by the
renderer (a reference count above the log's own). A frame passes when it starts with an
enqueue, nothing waits before its first read, and nothing is enqueued or waits on
unfinished work after it (the queue runs in order: once a read returns, every earlier
command is complete). The 2nd frame is checked: the 1st may allocate. Exact equality of
hits and images for the overflowed frame: the same kernels over the same lists.
"""
from __future__ import annotations

import sys

import numpy as np
import pyopencl as cl
import pytest

from clrender.camera import Camera, look_at
from clrender.ndrf import raster_cl
from clrender.ndrf.config import NDRFConfig
from clrender.ndrf.random_model import random_ndrf_model
from clrender.ndrf.raster_cl import Rasteriser
from clrender.ndrf.render import Renderer as NDRFRenderer
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_cl import Renderer as NGPRTRenderer

CAMERA = Camera.from_fov(0.9, 40, 32, look_at([2.2, -1.9, 1.1]))


class _Log:
    """The pyopencl calls of a frame, in order: ``calls`` [(kind, what)], ``host_copies``
    the events of non-blocking copies between host and device."""

    def __init__(self):
        self.calls: list[tuple[str, str]] = []
        self.host_copies: list = []
        self.dropped: list[str] = []

    def add(self, kind: str, what: str):
        if kind == "read" and not any(k == "read" for k, _ in self.calls):
            alone = [sys.getrefcount(e) for e in [object()]][0]   # held by a list alone
            self.dropped = [str(e) for e in self.host_copies if sys.getrefcount(e) <= alone]
        self.calls.append((kind, what))

    def clear(self):
        self.calls, self.host_copies, self.dropped = [], [], []


@pytest.fixture
def log(monkeypatch) -> _Log:
    log = _Log()
    copy, kernel_call = cl.enqueue_copy, cl.Kernel.__call__
    wait, finish, wait_for, profile = (cl.Event.wait, cl.CommandQueue.finish,
                                       cl.wait_for_events, cl.Event.profile)

    def enqueue_copy(queue, dest, src, **kwargs):
        to_device = isinstance(dest, cl.MemoryObjectHolder)
        between_buffers = to_device and isinstance(src, cl.MemoryObjectHolder)
        blocking = not between_buffers and kwargs.get("is_blocking", True)
        kind = "enqueue" if not blocking else "wait" if to_device else "read"
        log.add(kind, "copy to the device" if to_device else "copy to the host")
        event = copy(queue, dest, src, **kwargs)
        if not blocking and not between_buffers:
            log.host_copies.append(event)
        return event

    def launch(self, *args, **kwargs):
        log.add("enqueue", f"kernel {self.function_name}")
        return kernel_call(self, *args, **kwargs)

    def logged(name, fn):
        def call(*args, **kwargs):
            log.add("wait", name)
            return fn(*args, **kwargs)
        return call

    monkeypatch.setattr(cl, "enqueue_copy", enqueue_copy)
    monkeypatch.setattr(cl.Kernel, "__call__", launch)
    monkeypatch.setattr(cl.Event, "wait", logged("Event.wait", wait))
    monkeypatch.setattr(cl.CommandQueue, "finish", logged("CommandQueue.finish", finish))
    monkeypatch.setattr(cl, "wait_for_events", logged("wait_for_events", wait_for))
    monkeypatch.setattr(cl.Event, "profile",
                        property(logged("Event.profile", profile.fget)))
    return log


def _assert_waits_only_in_final_reads(log: _Log):
    calls = log.calls
    first = next((i for i, (kind, _) in enumerate(calls) if kind == "read"), None)
    assert first is not None and calls[0][0] == "enqueue", calls
    assert any(what.startswith("kernel") for _, what in calls[:first]), calls
    assert [c for c in calls[:first] if c[0] != "enqueue"] == [], calls
    assert [c for c in calls[first:] if c[0] == "enqueue"] == [], calls
    assert log.dropped == [], f"non-blocking copies' events dropped (each waits): {log.dropped}"


@pytest.mark.parametrize("stats", [False, True])
def test_ngprt_frame_waits_only_in_its_reads(log, stats):
    model = random_baked_model(preset("tiny", variant="separate-v", L=2), seed=0)
    renderer = NGPRTRenderer(model)
    first = renderer.render(CAMERA, stats=stats)
    log.clear()
    out = renderer.render(CAMERA, stats=stats)
    _assert_waits_only_in_final_reads(log)
    np.testing.assert_array_equal(out["rgb"], first["rgb"])
    assert out["ms"] > 0


@pytest.mark.parametrize("stats", [False, True])
def test_ndrf_raster_frame_waits_only_in_its_reads(log, stats):
    renderer = NDRFRenderer(random_ndrf_model(NDRFConfig(), seed=0), hits="raster")
    first = renderer.render(CAMERA, stats=stats)
    log.clear()
    out = renderer.render(CAMERA, stats=stats)
    _assert_waits_only_in_final_reads(log)
    np.testing.assert_array_equal(out["rgb"], first["rgb"])
    assert out["ms_intersect"] > 0 and renderer.rasteriser.binned_pairs > 0


def test_overflowed_tile_list_is_grown_and_the_frame_redone(monkeypatch):
    model = random_ndrf_model(NDRFConfig(), seed=0)
    ample, ample_render = Rasteriser(model), NDRFRenderer(model).render(CAMERA)
    expected = ample.hits(CAMERA)
    monkeypatch.setattr(raster_cl, "INITIAL_PAIRS", 8)
    raster = Rasteriser(model)
    hits = raster.hits(CAMERA)
    assert raster.binned_pairs == ample.binned_pairs > 8
    assert raster.capacity >= raster.binned_pairs
    for got, want in zip((hits.tri, hits.bary, hits.depth),
                         (expected.tri, expected.bary, expected.depth)):
        np.testing.assert_array_equal(got, want)
    renderer = NDRFRenderer(model)
    out = renderer.render(CAMERA, stats=True)
    assert renderer.rasteriser.capacity >= renderer.rasteriser.binned_pairs > 8
    np.testing.assert_array_equal(out["rgb"], ample_render["rgb"])
    assert out["coverage"].any()
