"""Bad input, for every loader (Blender, nerfstudio transforms.json, LLFF, COLMAP): each is
refused with a message naming the file and the problem. (``clrender train`` writing nothing
on these: tests/test_data_cli.py.)"""
import json

import numpy as np
import pytest
from dataset_fixtures import (H, W, edit_json, write_blender, write_colmap, write_images,
                              write_llff, write_transforms)

from clrender.data import load_dataset

LOADERS = ("blender", "transforms", "llff", "colmap")
NON_RIGID = np.diag([2.0, 1.0, 1.0, 1.0])   # a scaled axis


def write(loader, root, ext=".png"):
    {"blender": write_blender, "transforms": write_transforms, "llff": write_llff,
     "colmap": write_colmap}[loader](root, ext=ext)


def train_image(loader, root, ext=".png"):
    """The file of a train-split image (frame / image 1)."""
    return {"blender": root / "train" / f"r_1{ext}",
            "transforms": root / "images" / f"frame_00001{ext}",
            "llff": root / "images" / f"IMG_0001{ext}",
            "colmap": root / "images" / f"IMG_0001{ext}"}[loader]


def set_pose(loader, root, change):
    """Replace the pose ``m`` (4, 4) of frame / image 1 by ``change(m)``: camera-to-world
    (LLFF: its [down, right, back, position] columns; COLMAP: world-to-camera, translation)."""
    if loader in ("blender", "transforms"):
        file = root / ("transforms_train.json" if loader == "blender" else "transforms.json")
        edit_json(file, lambda meta: meta["frames"][1].update(
            transform_matrix=change(np.array(meta["frames"][1]["transform_matrix"])).tolist()))
    elif loader == "llff":
        rows = np.load(root / "poses_bounds.npy")
        m = np.eye(4)
        m[:3, :4] = rows[1, :15].reshape(3, 5)[:, :4]
        rows[1, :15] = np.concatenate([change(m)[:3, :4], rows[1, :15].reshape(3, 5)[:, 4:]],
                                      1).reshape(-1)
        np.save(root / "poses_bounds.npy", rows)
    else:  # COLMAP: the pose of image 2's frame (trivial rig), world-to-camera; translation
        import pycolmap

        rec = pycolmap.Reconstruction(str(root / "sparse" / "0"))
        frame = rec.frames[rec.images[2].frame_id]
        m = np.eye(4)
        m[:3, :4] = frame.rig_from_world.matrix()
        frame.rig_from_world = pycolmap.Rigid3d(frame.rig_from_world.rotation, change(m)[:3, 3])
        rec.write_binary(str(root / "sparse" / "0"))


@pytest.mark.parametrize("loader", LOADERS)
def test_missing_image(tmp_path, loader):
    write(loader, tmp_path)
    train_image(loader, tmp_path).unlink()
    message = {"llff": r"images: found 9 images, but .*poses_bounds\.npy has 10 poses",
               "colmap": r"IMG_0001\.png: image file not found \(1 of the 10 images"}.get(
        loader, r"1\.png: image file not found")
    with pytest.raises((FileNotFoundError, ValueError), match=message):
        load_dataset(tmp_path)


@pytest.mark.parametrize("loader", LOADERS)
def test_image_count_differs_from_pose_count(tmp_path, loader):
    write(loader, tmp_path)
    if loader == "blender":  # one pose per frame: a frame without one
        edit_json(tmp_path / "transforms_train.json",
                  lambda m: m["frames"][1].pop("transform_matrix"))
        message = r"transforms_train\.json: frame 1 has no 'transform_matrix'"
    elif loader == "transforms":  # a split list naming an image no frame has
        edit_json(tmp_path / "transforms.json",
                  lambda m: m.update(train_filenames=["images/frame_00001.png", "images/x.png"]))
        message = r"transforms\.json: train_filenames names 1 file\(s\) no frame has, e.g. " \
                  r"'images/x\.png'"
    else:  # an image without a pose
        write_images(tmp_path / "images", np.zeros((1, H, W, 3), np.uint8), ["IMG_0010.png"])
        message = r"images: found 11 images, but .*10 poses" if loader == "llff" else \
            r"images: 11 images, but .*sparse/0 has poses for 10; without a pose: IMG_0010\.png"
    with pytest.raises(ValueError, match=message):
        load_dataset(tmp_path)


