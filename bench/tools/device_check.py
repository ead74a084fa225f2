"""Every OpenCL device of a machine renders both methods, checked against reference images.

    python -m bench.tools.device_check --make-reference .devcheck     # here, with PoCL: models + images
    python -m bench.tools.device_check --reference .devcheck --out results/   # on any machine

``--make-reference`` writes each registered method's example model (its ``example_model``:
NGP-RT a random ``cpu`` model, separate-v, L = 2; NDRF a random K = 2 model) as baked files,
and each one's render of an orbit view at 800x800
and 1920x1080 on the chosen device (``$CLRENDER_DEVICE``, PoCL here) as reference images
(uint16 in ``reference.npz``, with the device and date in ``reference.json``). The check
then lists every platform and device, renders the same views of the same files on each,
and reports per device, method and size the frame time (median of ``--repeats`` after a
warm-up), the PSNR and largest difference against the reference, and writes
``device_check.{md,json}``. Each device is checked in a process of its own: a driver that
crashes (at a build, a render or its own teardown: pip's PoCL 3.0 aborts at exit on CPUs its
LLVM does not know) is that device's finding, not the end of the check.

It needs numpy and pyopencl only (no torch, scipy, scikit-image or embreex), so it runs on a
machine that reaches no package registry with those two as wheels beside the folder the
first command wrote. Never asserts.
"""
from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
import tempfile
import traceback
from pathlib import Path

import numpy as np

from clrender import methods
from clrender.atomic import write_atomic
from clrender.device import device_info, list_devices
from clrender.metrics import psnr, summarize_ms
from clrender.paths import path_cameras
from clrender.renderer import Renderer

from bench.speed.sizes import parse_size

SIZES = ((800, 800), (1920, 1080))


def _camera(width: int, height: int):
    return path_cameras("bounded", "orbit", 8, width, height)[1]


def checked_methods() -> list[str]:
    """The registered methods with an ``example_model``."""
    return [n for n, bench in methods.benched().items() if bench.example_model is not None]


def make_models(folder: Path) -> dict:
    """Every checked method's example model baked into ``folder``: {method: path}."""
    folder.mkdir(parents=True, exist_ok=True)
    return {name: methods.bench_of(name).example_model(folder / f"{name}.npz")
            for name in checked_methods()}


def make_reference(folder: Path, device=None) -> None:
    paths = make_models(folder)
    images, where = {}, None
    for method, path in paths.items():
        renderer = Renderer(path, device=device)
        where = renderer.device_name
        for w, h in SIZES:
            rgb = renderer.render(_camera(w, h))["rgb"]
            images[f"{method}_{w}x{h}"] = np.round(np.clip(rgb, 0, 1) * 65535).astype(np.uint16)
            print(f"reference {method} {w}x{h} on {where}", flush=True)
    tmp = folder / "reference.tmp.npz"
    np.savez_compressed(tmp, **images)
    tmp.replace(folder / "reference.npz")
    write_atomic(folder / "reference.json", json.dumps(
        {"device": where, "date": datetime.datetime.now().isoformat(timespec="seconds"),
         "sizes": [list(s) for s in SIZES], "methods": sorted(paths)}, indent=2))


def check_device(index: int, folder: Path, reference: dict, repeats: int,
                 sizes=SIZES) -> list[dict]:
    """Rows for device ``index`` of :func:`list_devices`: each method and size, or the error
    (in this process; :func:`check_device_apart` runs it in a process of its own)."""
    rows = []
    for method in _methods_in(reference):
        try:
            renderer = Renderer(methods.load(folder / f"{method}.npz"), device=str(index))
        except Exception as e:          # noqa: BLE001 - a device that cannot build is a finding
            rows.append({"method": method, "error": f"{type(e).__name__}: {e}"})
            continue
        for w, h in sizes:
            row = {"method": method, "size": f"{w}x{h}"}
            try:
                camera = _camera(w, h)
                rgb = renderer.render(camera)["rgb"]
                row["ms"] = summarize_ms(renderer.render(camera)["ms"] for _ in range(repeats))
                ref = reference[f"{method}_{w}x{h}"].astype(np.float32) / 65535
                got = np.round(np.clip(rgb, 0, 1) * 65535).astype(np.float32) / 65535
                row["psnr"] = float(psnr(got, ref))
                row["max_abs_diff"] = float(np.abs(got - ref).max())
            except Exception as e:      # noqa: BLE001
                row["error"] = f"{type(e).__name__}: {e}"
                traceback.print_exc()
            rows.append(row)
            print(index, row, flush=True)
    return rows


