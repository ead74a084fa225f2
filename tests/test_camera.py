"""Camera conventions, ray generation (numpy vs OpenCL) and camera paths."""
import numpy as np
import pytest

from clrender.camera import Camera, generate_rays, generate_rays_cl, look_at
from clrender.paths import orbit_path, spiral_path


def _cameras():
    rng = np.random.default_rng(3)
    cams = [Camera.from_fov(0.69, 40, 30, look_at([0.0, -4.0, 1.0]))]
    for _ in range(3):
        eye = rng.normal(size=3) * 3
        cams.append(Camera(rng.uniform(20, 60), rng.uniform(20, 60), rng.uniform(10, 20),
                           rng.uniform(5, 15), 33, 21, look_at(eye, rng.normal(size=3) * 0.3)))
    return cams


@pytest.mark.parametrize("cam", _cameras())
def test_ray_kernel_matches_numpy(cam, cl_platform):
    o, d = generate_rays(cam)
    o_cl, d_cl = generate_rays_cl(cam)
    assert np.abs(d - d_cl).max() <= 1e-5
    assert np.abs(o - o_cl).max() <= 1e-5


def test_centre_ray_looks_down_minus_z():
    cam = Camera.from_fov(0.8, 64, 64, look_at([0.0, -3.0, 0.0]))
    _, d = generate_rays(cam)
    centre = (d[31, 31] + d[32, 32]) / 2
    np.testing.assert_allclose(centre / np.linalg.norm(centre), [0, 1, 0], atol=1e-3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-6)
    # +y up in the image: the top row points up (world +z here), the left column left.
    assert d[0, 32, 2] > 0 > d[-1, 32, 2]
    assert d[32, 0, 0] < 0 < d[32, -1, 0]


def test_resized_keeps_the_field_of_view():
    cam = Camera.from_fov(0.8, 64, 48, look_at([1.0, 2.0, 3.0]))
    small = cam.resized(0.5)
    assert (small.width, small.height) == (32, 24)
    _, d = generate_rays(cam)
    _, ds = generate_rays(small)
    np.testing.assert_allclose(ds[0, 0], (d[0, 0] + d[1, 1]) / 2, atol=2e-3)


def test_bad_camera_matrix_is_rejected():
    with pytest.raises(ValueError, match="c2w"):
        Camera(10, 10, 5, 5, 10, 10, np.eye(3))


def test_orbit_looks_at_target():
    for c2w in orbit_path(8, radius=3.0, elevation_deg=20.0):
        eye = c2w[:3, 3]
        assert abs(np.linalg.norm(eye) - 3.0) < 1e-9
        np.testing.assert_allclose(-c2w[:3, 2], -eye / np.linalg.norm(eye), atol=1e-9)


def test_spiral_stays_near_the_input_cameras():
    base = np.stack([look_at([x, -3.0, 0.2 * x]) for x in np.linspace(-0.5, 0.5, 10)])
    path = spiral_path(base, 12)
    assert len(path) == 12
    eyes = np.stack([p[:3, 3] for p in path])
    assert np.abs(eyes - base[:, :3, 3].mean(0)).max() < 1.0
