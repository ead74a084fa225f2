"""Private memory, work-group limits and launch sizes of every kernel, per OpenCL device.

    python -m bench.speed.kernel_resources                  # every device, 1920x1080, results/
    python -m bench.speed.kernel_resources --size 800x800 --out /tmp/r

For every device that builds kernels, each method's kernels are built (the fast build, the
one that renders) in two layouts: ``gpu``, the organisation the renderers choose on a GPU
(the NGP-RT march and deferred MLP one ray / pixel a work-item, ``RAYS = 1``; the NDRF
rasteriser one tile row and one triangle a work-item, ``rows = 1``, ``lanes = 1``:
:data:`clrender.ndrf.raster_cl.GPU_LAYOUT`; the NDRF shader's conv0 one pixel a work-item,
``SEG = 1``: :data:`clrender.ndrf.shader_cl.GPU_LAYOUT`), and ``default``, the one they
choose on that device. Models: random ones (NGP-RT the ``cpu`` preset, separate-v, L = 2;
NDRF the default config, K = 2: the methods' ``example_model``). Per kernel:
CL_KERNEL_PRIVATE_MEM_SIZE (bytes a work-item), CL_KERNEL_WORK_GROUP_SIZE,
CL_KERNEL_PREFERRED_WORK_GROUP_SIZE_MULTIPLE, and the global work-items of its launch in a
frame (before padding to the work-group size; the renderers' own ``launch_sizes``; the
smallest where a frame launches it more than once). The NDRF rasteriser's setup and bin
passes run per face (one per ``lanes`` faces, one per face), so their counts are the random
model's; its tile scan is one work-group. Writes ``<out>/kernel_resources.{md,json}``.
Never asserts.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
from pathlib import Path

import pyopencl as cl

from clrender.atomic import write_atomic
from clrender.device import device_type_name, get_runtime, list_devices

from .sizes import parse_size

LAYOUTS = ("gpu", "default")


def example_models() -> tuple:
    """(NGP-RT model, NDRF model): the random models of the module doc."""
    from clrender.ndrf.config import NDRFConfig
    from clrender.ndrf.random_model import random_ndrf_model
    from clrender.ngprt.config import preset
    from clrender.ngprt.random_model import random_baked_model

    return (random_baked_model(preset("cpu", variant="separate-v", L=2), seed=0),
            random_ndrf_model(NDRFConfig(), seed=0))


def renderers(runtime, layout: str, models: tuple) -> dict:
    """``{method: [renderer objects]}`` built on ``runtime`` in ``layout`` (:data:`LAYOUTS`),
    each with ``kernels`` and ``launch_sizes(width, height)``."""
    from clrender.ndrf import raster_cl, shader_cl
    from clrender.ngprt.render_cl import Renderer

    gpu = layout == "gpu"
    ngprt, ndrf = models
    return {"ngprt": [Renderer(ngprt, runtime, rays=1 if gpu else None,
                               deferred_vec=1 if gpu else None)],
            "ndrf": [raster_cl.Rasteriser(ndrf, runtime,
                                          **(raster_cl.GPU_LAYOUT if gpu else {})),
                     shader_cl.Shader(ndrf, runtime,
                                      layout=shader_cl.GPU_LAYOUT if gpu else None)]}


def frame_launches(runtime, layout: str, width: int, height: int,
                   models: tuple | None = None) -> list[dict]:
    """Every kernel launch of a ``width`` x ``height`` frame of each method on ``runtime``
    in ``layout``, in order: ``{"method", "kernel", "size"`` (global work-items per axis,
    before padding), ``"work_items"`` (their product), ``"cl_kernel"``}``. ``models``:
    (NGP-RT, NDRF), default :func:`example_models`."""
    out = []
    for method, objects in renderers(runtime, layout, models or example_models()).items():
        for obj in objects:
            for name, size in obj.launch_sizes(width, height):
                out.append({"method": method, "kernel": name, "size": list(size),
                            "work_items": math.prod(size), "cl_kernel": obj.kernels[name]})
    return out


def kernel_rows(runtime, layout: str, width: int, height: int, models: tuple) -> list[dict]:
    """One row per kernel of :func:`frame_launches`: its launches in the frame, the smallest
    one's work-items, and the kernel's work-group info on the device."""
    info, device, rows = cl.kernel_work_group_info, runtime.device, {}
    for launch in frame_launches(runtime, layout, width, height, models):
        key = (launch["method"], launch["kernel"])
        if key in rows:
            rows[key]["launches"] += 1
            rows[key]["work_items"] = min(rows[key]["work_items"], launch["work_items"])
            continue
        kernel = launch["cl_kernel"]
        rows[key] = {
            "layout": layout, "method": launch["method"], "kernel": launch["kernel"],
            "launches": 1, "work_items": launch["work_items"], "size": launch["size"],
            "private_bytes": int(kernel.get_work_group_info(info.PRIVATE_MEM_SIZE, device)),
            "work_group_size": int(kernel.get_work_group_info(info.WORK_GROUP_SIZE, device)),
            "preferred_multiple": int(kernel.get_work_group_info(
                info.PREFERRED_WORK_GROUP_SIZE_MULTIPLE, device))}
    return list(rows.values())


def device_rows(width: int, height: int) -> list[dict]:
    """Per device: ``{"device", "type", "rows"}`` (:func:`kernel_rows` of both layouts) or
    ``"error"`` where it builds no kernel or a build fails."""
    models, out = example_models(), []
    for i, device in enumerate(list_devices()):
        entry = {"device": f"{device.platform.name.strip()} / {device.name.strip()}",
                 "type": device_type_name(device)}
        try:
            runtime = get_runtime(str(i))
            entry["rows"] = [r for layout in LAYOUTS
                             for r in kernel_rows(runtime, layout, width, height, models)]
        except (cl.Error, RuntimeError) as exc:
            entry["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0][:300]}"
        out.append(entry)
        print(entry["device"], "done" if "rows" in entry else entry["error"], flush=True)
    return out


def markdown(devices: list[dict], meta: dict) -> str:
    head = ["layout", "method", "kernel", "launches", "work-items", "private B",
            "max WG", "WG multiple"]
    lines = [f"# Kernel resources at {meta['width']}x{meta['height']}", "",
             f"{meta['date']}; the fast build; work-items: global, before padding (the "
             "smallest launch where a frame has several); private B: "
             "CL_KERNEL_PRIVATE_MEM_SIZE a work-item; max WG: CL_KERNEL_WORK_GROUP_SIZE; "
             "WG multiple: CL_KERNEL_PREFERRED_WORK_GROUP_SIZE_MULTIPLE. Layouts: `gpu` "
             "(RAYS = 1, raster rows = 1 and lanes = 1, shader SEG = 1), `default` (the "
             "device's own).", ""]
    for d in devices:
        lines += [f"## {d['device']} ({d['type']})", ""]
        if "error" in d:
            lines += [f"Not measured: {d['error']}", ""]
            continue
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += [f"| {r['layout']} | {r['method']} | {r['kernel']} | {r['launches']} | "
                  f"{r['work_items']} | {r['private_bytes']} | {r['work_group_size']} | "
                  f"{r['preferred_multiple']} |" for r in d["rows"]]
        lines.append("")
    return "\n".join(lines)


def run(width: int, height: int, out: Path) -> list[dict]:
    devices = device_rows(width, height)
    meta = {"width": width, "height": height,
            "date": datetime.datetime.now().isoformat(timespec="seconds")}
    text = markdown(devices, meta)
    write_atomic(out / "kernel_resources.md", text)
    write_atomic(out / "kernel_resources.json",
                 json.dumps({"meta": meta, "devices": devices}, indent=2))
    print(text)
    return devices


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.speed.kernel_resources", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=parse_size, default=(1920, 1080), metavar="WxH",
                   help="frame size whose launches are counted (default 1920x1080)")
    p.add_argument("--out", type=Path, default=Path("results"))
    args = p.parse_args(argv)
    run(*args.size, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