@pytest.mark.parametrize("loader", LOADERS)
@pytest.mark.parametrize("bad", ["nan", "non-rigid"])
def test_bad_pose(tmp_path, loader, bad):
    write(loader, tmp_path)
    if bad == "nan":
        set_pose(loader, tmp_path, lambda m: m + np.array([[0, 0, 0, np.nan]] + [[0] * 4] * 3))
    elif loader == "colmap":  # a non-unit quaternion (COLMAP stores unit ones)
        folder = tmp_path / "sparse" / "0"
        import pycolmap

        rec = pycolmap.Reconstruction(str(folder))
        rec.write_text(str(folder))
        for f in [*folder.glob("*.bin"), folder / "rigs.txt", folder / "frames.txt"]:
            f.unlink()  # the format before rigs: poses in images.txt (as Mip-NeRF 360's)
        lines = (folder / "images.txt").read_text().splitlines()
        i = next(k for k, line in enumerate(lines) if line.startswith("2 "))
        fields = lines[i].split()
        lines[i] = " ".join(fields[:1] + ["1", "1", "0", "0"] + fields[5:])  # |q| = sqrt 2
        (folder / "images.txt").write_text("\n".join(lines) + "\n")
    else:
        set_pose(loader, tmp_path, lambda m: m @ NON_RIGID)
    where = {"blender": r"frame 1", "transforms": r"frame 1", "llff": r"pose 1 \(IMG_0001",
             "colmap": r"image 'IMG_0001\.png'"}[loader]
    problem = {"nan": r"(non-finite|finite numbers)", "non-rigid": r"not rigid"}[bad]
    message = r"poses_bounds\.npy: poses_bounds must hold finite numbers" \
        if (loader, bad) == ("llff", "nan") else rf"{where}.*{problem}"
    with pytest.raises(ValueError, match=message):
        load_dataset(tmp_path)


@pytest.mark.parametrize("loader", LOADERS)
def test_mixed_image_sizes(tmp_path, loader):
    write(loader, tmp_path)
    file = train_image(loader, tmp_path)
    write_images(file.parent, np.zeros((1, H - 2, W, 3), np.uint8), [file.name])
    message = rf"{file.name}: image is {W}x{H - 2}, but " + {
        "colmap": rf"COLMAP camera 1 is {W}x{H}",
        "transforms": rf"w, h of transforms\.json say {W}x{H}"}.get(
        loader, rf"\d of the \d images of split 'train' are {W}x{H}")
    with pytest.raises(ValueError, match=message):
        load_dataset(tmp_path)


@pytest.mark.parametrize("loader", LOADERS)
@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_truncated_image(tmp_path, loader, ext):
    write(loader, tmp_path, ext)
    file = train_image(loader, tmp_path, ext)
    data = file.read_bytes()
    file.write_bytes(data[:len(data) * 3 // 4])
    with pytest.raises(ValueError, match=rf"{file.name}: (cannot read image|not a readable "
                                         r"image) \(.*truncated"):
        load_dataset(tmp_path)


@pytest.mark.parametrize("loader", LOADERS)
def test_non_image_file(tmp_path, loader):
    write(loader, tmp_path)
    file = train_image(loader, tmp_path)
    file.write_text("not an image")
    with pytest.raises(ValueError, match=rf"{file.name}: not a readable image"):
        load_dataset(tmp_path)


@pytest.mark.parametrize("loader", ["llff", "colmap"])
def test_other_files_in_the_image_folder_are_not_images(tmp_path, loader):
    write(loader, tmp_path)
    (tmp_path / "images" / "notes.txt").write_text("taken at noon")
    (tmp_path / "images" / ".DS_Store").write_bytes(b"\0\1")
    assert len(load_dataset(tmp_path).cameras) == 8


@pytest.mark.parametrize("loader", LOADERS)
def test_empty_split(tmp_path, loader):
    if loader == "blender":
        write_blender(tmp_path)
        (tmp_path / "transforms_test.json").write_text(json.dumps({"camera_angle_x": 0.69,
                                                                   "frames": []}))
        split, message = "test", r"transforms_test\.json: missing or empty 'frames' list"
    elif loader == "transforms":
        write_transforms(tmp_path)
        edit_json(tmp_path / "transforms.json",
                  lambda m: m.update(train_filenames=["images/frame_00001.png"],
                                     test_filenames=[]))
        split, message = "test", r"transforms\.json: test_filenames is empty, split 'test'"
    else:  # one image: all of it is the test split
        write_llff(tmp_path, n=1) if loader == "llff" else write_colmap(tmp_path, n=1)
        split, message = "train", r"images: split 'train' has no images"
    with pytest.raises(ValueError, match=message):
        load_dataset(tmp_path, split)
