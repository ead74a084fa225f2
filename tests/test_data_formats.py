"""COLMAP and nerfstudio / instant-ngp transforms.json loaders, ``clrender data check``, on
tiny fixtures (tests/dataset_fixtures.py). Poses compared to 1e-9 (float64 throughout),
pixels to 1e-6 (uint8 / 255 in float32)."""
import numpy as np
import pytest
from dataset_fixtures import (FOCAL, H, OPENCV_TO_NERF, W, edit_json, write_colmap,
                              write_colmap_by_hand, write_images, write_transforms)

from clrender.data import detect_format, load_dataset, scan_dataset
from clrender.data.check import check_dataset, format_summary
from clrender.data.llff import normalise


def looks_at_centre_upright(cameras):
    """Every camera looks at the origin (the ring's centre) with its up along world +z."""
    for c in cameras:
        forward, to_centre = -c.c2w[:3, 2], -c.origin / np.linalg.norm(c.origin)
        assert forward @ to_centre == pytest.approx(1.0, abs=1e-6)
        assert c.c2w[2, 1] > 0.95
        np.testing.assert_allclose(c.c2w[:3, :3].T @ c.c2w[:3, :3], np.eye(3), atol=1e-9)


# -- COLMAP ---------------------------------------------------------------------------------

@pytest.mark.parametrize("text", [False, True], ids=["bin", "txt"])
def test_colmap_round_trip(tmp_path, text):
    images, c2w = write_colmap(tmp_path, text=text)
    assert detect_format(tmp_path) == "colmap"
    train, test = load_dataset(tmp_path, "train"), load_dataset(tmp_path, "test")
    assert train.scene == "unbounded" and len(train.cameras) == 8 and len(test.cameras) == 2
    np.testing.assert_allclose(test.images, images[[0, 8]] / 255.0, atol=1e-6)
    np.testing.assert_allclose(train.images[0], images[1] / 255.0, atol=1e-6)
    cam = train.cameras[0]
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (
        FOCAL, FOCAL + 1, W / 2, H / 2, W, H)
    # The LLFF loader's normalisation of the written poses, and the same split.
    expect = normalise(c2w)
    got = np.stack([c.c2w for c in test.cameras + train.cameras])
    np.testing.assert_allclose(got, expect[[0, 8, 1, 2, 3, 4, 5, 6, 7, 9]], atol=1e-9)
    looks_at_centre_upright(train.cameras + test.cameras)


def test_colmap_by_hand_simple_pinhole_and_axes(tmp_path):
    # Image 1 at the world origin, unrotated: OpenCV axes, so it looks along world +z with
    # its up along -y. Image 2 rotated 90 degrees about the camera z axis, 1 unit along x.
    q = np.sqrt(0.5)
    write_colmap_by_hand(tmp_path, "# camera list\n1 SIMPLE_PINHOLE 32 24 20 16 12\n",
                         "# image list\n"
                         "1 1 0 0 0 0 0 0 1 a.png\n\n"
                         f"2 {q} 0 0 {q} 1 0 0 1 b.png\n\n", ["a.png", "b.png"])
    views = scan_dataset(tmp_path, "test")  # image 0 (a.png) is the test split
    cam = views.cameras[0]
    assert views.files[0].name == "a.png"
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (20.0, 20.0, 16.0, 12.0)
    # Before normalisation: c2w of a = OpenCV identity -> NeRF axes [x, -y, -z].
    from clrender.data.colmap import read_model
    _, images = read_model(tmp_path / "sparse" / "0")
    c2w_a = np.linalg.inv(images[0][2]) @ OPENCV_TO_NERF
    np.testing.assert_allclose(c2w_a, OPENCV_TO_NERF, atol=1e-12)
    c2w_b = np.linalg.inv(images[1][2])
    np.testing.assert_allclose(c2w_b[:3, 3], [0.0, 1.0, 0.0], atol=1e-12)  # -R^T t


@pytest.mark.parametrize("model, params", [("SIMPLE_RADIAL", [20.0, 16.0, 12.0, 0.01]),
                                           ("OPENCV", [20.0, 21.0, 16.0, 12.0, 0.1, 0, 0, 0])])
def test_colmap_distorted_camera_refused(tmp_path, model, params):
    write_colmap(tmp_path, model=model, params=params)
    with pytest.raises(ValueError, match=rf"sparse/0: camera 1 is {model} with parameters "
                                         r".*k.* = \[20\.0, .*undistort"):
        load_dataset(tmp_path)