def check_device_apart(index: int, folder: Path, repeats: int, sizes) -> tuple[list[dict], str]:
    """:func:`check_device` in a child process: ``(rows, exit)``, exit "" for a clean exit,
    else what ended the child (its rows kept where it wrote them before dying)."""
    with tempfile.TemporaryDirectory() as tmp:
        rows_file = Path(tmp) / "rows.json"
        proc = subprocess.run(     # from the folder bench/ is in, whatever the caller's
            [sys.executable, "-m", "bench.tools.device_check", "--reference", str(folder.resolve()),
             "--device-index", str(index), "--rows-out", str(rows_file),
             "--repeats", str(repeats), "--sizes", *(f"{w}x{h}" for w, h in sizes)],
            capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2])
        print(proc.stdout, end="", flush=True)
        rows = json.loads(rows_file.read_text()) if rows_file.exists() else None
    if proc.returncode == 0 and rows is not None:
        return rows, ""
    how = (f"signal {-proc.returncode}" if proc.returncode < 0
           else f"exit status {proc.returncode}")
    tail = " ".join(proc.stderr.strip().splitlines()[-2:])[-300:]
    exit_note = f"its process ended with {how} ({tail})"
    if rows is None:
        rows = [{"method": m, "error": f"no result: {exit_note}"} for m in checked_methods()]
    return rows, exit_note


def markdown(devices: list[dict], meta: dict) -> str:
    checked = ", ".join(meta["reference"].get("methods", []))
    lines = ["## Device check", "",
             f"Reference images: {meta['reference']['device']} ({meta['reference']['date']}); "
             f"each method's example model ({checked}), one "
             f"orbit view; frame time: median of {meta['repeats']} after a warm-up (each "
             "method's frame time, its TIME_NOTE). PSNR against the reference, both "
             "quantised to 16 bits (ceiling ~107 dB).", "",
             "| device | type | method | frame | ms | FPS | PSNR vs reference | max abs diff |",
             "|---|---|---|---|---|---|---|---|"]
    for d in devices:
        for r in d["rows"]:
            if "error" in r:
                lines.append(f"| {d['name']} | {d['type']} | {r['method']} | "
                             f"{r.get('size', '')} | error: {r['error'][:120]} | | | |")
                continue
            ms = r["ms"]["median"]
            lines.append(f"| {d['name']} | {d['type']} | {r['method']} | {r['size']} | "
                         f"{ms:.1f} | {1000 / ms:.1f} | {r['psnr']:.1f} | "
                         f"{r['max_abs_diff']:.1e} |")
    ended = [f"- {d['name']}: {d['exit']}" for d in devices if d.get("exit")]
    if ended:
        lines += ["", "Devices whose check process did not exit cleanly (rows above as "
                  "written before):", *ended]
    return "\n".join(lines) + "\n"


def _methods_in(reference: dict) -> list[str]:
    """The methods a reference has images of (keys ``<method>_<W>x<H>``)."""
    return sorted({key.rsplit("_", 1)[0] for key in reference})


def load_reference(folder: Path) -> dict:
    with np.load(folder / "reference.npz", allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


def run(folder: Path, out: Path, repeats: int) -> list[dict]:
    devices = []
    for index, device in enumerate(list_devices()):
        info = device_info(device)
        name = f"{info['platform']} / {info['device']}"
        print(f"[{index}] {name}", flush=True)
        rows, exit_note = check_device_apart(index, folder, repeats, SIZES)
        devices.append({"index": index, "name": name, "type": info["type"], "info": info,
                        "rows": rows, "exit": exit_note})
    meta = {"reference": json.loads((folder / "reference.json").read_text()),
            "repeats": repeats, "date": datetime.datetime.now().isoformat(timespec="seconds")}
    text = markdown(devices, meta)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "device_check.md", text)
    write_atomic(out / "device_check.json", json.dumps({"meta": meta, "devices": devices},
                                                       indent=2))
    print(text)
    return devices


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.tools.device_check", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--make-reference", type=Path, metavar="DIR",
                   help="write the models and reference images (on this machine's device)")
    g.add_argument("--reference", type=Path, metavar="DIR", help="check every device against DIR")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--device", default=None, help="device for --make-reference")
    # One device's check in its own process (run() starts these).
    p.add_argument("--device-index", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--rows-out", type=Path, default=None, help=argparse.SUPPRESS)
    p.add_argument("--sizes", nargs="+", type=parse_size, default=list(SIZES),
                   help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.make_reference:
        make_reference(args.make_reference, args.device)
    elif args.device_index is not None:
        rows = check_device(args.device_index, args.reference, load_reference(args.reference),
                            args.repeats, args.sizes)
        write_atomic(args.rows_out, json.dumps(rows))
    else:
        run(args.reference, args.out, args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
