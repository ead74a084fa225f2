"""The ``clrender`` command line: info | scene | data | capture | train | bake | render |
eval | view | export, plus each method's own commands (``clrender ndrf extract | init``).

Errors a user can cause (a bad file or folder, a missing or wrong device, a missing extra,
a port in use) print one line on stderr and exit with status 2."""
from __future__ import annotations

import argparse
import json
import os
import sys

from . import __version__, cliopts, methods
from .contract import check_options
from .device import DeviceError
from .export.serve import DEFAULT_PORT
from .extras import missing, require
from .paths import PATHS


def _cmd_info(args) -> int:
    from . import device

    devices = device.list_devices()
    if not devices:
        print("no OpenCL platform found")
        return 1
    chosen = None
    try:
        chosen = device.select_device(args.device)
    except device.DeviceError as exc:
        _error("info", exc)
    for i, d in enumerate(devices):
        info = device.device_info(d)
        mark = "*" if chosen is not None and d == chosen else " "
        print(f"{mark}[{i}] {info['platform']} ({info['platform_version']})")
        for k, v in info.items():
            if k not in ("platform", "platform_version"):
                print(f"      {k:20s} {v}")
    if chosen is not None:
        how = (f"CLRENDER_DEVICE / --device {args.device or os.environ.get('CLRENDER_DEVICE')!r}"
               if (args.device or os.environ.get("CLRENDER_DEVICE", "")).strip()
               else device.choice_reason(chosen, devices))
        print(f"selected: {chosen.platform.name.strip()} / {chosen.name.strip()} ({how})")
    return 0 if chosen is not None else 2


def _cmd_scene(args) -> int:
    require("train", "`clrender scene make`", modules=("trimesh", "embreex"))
    from .data.scene import make_scene

    out = make_scene(args.kind, args.out, seed=args.seed, n_train=args.train, n_test=args.test,
                     width=args.size, height=args.size)
    print(f"wrote {args.kind} scene to {out}")
    return 0


def _cmd_data_check(args) -> int:
    from .data.check import check_dataset, format_summary

    print(format_summary(check_dataset(args.dir, downscale=args.downscale)))
    return 0


def _cmd_capture(args) -> int:
    require("capture", "`clrender capture`")
    from .capture import capture
    from .capture.output import format_report

    report = capture(args.src, args.out, max_frames=args.frames, matcher=args.matcher,
                     bounded=args.bounded, downscale=args.downscale, force=args.force,
                     threads=args.threads, mapper=args.mapper, focal=args.focal)
    if report.get("reused"):
        print(f"{args.out}: a finished capture with these options, kept as it is "
              "(--force redoes it)")
    print(format_report(report))
    print(f"wrote {args.out} (train with: clrender train {args.out} --out RUN"
          f"{f' --downscale {args.downscale}' if args.downscale else ''})")
    return 0


def _pixels(text: str) -> float:
    """An argparse type: a length in pixels > 0."""
    try:
        value = float(text)
    except ValueError:
        value = 0.0
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number of pixels > 0, got {text!r}")
    return value


def _add_downscale(parser, default, help_default: str) -> None:
    parser.add_argument("--downscale", type=cliopts.whole_number(), default=default,
                        metavar="N",
                        help="read the dataset's images_N/ (LLFF, Mip-NeRF 360, COLMAP, "
                             f"nerfstudio), else shrink its images N times ({help_default})")


def _model_downscale(args) -> int:
    """--downscale, else the one the model was trained at (its manifest), else 1."""
    from .bakedfile import trained_downscale

    return args.downscale if args.downscale is not None else trained_downscale(args.model)


def _cmd_train(args) -> int:
    require("train", "`clrender train`")
    spec = methods.get(args.method)
    preset = args.preset or spec.default_preset
    if preset not in spec.presets:
        raise ValueError(f"--preset {preset!r}: method {args.method!r} has presets "
                         f"{', '.join(spec.presets)}")
    options = cliopts.chosen(args, "train", args.method)
    check_options(options, spec.train_options, "training options", args.method)
    run = spec.train(args.data, args.out, preset, seed=args.seed, iterations=args.iterations,
                     torch_device=args.torch_device, downscale=args.downscale, **options)
    print(f"trained {args.method} run in {run}")
    return 0


