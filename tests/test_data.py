"""Dataset loaders: Blender / NeRF-synthetic and LLFF / Mip-NeRF 360, on tiny fixtures."""
import json

import imageio.v3 as iio
import numpy as np
import pytest

from clrender.camera import look_at
from clrender.data import load_blender, load_dataset, load_llff

SIZE = 24
ANGLE = 0.69


# -- Blender fixtures --------------------------------------------------------------------------

def write_blender(root, n=4, split="train", extra=None, frame_extra=None, ext=""):
    """n RGBA images (SIZE x SIZE) + transforms_{split}.json; returns (rgba uint8, c2ws)."""
    rng = np.random.default_rng(1)
    (root / split).mkdir(parents=True, exist_ok=True)
    rgba = rng.integers(0, 256, (n, SIZE, SIZE, 4), dtype=np.uint8)
    rgba[:, :4, :, 3] = 0
    rgba[:, -4:, :, 3] = 255
    c2ws = [look_at(4.0 * np.array([np.cos(a), np.sin(a), 0.5])) for a in np.arange(n)]
    frames = []
    for i in range(n):
        iio.imwrite(root / split / f"r_{i}.png", rgba[i])
        frames.append({"file_path": f"./{split}/r_{i}{ext}", "transform_matrix": c2ws[i].tolist(),
                       **(frame_extra or {})})
    meta = {"camera_angle_x": ANGLE, "frames": frames, **(extra or {})}
    (root / f"transforms_{split}.json").write_text(json.dumps(meta))
    return rgba, np.stack(c2ws)


def test_blender_round_trip(tmp_path):
    rgba, c2ws = write_blender(tmp_path)
    for bg in ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0)):
        ds = load_dataset(tmp_path, "train", background=bg)
        a = rgba[..., 3:] / 255.0
        expect = rgba[..., :3] / 255.0 * a + np.asarray(bg) * (1 - a)
        assert ds.images.shape == (4, SIZE, SIZE, 3) and ds.images.dtype == np.float32
        np.testing.assert_allclose(ds.images, expect, atol=1e-6)
        np.testing.assert_allclose(ds.alpha, a[..., 0], atol=1e-6)
    assert ds.scene == "bounded" and ds.split == "train"
    cam = ds.cameras[1]
    assert cam.width == SIZE and cam.fx == pytest.approx(0.5 * SIZE / np.tan(0.5 * ANGLE))
    assert (cam.cx, cam.cy) == (SIZE / 2, SIZE / 2)
    # NeRF-synthetic default: bounded, translations scaled by 2/3, rotations unchanged.
    np.testing.assert_allclose(cam.c2w[:3, 3], c2ws[1, :3, 3] * 2 / 3)
    np.testing.assert_allclose(cam.c2w[:3, :3], c2ws[1, :3, :3])


def test_blender_clrender_key_and_instant_ngp_intrinsics(tmp_path):
    extra = {"clrender": {"scene": "unbounded", "scale": 0.5}, "fl_x": 30.0, "fl_y": 31.0,
             "cx": 11.0, "cy": 13.0, "w": SIZE, "h": SIZE}
    _, c2ws = write_blender(tmp_path, extra=extra, ext=".png")
    ds = load_blender(tmp_path, "train")
    cam = ds.cameras[0]
    assert ds.scene == "unbounded"
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (30.0, 31.0, 11.0, 13.0)
    np.testing.assert_allclose(cam.c2w[:3, 3], c2ws[0, :3, 3] * 0.5)


