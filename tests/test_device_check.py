"""bench.tools.device_check on this machine's devices against references made here (small sizes),
once per CPU implementation (cl_platform: PoCL, Intel's runtime) as the reference's
device: every device that builds kernels renders both methods, and the reference's device
reproduces its own references."""
from __future__ import annotations

import json

import pytest

from bench.tools import device_check
from clrender.device import _compiles, list_devices


def test_device_check_against_own_reference(tmp_path, monkeypatch, cl_platform):
    monkeypatch.setattr(device_check, "SIZES", ((40, 30), (24, 24)))
    device_check.make_reference(tmp_path / "ref")
    devices = device_check.run(tmp_path / "ref", tmp_path / "out", repeats=1)
    report = json.loads((tmp_path / "out" / "device_check.json").read_text())
    assert len(report["devices"]) == len(devices) >= 1
    ref_device = report["meta"]["reference"]["device"]
    own = [d for d in devices if d["name"] == ref_device]
    assert len(own) == 1, (ref_device, [d["name"] for d in devices])
    rows = own[0]["rows"]
    assert {(r["method"], r["size"]) for r in rows} == {
        (m, s) for m in device_check.checked_methods() for s in ("40x30", "24x24")}
    assert {"ngprt", "ndrf"} <= set(device_check.checked_methods())
    for r in rows:
        assert "error" not in r and r["max_abs_diff"] == pytest.approx(0.0, abs=1 / 65535), r
    builds = {f"{d.platform.name.strip()} / {d.name.strip()}" for d in list_devices()
              if _compiles(d)}
    for d in devices:
        if d["name"] in builds:
            assert all("error" not in r for r in d["rows"]), (d["name"], d["rows"])
    assert "| ndrf | 40x30 |" in (tmp_path / "out" / "device_check.md").read_text()


def test_a_dying_device_process_is_that_devices_finding(tmp_path):
    # The child process of device 0 fails before writing its rows (no reference here):
    # every method gets an error row naming how the process ended, and the check goes on.
    rows, exit_note = device_check.check_device_apart(0, tmp_path, 1, ((8, 8),))
    assert [r["method"] for r in rows] == device_check.checked_methods()
    assert all(r["error"].startswith("no result: its process ended with exit status 1")
               for r in rows), rows
    assert "reference.npz" in exit_note