def _cmd_bake(args) -> int:
    require("train", "`clrender bake`", modules=("torch",))
    spec = methods.of_run(args.run)
    path = spec.bake_run(args.run, args.out,
                         **cliopts.chosen(args, "bake", methods.name_of(spec)))
    print(f"wrote {path}")
    return 0


def _render_options(args) -> dict:
    """The render options given for the model's method (another method's is an error)."""
    from . import bakedfile

    spec = methods.for_format(bakedfile.peek_format(args.model), args.model)
    return cliopts.chosen(args, "render", methods.name_of(spec))


def _cmd_render(args) -> int:
    from .video import render_path

    if str(args.out).lower().endswith(".mp4"):
        require("video", "an .mp4 from `clrender render` (or: --out a .gif or a folder)")
    downscale = _model_downscale(args) if args.data else 1
    render_path(args.model, args.out, path=args.path, frames=args.frames, width=args.width,
                height=args.height, data=args.data, downscale=downscale, device=args.device,
                background=args.background, fps=args.fps, **_render_options(args))
    return 0


def _cmd_eval(args) -> int:
    require("eval", "`clrender eval`")
    from .evaluate import evaluate

    result = evaluate(args.model, args.data, device=args.device, split=args.split,
                      out_dir=args.save, downscale=_model_downscale(args),
                      **_render_options(args))
    print(json.dumps(result["mean"], indent=2))
    return 0


def _cmd_view(args) -> int:
    require("view", "`clrender view`")
    from .viewer import serve

    serve(args.model, data=args.data, host=args.host, port=args.port, device=args.device,
          max_size=args.max_size)
    return 0


def _cmd_export(args) -> int:
    if args.format == "glb":
        return _export_glb(args)
    glb_only = [f for f, v in (("--colours", args.colours), ("--threshold", args.threshold),
                               ("--extraction", args.extraction), ("--cameras", args.cameras))
                if v not in (None, False)]
    if glb_only:
        raise ValueError(f"{', '.join(glb_only)}: options of --format glb")
    from .export import export, serve

    out = export(args.model, args.out, data=args.data, downscale=args.downscale)
    print(f"wrote {out} (serve it: python -m http.server -d {out}, or --serve)")
    if args.serve:
        serve(out, host=args.host, port=args.port, block=True)
    return 0


