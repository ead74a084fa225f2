"""Tiny datasets of every format, written on the fly: a ring of cameras around CENTRE
looking at it (up along TILT), random H x W images. Each writer returns (images uint8
(N, H, W, 3), NeRF camera-to-world (N, 4, 4) before normalisation)."""
import json

import imageio.v3 as iio
import numpy as np

from clrender.camera import look_at

H, W = 24, 32
CENTRE = np.array([1.0, 2.0, 3.0])
TILT = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
FOCAL = 20.0
OPENCV_TO_NERF = np.diag([1.0, -1.0, -1.0, 1.0])


def ring(n: int) -> np.ndarray:
    """(n, 4, 4) NeRF c2w on a circle of radius 2.5 around CENTRE, looking at it."""
    a = np.cross(TILT, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(TILT, a)
    eyes = [CENTRE + 2.5 * (np.cos(t) * a + np.sin(t) * b) + 0.3 * TILT
            for t in 2 * np.pi * np.arange(n) / n]
    return np.stack([look_at(e, CENTRE, up=TILT) for e in eyes])


def random_images(n: int, seed: int = 2) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, H, W, 3), dtype=np.uint8)


def write_images(folder, images, names):
    folder.mkdir(parents=True, exist_ok=True)
    for img, name in zip(images, names):
        iio.imwrite(folder / name, img)


def names(n: int, ext: str = ".png") -> list[str]:
    return [f"IMG_{i:04d}{ext}" for i in range(n)]


# -- COLMAP ---------------------------------------------------------------------------------

def write_colmap(root, n=10, ext=".png", model="PINHOLE", params=None, text=False):
    """``root/sparse/0`` (binary, or text with ``text``) written by pycolmap + images/."""
    import pycolmap

    c2w = ring(n)
    rec = pycolmap.Reconstruction()
    params = params or [FOCAL, FOCAL + 1, W / 2, H / 2]
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=W, height=H,
                                                    params=params, camera_id=1))
    for i, name in enumerate(names(n, ext)):
        w2c = np.linalg.inv(c2w[i] @ OPENCV_TO_NERF)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=i + 1),
                                         pose)
    folder = root / "sparse" / "0"
    folder.mkdir(parents=True)
    (rec.write_text if text else rec.write_binary)(str(folder))
    images = random_images(n)
    write_images(root / "images", images, names(n, ext))
    return images, c2w


def write_colmap_by_hand(root, cameras_txt: str, images_txt: str, image_names):
    """A text model written from COLMAP's documented format, and black images."""
    folder = root / "sparse" / "0"
    folder.mkdir(parents=True)
    (folder / "cameras.txt").write_text(cameras_txt)
    (folder / "images.txt").write_text(images_txt)
    (folder / "points3D.txt").write_text("# 3D point list\n")
    write_images(root / "images", np.zeros((len(image_names), H, W, 3), np.uint8), image_names)


# -- nerfstudio / instant-ngp transforms.json -----------------------------------------------

def write_transforms(root, n=10, ext=".png", extra=None, frame_extra=None):
    """``root/transforms.json`` (global fl_x fl_y cx cy w h) + ``images/frame_*``."""
    c2w = ring(n)
    files = [f"frame_{i:05d}{ext}" for i in range(n)]
    frames = [{"file_path": f"images/{f}", "transform_matrix": c2w[i].tolist(),
               **(frame_extra or {})} for i, f in enumerate(files)]
    meta = {"camera_model": "OPENCV", "fl_x": FOCAL, "fl_y": FOCAL + 1, "cx": W / 2 + 0.5,
            "cy": H / 2, "w": W, "h": H, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
            "frames": frames, **(extra or {})}
    (root / "transforms.json").write_text(json.dumps(meta))
    images = random_images(n)
    write_images(root / "images", images, files)
    return images, c2w


def edit_json(file, change):
    meta = json.loads(file.read_text())
    change(meta)
    file.write_text(json.dumps(meta))


# -- LLFF -----------------------------------------------------------------------------------

def write_llff(root, n=10, ext=".png", folder="images"):
    """``poses_bounds.npy`` (hwf of 2x larger originals) + ``images/IMG_*``."""
    c2w = ring(n)
    rows = []
    for m in c2w:
        llff = np.stack([-m[:3, 1], m[:3, 0], m[:3, 2], m[:3, 3], [2 * H, 2 * W, 2 * FOCAL]], 1)
        rows.append(np.concatenate([llff.reshape(-1), [0.5, 10.0]]))
    np.save(root / "poses_bounds.npy", np.array(rows))
    images = random_images(n)
    write_images(root / folder, images, names(n, ext))
    return images, c2w


# -- Blender --------------------------------------------------------------------------------

def write_blender(root, n=4, ext=".png", split="train"):
    """``transforms_{split}.json`` (camera_angle_x) + ``{split}/r_*``."""
    c2w = ring(n)
    files = [f"r_{i}{ext}" for i in range(n)]
    frames = [{"file_path": f"./{split}/{f}", "transform_matrix": c2w[i].tolist()}
              for i, f in enumerate(files)]
    (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.69,
                                                                "frames": frames}))
    images = random_images(n)
    write_images(root / split, images, files)
    return images, c2w
