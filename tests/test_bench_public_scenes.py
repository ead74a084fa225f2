"""bench.tools.public_scenes on fake clones laid out like the public repositories: the folders it
writes are read by clrender's loaders with the stated splits, and bad clones are refused
without leaving a folder behind."""
import json
import shutil

import numpy as np
import pytest

from bench.tools import public_scenes
from clrender.data.check import check_dataset
from dataset_fixtures import write_blender, write_llff


def fake_bonsai(tmp_path):
    """Bonsaidownload (252 frames at the root, 40 under input/) and sfm-ooi-extract."""
    llff = tmp_path / "llff"
    llff.mkdir()
    write_llff(llff, n=public_scenes.BONSAI_FRAMES, ext=".JPG")
    images, poses = tmp_path / "Bonsaidownload", tmp_path / "sfm-ooi-extract"
    (images / "input").mkdir(parents=True)
    for i, f in enumerate(sorted((llff / "images").iterdir())):
        shutil.copyfile(f, images / ("input" if i % 7 == 3 and i < 280 else ".")
                        / f"DSCF{5605 + i}.JPG")
    (poses / "data" / "bonsai").mkdir(parents=True)
    shutil.copyfile(llff / "poses_bounds.npy", poses / "data" / "bonsai" / "poses_bounds.npy")
    return images, poses


def test_bonsai_folder_is_an_llff_scene_with_every_8th_view_held_out(tmp_path):
    images, poses = fake_bonsai(tmp_path)
    assert len(list((images / "input").iterdir())) == 40
    out = tmp_path / "data" / "bonsai"
    assert public_scenes.main(["bonsai", str(images), str(poses), str(out)]) == 0
    summary = check_dataset(out)
    assert (summary["format"], summary["scene"]) == ("llff", "unbounded")
    assert summary["splits"]["train"]["views"] == 255
    assert summary["splits"]["test"]["views"] == 37
    files = sorted(p.name for p in (out / "images").iterdir())
    assert files == [f"DSCF{5605 + i}.JPG" for i in range(public_scenes.BONSAI_FRAMES)]


def fake_lego(tmp_path) -> dict:
    """shouxieai/nerf's lego under ``tmp_path/nerf``; returns its train transforms."""
    root = tmp_path / "nerf" / "data" / "nerf_synthetic" / "lego"
    root.mkdir(parents=True)
    write_blender(root, n=public_scenes.LEGO_FRAMES)
    meta = json.loads((root / "transforms_train.json").read_text())
    for f in meta["frames"]:  # the public copy's paths have no extension
        f["file_path"] = f["file_path"].removesuffix(".png")
    (root / "transforms_train.json").write_text(json.dumps(meta))
    return meta


def test_lego_folder_holds_out_every_8th_train_frame(tmp_path):
    meta = fake_lego(tmp_path)
    out = tmp_path / "lego"
    assert public_scenes.main(["lego", str(tmp_path / "nerf"), str(out)]) == 0
    summary = check_dataset(out)
    assert summary["format"] == "blender"
    assert summary["splits"]["train"]["views"] == 87
    assert summary["splits"]["test"]["views"] == 13
    test = json.loads((out / "transforms_test.json").read_text())["frames"]
    assert [f["file_path"] for f in test] == [meta["frames"][i]["file_path"]
                                              for i in range(0, 100, 8)]


def test_a_partial_clone_is_refused_and_leaves_nothing(tmp_path, capsys):
    images, poses = fake_bonsai(tmp_path)
    next((images / "input").iterdir()).unlink()
    out = tmp_path / "data" / "bonsai"
    assert public_scenes.main(["bonsai", str(images), str(poses), str(out)]) == 2
    assert "expected 292" in capsys.readouterr().err
    assert list((tmp_path / "data").iterdir()) == []


def test_an_existing_output_folder_is_not_overwritten(tmp_path):
    out = tmp_path / "lego"
    out.mkdir()
    with pytest.raises(ValueError, match="already exists"):
        public_scenes.build(out, lambda d: None)
    assert not any(out.iterdir())


def test_an_assembled_folder_is_known_by_its_cameras_and_others_are_not(tmp_path, monkeypatch):
    images, poses = fake_bonsai(tmp_path)
    bonsai = tmp_path / "data" / "bonsai"
    assert public_scenes.main(["bonsai", str(images), str(poses), str(bonsai)]) == 0
    assert public_scenes.identify(bonsai) is None        # the fake's cameras are not bonsai's
    hwf = np.load(bonsai / "poses_bounds.npy")[0, :15].reshape(3, 5)[:, 4]
    monkeypatch.setattr(public_scenes, "BONSAI_HWF", tuple(hwf))
    assert public_scenes.identify(bonsai) == "bonsai"
    assert public_scenes.identify(tmp_path) is None
    (tmp_path / "blender").mkdir()
    write_blender(tmp_path / "blender", n=public_scenes.LEGO_FRAMES)
    assert public_scenes.identify(tmp_path / "blender") is None      # 100 train frames
    assert public_scenes.commands("lego", "data/lego") == [
        "git clone https://github.com/shouxieai/nerf",
        "python -m bench.tools.public_scenes lego nerf data/lego"]


def test_the_lego_folder_is_known_by_its_field_of_view_and_split(tmp_path, monkeypatch):
    fake_lego(tmp_path)
    out = tmp_path / "lego"
    assert public_scenes.main(["lego", str(tmp_path / "nerf"), str(out)]) == 0
    fov = json.loads((out / "transforms_test.json").read_text())["camera_angle_x"]
    assert public_scenes.identify(out) == ("lego" if fov == public_scenes.LEGO_FOV else None)
    monkeypatch.setattr(public_scenes, "LEGO_FOV", fov)
    assert public_scenes.identify(out) == "lego"