def _export_glb(args) -> int:
    require("train", "`clrender export --format glb`",
            modules=("trimesh", "skimage", "fast_simplification", "embreex"))
    from .export.gltf import export_glb

    if args.serve:
        raise ValueError("--serve: a page's option (--format page)")
    if not str(args.out).lower().endswith(".glb"):
        raise ValueError(f"--out {args.out}: a .glb file is expected with --format glb")
    out = export_glb(args.model, args.out, data=args.data, downscale=args.downscale,
                     colours=args.colours or "renders", threshold=args.threshold,
                     extraction=args.extraction or "cpu", cameras=args.cameras)
    print(f"wrote {out} ({out.stat().st_size / 2**20:.1f} MiB)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="clrender", description=__doc__.split("\n\n")[0])
    p.add_argument("--version", action="version", version=f"clrender {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("info", help="list OpenCL platforms and devices")
    s.add_argument("--device", default=None, help="device spec to select (default $CLRENDER_DEVICE)")
    s.set_defaults(func=_cmd_info)

    s = sub.add_parser("scene", help="built-in scenes")
    ss = s.add_subparsers(dest="scene_command", required=True)
    m = ss.add_parser("make", help="render a built-in scene to a Blender-format folder")
    m.add_argument("kind", choices=["bounded", "unbounded"])
    m.add_argument("out")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--train", type=int, default=100, help="training views")
    m.add_argument("--test", type=int, default=20, help="test views")
    m.add_argument("--size", type=int, default=200, help="image width and height in pixels")
    m.set_defaults(func=_cmd_scene)

    s = sub.add_parser("data", help="dataset tools")
    ss = s.add_subparsers(dest="data_command", required=True)
    c = ss.add_parser("check", help="what the loader sees: format, splits, sizes, intrinsics, "
                                    "bounded/unbounded, camera spread (reads image headers)")
    c.add_argument("dir")
    _add_downscale(c, 1, "default 1")
    c.set_defaults(func=_cmd_data_check)

    s = sub.add_parser("capture", help="photos or a video -> a COLMAP dataset "
                                       "(pycolmap structure from motion)")
    s.add_argument("src", help="a folder of photos or a video file")
    s.add_argument("--out", required=True, help="dataset folder to write")
    s.add_argument("--frames", type=cliopts.whole_number(), default=200, metavar="N",
                   help="a video's frames to keep, the sharpest of each window (default 200)")
    s.add_argument("--matcher", default="auto", choices=["auto", "exhaustive", "sequential"],
                   help="auto: exhaustive for up to 300 photos, else sequential (video too)")
    s.add_argument("--mapper", default="auto", choices=["auto", "incremental", "global"],
                   help="incremental (COLMAP's, registers one image at a time) or global "
                        "(GLOMAP's: all rotations, then all positions; no drift round an "
                        "orbit); auto (default): incremental for an object on a transparent "
                        "background (its cameras then checked against the silhouettes), "
                        "else global (see docs/guides/capture.md)")
    s.add_argument("--focal", type=_pixels, default=None, metavar="PX",
                   help="the photos' focal length in pixels, if known: the mapping's prior "
                        "(default: EXIF, else 1.2 times the larger image side, refined)")
    s.add_argument("--bounded", action=argparse.BooleanOptionalAction, default=None,
                   help="an object capture, scaled into [-1, 1]^3 (default: when every "
                        "photo has a transparent background)")
    s.add_argument("--downscale", type=cliopts.whole_number(), default=None, metavar="N",
                   help="also write images_N/ (then train with --downscale N)")
    s.add_argument("--threads", type=cliopts.whole_number(), default=None,
                   help="CPU threads (default: all)")
    s.add_argument("--force", action="store_true", help="redo every stage")
    s.set_defaults(func=_cmd_capture)

    s = sub.add_parser("train", help="train a model (PyTorch)")
    s.add_argument("data", help="dataset folder: Blender transforms_*.json, nerfstudio "
                                "transforms.json, LLFF poses_bounds.npy or COLMAP sparse/0")
    _add_downscale(s, 1, "default 1; bake and eval reuse it")
    s.add_argument("--method", default=methods.default(), choices=methods.names())
    s.add_argument("--out", required=True, help="run folder (checkpoints, config, log)")
    s.add_argument("--preset", default=None, choices=methods.all_presets(),
                   help="the method's preset (default: its default_preset)")
    s.add_argument("--iterations", type=int, default=None, help="override the preset's count")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--torch-device", default=None, help="torch device (default cuda if present)")
    cliopts.add_groups(s, "train")
    s.set_defaults(func=_cmd_train)

    s = sub.add_parser("bake", help="bake a trained run (any method) into a model file")
    s.add_argument("run")
    s.add_argument("--out", required=True)
    cliopts.add_groups(s, "bake")
    s.set_defaults(func=_cmd_bake)

    s = sub.add_parser("render", help="render a baked model along a camera path")
    s.add_argument("model")
    s.add_argument("--path", default="orbit", choices=PATHS)
    s.add_argument("--frames", type=int, default=60)
    s.add_argument("--out", required=True, help="a .mp4/.gif file or a folder for PNGs")
    s.add_argument("--width", type=int, default=400)
    s.add_argument("--height", type=int, default=400)
    s.add_argument("--data", default=None, help="dataset whose cameras define spiral/test paths")
    _add_downscale(s, None, "of --data; default: the model's training downscale")
    s.add_argument("--background", type=float, nargs=3, default=None,
                   help="RGB in [0, 1] (default: the method's, NGP-RT white)")
    s.add_argument("--fps", type=int, default=30)
    s.add_argument("--device", default=None)
    cliopts.add_groups(s, "render")
    s.set_defaults(func=_cmd_render)

    s = sub.add_parser("eval", help="PSNR/SSIM and ms/frame of a baked model on test views")
    s.add_argument("model")
    s.add_argument("data")
    s.add_argument("--split", default="test")
    _add_downscale(s, None, "default: the model's training downscale")
    s.add_argument("--save", default=None, help="folder for the rendered test views")
    s.add_argument("--device", default=None)
    cliopts.add_groups(s, "render")
    s.set_defaults(func=_cmd_eval)

    s = sub.add_parser("view", help="live browser viewer of a baked model (viser)")
    s.add_argument("model")
    s.add_argument("--data", default=None, help="dataset whose training cameras are drawn")
    s.add_argument("--host", default="127.0.0.1", help="address to listen on (default local only)")
    s.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"port (default {DEFAULT_PORT}; the next free one if taken)")
    s.add_argument("--max-size", type=int, default=800, help="long side of a resting frame, px")
    s.add_argument("--device", default=None)
    s.set_defaults(func=_cmd_view)

    s = sub.add_parser("export", help="a static WebGL2 page of a baked model, or its coloured "
                                      "mesh as glTF (--format glb)")
    s.add_argument("model")
    s.add_argument("--format", default="page", choices=["page", "glb"],
                   help="page: a WebGL2 page (default); glb: coloured meshes, glTF 2.0 binary")
    s.add_argument("--out", required=True, help="a new folder for the page, or a .glb file")
    s.add_argument("--data", default=None, help="dataset whose test cameras the page lists "
                                                "(glb: whose training views colour the mesh)")
    _add_downscale(s, None, "of --data; default: the model's training downscale")
    s.add_argument("--colours", default=None, choices=["renders", "images"],
                   help="glb: fit the vertex colours to the model's renders (default) or to "
                        "the training images of --data")
    s.add_argument("--threshold", type=float, default=None, metavar="ALPHA",
                   help="glb of an NGP-RT model: the surface's alpha level (default 0.3)")
    s.add_argument("--extraction", default=None, choices=["tiny", "cpu", "paper"],
                   help="glb of an NGP-RT model: the extraction's size (density grid 64, 256, "
                        "512 a side; default cpu)")
    s.add_argument("--cameras", action="store_true",
                   help="glb: also write the test cameras of --data as glTF cameras")
    s.add_argument("--serve", action="store_true", help="then serve it over HTTP")
    s.add_argument("--host", default="127.0.0.1", help="address to serve on (default local only)")
    s.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"port to serve on (default {DEFAULT_PORT}; 0: a free one)")
    s.set_defaults(func=_cmd_export)

    for name in methods.names():
        if methods.get(name).add_commands is not None:
            methods.get(name).add_commands(sub)
    return p


def main(argv=None) -> int:
    try:
        parser = build_parser()
    except methods.PluginError as exc:            # a plug-in that breaks every command
        print(f"clrender: error: {exc}", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ModuleNotFoundError as exc:               # an extra's package, else a broken install
        extra = missing(exc, f"`clrender {args.command}`")
        if extra is None:
            raise
        return _error(args.command, extra)
    except USER_ERRORS as exc:
        return _error(args.command, exc)


# What a user's input can raise (a bad file, folder, option, device or plug-in): reported
# in one line. Anything else is a defect and keeps its traceback.
USER_ERRORS = (ValueError, OSError, DeviceError, methods.PluginError)


def one_line_error(prog: str, exc: Exception) -> int:
    """Print ``PROG: error: ...`` (the message on one line) on stderr; returns 2, the exit
    status."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    print(f"{prog}: error: {text}", file=sys.stderr)
    return 2


def _error(command: str, exc: Exception) -> int:
    return one_line_error(f"clrender {command}", exc)


if __name__ == "__main__":
    sys.exit(main())
