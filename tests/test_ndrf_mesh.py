"""Duplex mesh extraction (clrender/ndrf/mesh.py).

Tolerances:
- analytic sphere, N = 64 over [-1, 1]^3 (voxel h = 1/32): vertex radii within one voxel of
  the analytic level-set radius (max), within a quarter voxel on average;
- teacher density: bit-equal to ``exp(features logit)`` of the numpy reference in occupied
  cells, exactly 0 in empty ones;
- decimation: at most the face budget, at least 90% of it;
- culling (cameras on +z): no kept face with its centre below z = 0 (the visible caps end at
  z = r^2 / distance > 0), and every in-view face with centre z > 0.3 r is kept.
"""
import json

import numpy as np
import pytest
import trimesh

from clrender.camera import Camera, look_at
from clrender.ndrf.mesh import ExtractConfig, extract_duplex, extract_mesh, extract_preset, \
    sample_alpha, teacher_density, write_meshes
from clrender.ngprt.config import preset
from clrender.ngprt.random_model import random_baked_model
from clrender.ngprt.render_ref import features

N = 64
H = 2.0 / N                       # voxel size in world units
STEP = 2.0 * np.sqrt(3.0) / N     # a teacher's base step at this resolution
THRESHOLDS = (1e-4, 1e-2)
R_OUT, R_IN = 0.7, 0.45           # radii where alpha crosses 1e-4 and 1e-2


def _sigma_at(alpha):
    return -np.log1p(-alpha) / STEP


# sigma(r) = A exp(-r^2 / (2 s^2)) with alpha(R_OUT) = 1e-4 and alpha(R_IN) = 1e-2.
_S2 = (R_OUT ** 2 - R_IN ** 2) / (2.0 * np.log(_sigma_at(1e-2) / _sigma_at(1e-4)))
_A = _sigma_at(1e-4) * np.exp(R_OUT ** 2 / (2.0 * _S2))
BLOB = np.array([0.8, 0.8, -0.8])


def sphere_density(xyz, blob=False):
    """Gaussian sphere; ``blob`` adds a tiny far part that only crosses the outer level,
    about 0.05 from BLOB (bounding-box diagonal ~0.18)."""
    x = np.asarray(xyz, np.float64)
    sigma = _A * np.exp(-np.sum(x * x, axis=1) / (2.0 * _S2))
    if blob:
        sigma += 10.0 * _sigma_at(1e-4) * np.exp(-np.sum((x - BLOB) ** 2, axis=1) / 8e-4)
    return sigma.astype(np.float32)


@pytest.fixture(scope="module")
def alpha_sphere():
    return sample_alpha(sphere_density, N, STEP, progress=False)


@pytest.fixture(scope="module")
def alpha_blob():
    return sample_alpha(lambda x: sphere_density(x, blob=True), N, STEP, progress=False)


def test_sphere_levels_at_analytic_radii(alpha_sphere):
    meshes, report = extract_duplex(sphere_density, ExtractConfig(N=N), THRESHOLDS, step=STEP,
                                    progress=False)
    assert [m["threshold"] for m in report["meshes"]] == list(THRESHOLDS)
    for mesh, r_expected in zip(meshes, (R_OUT, R_IN)):
        err = np.linalg.norm(mesh.vertices, axis=1) - r_expected
        assert np.abs(err).max() < H and np.abs(err).mean() < H / 4
        # Normals point out of the matter (towards decreasing alpha).
        assert np.all(np.sum(mesh.face_normals * mesh.triangles_center, axis=1) > 0)
        assert mesh.is_watertight


def test_small_components_dropped(alpha_blob):
    kept, stats = extract_mesh(alpha_blob, 1e-4, min_component=0.0)
    assert stats["components_dropped"] == 0
    assert np.linalg.norm(kept.vertices, axis=1).max() > 1.0          # the blob is there
    mesh, stats = extract_mesh(alpha_blob, 1e-4, min_component=0.1)   # diag 0.35 > blob's
    assert stats["components_dropped"] == 1
    assert np.linalg.norm(mesh.vertices, axis=1).max() < R_OUT + H
    assert len(mesh.split(only_watertight=False)) == 1