def test_blender_downscale_area_average(tmp_path):
    rgba, _ = write_blender(tmp_path)
    full = load_blender(tmp_path, "train", background=(0.2, 0.4, 0.6))
    half = load_blender(tmp_path, "train", downscale=2, background=(0.2, 0.4, 0.6))
    assert half.images.shape == (4, SIZE // 2, SIZE // 2, 3)
    block = full.images.reshape(4, SIZE // 2, 2, SIZE // 2, 2, 3).mean((2, 4))
    np.testing.assert_allclose(half.images, block, atol=1e-6)
    c, h = full.cameras[0], half.cameras[0]
    assert (h.width, h.fx, h.cx) == (SIZE // 2, pytest.approx(c.fx / 2), pytest.approx(c.cx / 2))


def test_blender_missing_image(tmp_path):
    write_blender(tmp_path)
    (tmp_path / "train" / "r_2.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"r_2\.png: image file not found"):
        load_dataset(tmp_path)


def test_blender_malformed_json(tmp_path):
    write_blender(tmp_path)
    (tmp_path / "transforms_train.json").write_text('{"frames": [')
    with pytest.raises(ValueError, match=r"transforms_train\.json: malformed JSON"):
        load_dataset(tmp_path)


@pytest.mark.parametrize("bad, message", [
    ({"transform_matrix": np.eye(3).tolist()},
     r"transforms_train\.json: frame \d transform_matrix has shape \(3, 3\), expected \(4, 4\)"),
    ({"transform_matrix": [[1, 0], [0]]},
     r"transforms_train\.json: frame \d transform_matrix is not numeric"),
])
def test_blender_wrong_pose(tmp_path, bad, message):
    write_blender(tmp_path, frame_extra=bad)
    with pytest.raises(ValueError, match=message):
        load_dataset(tmp_path)


def test_blender_missing_keys(tmp_path):
    write_blender(tmp_path)
    file = tmp_path / "transforms_train.json"
    meta = json.loads(file.read_text())
    del meta["camera_angle_x"]
    file.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"transforms_train\.json: frame 0 has no focal length"):
        load_dataset(tmp_path)
    del meta["frames"][1]["transform_matrix"]
    file.write_text(json.dumps({**meta, "camera_angle_x": ANGLE}))
    with pytest.raises(ValueError, match=r"transforms_train\.json: frame 1 has no 'transform_m"):
        load_dataset(tmp_path)
    file.write_text(json.dumps({"camera_angle_x": ANGLE}))
    with pytest.raises(ValueError, match=r"transforms_train\.json: missing or empty 'frames'"):
        load_dataset(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"transforms_test\.json: transforms file not"):
        load_dataset(tmp_path, "test")


def test_unknown_format(tmp_path):
    with pytest.raises(ValueError, match="unknown dataset format"):
        load_dataset(tmp_path)


# -- LLFF fixtures -----------------------------------------------------------------------------

H, W = 24, 32
CENTRE = np.array([1.0, 2.0, 3.0])


def write_llff(root, n=10, folder="images", seed=2):
    """360° capture: n cameras on a tilted ring around CENTRE looking at it; returns images."""
    rng = np.random.default_rng(seed)
    tilt = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    a, b = np.cross(tilt, [1.0, 0, 0]), None
    a /= np.linalg.norm(a)
    b = np.cross(tilt, a)
    rows = []
    for i in range(n):
        ang = 2 * np.pi * i / n
        eye = CENTRE + 2.5 * (np.cos(ang) * a + np.sin(ang) * b) + 0.3 * tilt
        c2w = look_at(eye, CENTRE, up=tilt)
        llff = np.stack([-c2w[:3, 1], c2w[:3, 0], c2w[:3, 2], c2w[:3, 3],
                         [2 * H, 2 * W, 40.0]], axis=1)  # hwf of 2x larger originals
        rows.append(np.concatenate([llff.reshape(-1), [0.5, 10.0]]))
    np.save(root / "poses_bounds.npy", np.array(rows))
    images = rng.integers(0, 256, (n, H, W, 3), dtype=np.uint8)
    write_images(root / folder, images)
    return images


def write_images(folder, images):
    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(images):
        iio.imwrite(folder / f"IMG_{i:04d}.png", img)


def test_llff_round_trip_and_conventions(tmp_path):
    images = write_llff(tmp_path)
    train, test = load_dataset(tmp_path, "train"), load_llff(tmp_path, "test")
    assert len(train.cameras) == 8 and len(test.cameras) == 2  # i % 8 == 0 -> test
    np.testing.assert_allclose(test.images, images[[0, 8]] / 255.0, atol=1e-6)
    np.testing.assert_allclose(train.images[0], images[1] / 255.0, atol=1e-6)
    assert train.scene == "unbounded" and train.alpha is None
    cam = train.cameras[0]
    assert (cam.width, cam.height, cam.cx, cam.cy) == (W, H, W / 2, H / 2)
    assert cam.fx == pytest.approx(40.0 / 2) and cam.fy == pytest.approx(40.0 / 2)
    cams = train.cameras + test.cameras
    pos = np.stack([c.origin for c in cams])
    assert np.linalg.norm(pos, axis=1).max() == pytest.approx(1.0)
    for c in cams:
        forward, to_centre = -c.c2w[:3, 2], -c.origin / np.linalg.norm(c.origin)
        assert forward @ to_centre == pytest.approx(1.0, abs=1e-6)  # looks at the scene centre
        assert c.c2w[2, 1] > 0.9  # camera up ~ world +z
        np.testing.assert_allclose(c.c2w[:3, :3].T @ c.c2w[:3, :3], np.eye(3), atol=1e-9)


def test_llff_forward_facing_recentred(tmp_path):
    rng = np.random.default_rng(3)
    rows = []
    for _ in range(9):
        c2w = look_at(rng.normal(0, 0.2, 3) + [5.0, 0, 0], [5.0, 0, -10.0], up=[0, 1.0, 0])
        llff = np.stack([-c2w[:3, 1], c2w[:3, 0], c2w[:3, 2], c2w[:3, 3], [H, W, 30.0]], 1)
        rows.append(np.concatenate([llff.reshape(-1), [1.0, 20.0]]))
    np.save(tmp_path / "poses_bounds.npy", np.array(rows))
    write_images(tmp_path / "images", np.zeros((9, H, W, 3), np.uint8))
    c2w = np.stack([c.c2w for c in load_llff(tmp_path, "train").cameras])
    assert np.all(c2w[:, 2, 2] > 0.99)  # all look down -z of the average pose
    assert np.linalg.norm(c2w[:, :3, 3], axis=1).max() <= 1.0 + 1e-9


def test_llff_downscale_folders(tmp_path):
    images = write_llff(tmp_path)
    small = np.full((10, H // 2, W // 2, 3), 7, np.uint8)
    ds = load_llff(tmp_path, "test", downscale=2)  # no images_2: shrink images/
    block = (images[[0, 8]] / 255.0).reshape(2, H // 2, 2, W // 2, 2, 3).mean((2, 4))
    np.testing.assert_allclose(ds.images, block, atol=1e-6)
    assert ds.cameras[0].fx == pytest.approx(40.0 / 4) and ds.cameras[0].width == W // 2
    write_images(tmp_path / "images_2", small)
    ds = load_llff(tmp_path, "test", downscale=2)  # images_2 is used as is
    np.testing.assert_allclose(ds.images, 7 / 255.0, atol=1e-6)
    assert ds.cameras[0].fx == pytest.approx(40.0 / 4) and ds.cameras[0].cx == W / 4


def test_llff_wrong_shape(tmp_path):
    write_llff(tmp_path)
    np.save(tmp_path / "poses_bounds.npy", np.zeros((10, 15)))
    with pytest.raises(ValueError, match=r"poses_bounds\.npy: poses_bounds has shape \(10, 15\), "
                                         r"expected \(N, 17\)"):
        load_dataset(tmp_path)
    np.save(tmp_path / "poses_bounds.npy", np.array([{"a": 1}] * 10), allow_pickle=True)
    with pytest.raises(ValueError, match=r"poses_bounds\.npy: not a plain numeric"):
        load_dataset(tmp_path)


def test_llff_count_mismatch_and_missing_folder(tmp_path):
    write_llff(tmp_path)
    (tmp_path / "images" / "IMG_0003.png").unlink()
    with pytest.raises(ValueError, match=r"images: found 9 images, but .*poses_bounds\.npy has "
                                         r"10 poses"):
        load_dataset(tmp_path)
    for f in (tmp_path / "images").iterdir():
        f.unlink()
    (tmp_path / "images").rmdir()
    with pytest.raises(FileNotFoundError, match=r"images: image folder not found"):
        load_dataset(tmp_path, downscale=4)
