"""Assemble dataset folders from local clones of public GitHub copies of two real scenes.

    git clone https://github.com/EricXu23/Bonsaidownload
    git clone https://github.com/FunnyPocketBook/sfm-ooi-extract
    python -m bench.tools.public_scenes bonsai Bonsaidownload sfm-ooi-extract data/bonsai
    python -m bench.run table4 --scene data/bonsai --downscale 2     # 400x266, 255 / 37 views

    git clone https://github.com/shouxieai/nerf
    python -m bench.tools.public_scenes lego nerf data/lego              # 800x800, 87 / 13 views

- **bonsai** (Mip-NeRF 360, the scene of NGP-RT's S4 and Table S1), an LLFF folder: the
  292 frames at 800x533 (JPEG, re-encoded by a third party) of ``EricXu23/Bonsaidownload``
  (252 at its root, 40 under ``input/``; its partial ``images/`` and ``sparse/`` are not
  used), sorted by name into ``images/``, and ``data/bonsai/poses_bounds.npy`` of
  ``FunnyPocketBook/sfm-ooi-extract`` (292 rows, hwf 2078 x 3118, focal 3222.7; its near /
  far columns are placeholders, 0.1 / 500, which clrender does not read). The LLFF loader
  holds out every 8th view for testing (37).
- **lego** (NeRF-synthetic), a Blender folder: the 100 frames of the train split in
  ``shouxieai/nerf`` (``data/nerf_synthetic/lego``; the copy has no test split), every 8th
  (13) written to ``transforms_test.json``, the other 87 to ``transforms_train.json``.

Licences: Mip-NeRF 360 and NeRF-synthetic are research datasets released by their
authors; these repositories are third-party copies (shouxieai/nerf says MIT for its code,
the others state none), so use the folders for research measurements only, and cite the
original datasets. Nothing in the tests depends on them. Sources, conditions and the
results on them: docs/guides/public-scenes.md.

Files are copied, never linked; the folder is built beside ``out`` and renamed into place,
so a failure leaves no half-written dataset.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from clrender.atomic import atomic_folder
from clrender.data.llff import split_indices

BONSAI_FRAMES = 292
LEGO_FRAMES = 100
BONSAI_HWF = (2078.0, 3118.0, 3222.7)      # poses_bounds.npy's height, width, focal (px)
LEGO_FOV = 0.6911112070083618              # transforms_*.json's camera_angle_x (rad)
SOURCES = {"bonsai": ("https://github.com/EricXu23/Bonsaidownload",
                      "https://github.com/FunnyPocketBook/sfm-ooi-extract"),
           "lego": ("https://github.com/shouxieai/nerf",)}


def commands(name: str, out: str) -> list[str]:
    """The lines that assemble the public scene ``name`` into the folder ``out``: its
    clones, then this module."""
    repos = [url.rsplit("/", 1)[1] for url in SOURCES[name]]
    return ([f"git clone {url}" for url in SOURCES[name]]
            + [f"python -m bench.tools.public_scenes {name} {' '.join(repos)} {out}"])


def identify(folder: Path) -> str | None:
    """The public scene a dataset folder holds, as :func:`main` writes it ("bonsai",
    "lego"), by its cameras and frame counts; None for any other folder."""
    folder = Path(folder)
    poses = folder / "poses_bounds.npy"
    if poses.is_file():
        p = np.load(poses, allow_pickle=False)
        if p.shape == (BONSAI_FRAMES, 17) and np.allclose(
                p[0, :15].reshape(3, 5)[:, 4], BONSAI_HWF, atol=0.1):
            return "bonsai"
        return None
    counts, fovs = {}, set()
    for split in ("train", "test"):
        file = folder / f"transforms_{split}.json"
        if not file.is_file():
            return None
        meta = json.loads(file.read_text())
        counts[split], fovs = len(meta.get("frames", [])), fovs | {meta.get("camera_angle_x")}
    lego = split_indices(LEGO_FRAMES, "train"), split_indices(LEGO_FRAMES, "test")
    return "lego" if (counts == {"train": len(lego[0]), "test": len(lego[1])}
                      and fovs == {LEGO_FOV}) else None


def bonsai_images(repo: Path) -> list[Path]:
    """The 292 frames of a Bonsaidownload clone (root and ``input/``), sorted by name."""
    files = sorted([*repo.glob("DSCF*.JPG"), *(repo / "input").glob("DSCF*.JPG")],
                   key=lambda p: p.name)
    names = [p.name for p in files]
    if len(files) != BONSAI_FRAMES or len(set(names)) != len(names):
        raise ValueError(f"{repo}: expected {BONSAI_FRAMES} distinct DSCF*.JPG frames at its "
                         f"root and under input/, found {len(files)} ({len(set(names))} "
                         f"distinct); is it a full clone of EricXu23/Bonsaidownload?")
    return files


def bonsai_poses(repo: Path) -> Path:
    """``poses_bounds.npy`` of a sfm-ooi-extract clone, checked to hold 292 rows."""
    file = repo / "data" / "bonsai" / "poses_bounds.npy"
    if not file.is_file():
        raise ValueError(f"{file}: not found; is {repo} a clone of "
                         f"FunnyPocketBook/sfm-ooi-extract?")
    poses = np.load(file, allow_pickle=False)
    if poses.shape != (BONSAI_FRAMES, 17):
        raise ValueError(f"{file}: expected shape ({BONSAI_FRAMES}, 17), got {poses.shape}")
    return file


def assemble_bonsai(images_repo: Path, poses_repo: Path, folder: Path) -> None:
    """Write the LLFF folder (``images/``, ``poses_bounds.npy``) into ``folder``."""
    files, poses = bonsai_images(images_repo), bonsai_poses(poses_repo)
    (folder / "images").mkdir(parents=True)
    for f in files:
        shutil.copyfile(f, folder / "images" / f.name)
    shutil.copyfile(poses, folder / "poses_bounds.npy")


def assemble_lego(repo: Path, folder: Path) -> None:
    """Write the Blender folder (87 train / 13 test frames) into ``folder``."""
    root = repo / "data" / "nerf_synthetic" / "lego"
    file = root / "transforms_train.json"
    if not file.is_file():
        raise ValueError(f"{file}: not found; is {repo} a clone of shouxieai/nerf?")
    meta = json.loads(file.read_text())
    frames = meta.get("frames", [])
    if len(frames) != LEGO_FRAMES:
        raise ValueError(f"{file}: expected {LEGO_FRAMES} frames, found {len(frames)}")
    (folder / "train").mkdir(parents=True)
    for frame in frames:
        name = Path(frame["file_path"]).name + ".png"
        shutil.copyfile(root / "train" / name, folder / "train" / name)
    for split in ("train", "test"):   # held out as the LLFF loader does: every 8th
        chosen = [frames[i] for i in split_indices(len(frames), split)]
        (folder / f"transforms_{split}.json").write_text(
            json.dumps({**meta, "frames": chosen}, indent=1))


def build(out: Path, write) -> Path:
    """Run ``write(folder)`` on a temporary folder beside ``out``, then rename it to ``out``."""
    if out.exists():
        raise ValueError(f"{out}: already exists; remove it or choose another folder")
    return atomic_folder(out, write)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.tools.public_scenes", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="scene", required=True)
    b = sub.add_parser("bonsai", help="Mip-NeRF 360 bonsai as an LLFF folder")
    b.add_argument("images_repo", type=Path, help="clone of EricXu23/Bonsaidownload")
    b.add_argument("poses_repo", type=Path, help="clone of FunnyPocketBook/sfm-ooi-extract")
    b.add_argument("out", type=Path)
    lego = sub.add_parser("lego", help="NeRF-synthetic lego (train split) as a Blender folder")
    lego.add_argument("repo", type=Path, help="clone of shouxieai/nerf")
    lego.add_argument("out", type=Path)
    args = p.parse_args(argv)
    try:
        if args.scene == "bonsai":
            build(args.out, lambda d: assemble_bonsai(args.images_repo, args.poses_repo, d))
        else:
            build(args.out, lambda d: assemble_lego(args.repo, d))
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}; check it with: clrender data check {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