def test_decimation_to_budget(alpha_sphere):
    full, _ = extract_mesh(alpha_sphere, 1e-4)
    mesh, _ = extract_mesh(alpha_sphere, 1e-4, face_budget=500)
    assert len(full.faces) > 2000
    assert 450 <= len(mesh.faces) <= 500
    assert np.all(np.sum(mesh.face_normals * mesh.triangles_center, axis=1) > 0)


def test_cull_keeps_the_side_cameras_see(alpha_sphere):
    cams = [Camera.from_fov(np.radians(40), 32, 32, look_at(eye, up=(0, 1, 0)))
            for eye in ((0, 0, 3), (0.5, 0, 3))]
    full, _ = extract_mesh(alpha_sphere, 1e-4)
    mesh, stats = extract_mesh(alpha_sphere, 1e-4, cameras=cams)
    centres = mesh.triangles_center
    assert centres[:, 2].min() > 0
    assert stats["faces_culled"] == len(full.faces) - len(mesh.faces) > len(full.faces) / 2
    front = full.triangles_center[full.triangles_center[:, 2] > 0.3 * R_OUT]
    kept = {tuple(c) for c in np.round(centres, 6)}
    assert all(tuple(c) in kept for c in np.round(front, 6))


def test_threshold_never_crossed(alpha_sphere):
    with pytest.raises(ValueError, match=r"threshold 0\.5: alpha range is \["):
        extract_mesh(alpha_sphere, 0.5)


@pytest.fixture(scope="module")
def teacher():
    return random_baked_model(preset("tiny"), seed=1)


def test_teacher_density_matches_reference(teacher):
    rng = np.random.default_rng(0)
    L_C = teacher.config.L_C
    occ = np.argwhere(teacher.arrays["occupancy_0"] != 0)
    in_occ = (occ[rng.choice(len(occ), 500)] + rng.random((500, 3))) / L_C * 2 - 1
    xyz = np.concatenate([in_occ, rng.uniform(-1, 1, (2000, 3)),
                          [[1.5, 0, 0], [0, -3, 0]]]).astype(np.float32)
    sigma = teacher_density(teacher)(xyz)
    u = (xyz + 1) / 2
    cell = np.clip(np.floor(u * L_C), 0, L_C - 1).astype(int)
    inside = np.all(np.abs(xyz) <= 1, axis=1)
    occupied = inside & (teacher.arrays["occupancy_0"][tuple(cell.T)] != 0)
    assert occupied[:500].all() and not occupied.all()
    np.testing.assert_array_equal(sigma[occupied], np.exp(features(teacher, u[occupied])[:, 0]))
    np.testing.assert_array_equal(sigma[~occupied], 0)


def test_unbounded_teacher_refused():
    model = random_baked_model(preset("tiny", scene="unbounded"))
    with pytest.raises(ValueError, match="bounded scenes only.*contracted space"):
        teacher_density(model)


def test_extract_and_write(teacher, tmp_path):
    meshes, report = extract_duplex(teacher, "tiny", progress=False)
    assert report["N"] == extract_preset("tiny").N and report["step"] == teacher.step
    assert len(meshes) == 2 and all(len(m.faces) > 0 for m in meshes)
    assert len(meshes[0].faces) <= extract_preset("tiny").face_budget
    paths = write_meshes(meshes, report, tmp_path / "out")
    assert [p.name for p in paths] == ["mesh_0.ply", "mesh_1.ply", "report.json"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(p.name for p in paths)
    assert paths[0].read_bytes().startswith(b"ply\nformat binary_little_endian")
    saved = json.loads(paths[2].read_text())
    for path, mesh, entry in zip(paths, meshes, saved["meshes"]):
        loaded = trimesh.load(path, process=False)
        assert entry["faces"] == len(loaded.faces) == len(mesh.faces)
        assert entry["vertices"] == len(loaded.vertices) == len(mesh.vertices)
        np.testing.assert_allclose(loaded.vertices, mesh.vertices, rtol=0, atol=1e-6)