def test_colmap_images_n_folder(tmp_path):
    images, _ = write_colmap(tmp_path)
    small = np.full((10, H // 2, W // 2, 3), 9, np.uint8)
    ds = load_dataset(tmp_path, "test", downscale=2)  # no images_2/: shrinks images/
    block = (images[[0, 8]] / 255.0).reshape(2, H // 2, 2, W // 2, 2, 3).mean((2, 4))
    np.testing.assert_allclose(ds.images, block, atol=1e-6)
    write_images(tmp_path / "images_2", small, [f"IMG_{i:04d}.png" for i in range(10)])
    ds = load_dataset(tmp_path, "test", downscale=2)
    np.testing.assert_allclose(ds.images, 9 / 255.0, atol=1e-6)
    assert (ds.cameras[0].fx, ds.cameras[0].cx) == (FOCAL / 2, W / 4)


# -- nerfstudio / instant-ngp ----------------------------------------------------------------

def test_transforms_unbounded_round_trip(tmp_path):
    images, c2w = write_transforms(tmp_path)
    assert detect_format(tmp_path) == "transforms"
    train, test = load_dataset(tmp_path, "train"), load_dataset(tmp_path, "test")
    assert train.scene == "unbounded" and (len(train.cameras), len(test.cameras)) == (8, 2)
    np.testing.assert_allclose(test.images, images[[0, 8]] / 255.0, atol=1e-6)
    cam = test.cameras[1]
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (FOCAL, FOCAL + 1, W / 2 + 0.5, H / 2)
    np.testing.assert_allclose(cam.c2w, normalise(c2w)[8], atol=1e-9)
    looks_at_centre_upright(train.cameras + test.cameras)


def test_transforms_aabb_scale_1_is_bounded_and_per_frame_intrinsics(tmp_path):
    _, c2w = write_transforms(tmp_path, extra={"aabb_scale": 1},
                              frame_extra={"fl_x": 30.0, "fl_y": 30.0})
    ds = load_dataset(tmp_path, "test")
    assert ds.scene == "bounded" and ds.cameras[0].fx == 30.0
    np.testing.assert_allclose(ds.cameras[1].c2w[:3, 3], c2w[8, :3, 3] * 2 / 3, atol=1e-12)
    edit_json(tmp_path / "transforms.json", lambda m: m.update(aabb_scale=16))
    assert load_dataset(tmp_path, "test").scene == "unbounded"


def test_transforms_camera_angle_x(tmp_path):
    write_transforms(tmp_path)

    def angle_only(meta):
        for k in ("fl_x", "fl_y", "cx", "cy"):
            del meta[k]
        meta["camera_angle_x"] = 0.69

    edit_json(tmp_path / "transforms.json", angle_only)
    cam = load_dataset(tmp_path, "test").cameras[0]
    assert cam.fx == pytest.approx(0.5 * W / np.tan(0.345)) and cam.cx == W / 2


def test_transforms_split_lists(tmp_path):
    images, _ = write_transforms(tmp_path, n=5)
    train = [f"images/frame_{i:05d}.png" for i in (0, 1, 3)]
    edit_json(tmp_path / "transforms.json",
              lambda m: m.update(train_filenames=train, val_filenames=["images/frame_00004.png",
                                                                       "./images/frame_00002.png"]))
    assert len(load_dataset(tmp_path, "train").cameras) == 3
    test = load_dataset(tmp_path, "test")  # no test list: nerfstudio's val list
    np.testing.assert_allclose(test.images, images[[4, 2]] / 255.0, atol=1e-6)
    edit_json(tmp_path / "transforms.json", lambda m: m.update(test_filenames=[train[0]]))
    np.testing.assert_allclose(load_dataset(tmp_path, "test").images, images[[0]] / 255.0,
                               atol=1e-6)


@pytest.mark.parametrize("extra, message", [
    ({"k1": 0.02}, r"frame 0 \(images/frame_00000\.png\): distortion \{.*'k1': 0\.02.*\} is "
                   r"not zero"),
    ({"camera_model": "OPENCV_FISHEYE"}, r"frame 0 .*camera_model 'OPENCV_FISHEYE' is not "
                                         r"supported"),
    ({"camera_model": "EQUIRECTANGULAR"}, r"frame 0 .*camera_model 'EQUIRECTANGULAR' is not "
                                          r"supported"),
])
def test_transforms_distortion_refused(tmp_path, extra, message):
    write_transforms(tmp_path, extra=extra)
    with pytest.raises(ValueError, match=r"transforms\.json: " + message):
        load_dataset(tmp_path)


def test_transforms_per_frame_distortion_refused(tmp_path):
    write_transforms(tmp_path)
    edit_json(tmp_path / "transforms.json", lambda m: m["frames"][3].update(p2=1e-3))
    with pytest.raises(ValueError, match=r"frame 3 \(images/frame_00003\.png\): distortion"):
        load_dataset(tmp_path)


def test_transforms_images_n_folder(tmp_path):
    write_transforms(tmp_path)
    files = [f"frame_{i:05d}.png" for i in range(10)]
    write_images(tmp_path / "images_2", np.full((10, H // 2, W // 2, 3), 5, np.uint8), files)
    ds = load_dataset(tmp_path, "test", downscale=2)
    np.testing.assert_allclose(ds.images, 5 / 255.0, atol=1e-6)
    assert (ds.cameras[0].fx, ds.cameras[0].cx) == (FOCAL / 2, (W / 2 + 0.5) / 2)
    assert scan_dataset(tmp_path, "test", 2).source.name == "transforms.json"


# -- clrender data check ---------------------------------------------------------------------

def test_data_check_summary(tmp_path):
    write_colmap(tmp_path)
    s = check_dataset(tmp_path, downscale=2)
    assert (s["format"], s["scene"]) == ("colmap", "unbounded")
    assert {k: v["views"] for k, v in s["splits"].items()} == {"train": 8, "val": 2, "test": 2}
    train = s["splits"]["train"]
    assert (train["width"], train["height"], train["resize"], train["fx"]) == (
        W // 2, H // 2, 2, FOCAL / 2)
    assert s["camera_distance"]["max"] == pytest.approx(1.0)
    text = format_summary(s)
    assert "colmap, unbounded" in text and "train    8 views  16x12" in text
    assert "shrunk 2x" in text and "cameras 1.000 to 1.000 from the scene centre" in text


def test_data_check_reads_no_pixels(tmp_path, monkeypatch):
    write_transforms(tmp_path)
    import clrender.data.views as views

    def no_decoding(file):
        raise AssertionError(f"decoded {file}")

    monkeypatch.setattr(views, "read_image", no_decoding)
    assert check_dataset(tmp_path)["splits"]["test"]["views"] == 2
    with pytest.raises(AssertionError, match="decoded"):
        load_dataset(tmp_path)
