"""``clrender export --format glb``: coloured meshes in a glTF 2.0 binary file.

Checked: the vertex-colour fit against colours it must recover; the file of a trained NDRF
student and of its NGP-RT teacher as trimesh reads it (colours present, unit normals,
counts of the model, +Y up) and as our reader reads it back; the Khronos glTF validator
(npm ``gltf-validator``, which .ci/install puts in ``.tools/``; skipped elsewhere, failed
under CI when missing) finds no error; bad input is one line.

Tolerances: positions are rotated by a matrix of 0 and +-1, so they come back exactly;
colours are stored as 16-bit linear values, so back in sRGB within 1e-3 (the sRGB curve's
steepest slope, 12.92, times half a step of 1/65535, rounded up). With a vanishing
smoothness term (1e-6) the fit recovers known colours to 1e-4 and reproduces their images
to 60 dB: what is left is the solver's tolerance.
"""
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from clrender import Camera, look_at, methods
from clrender.cli import main
from clrender.export.glb import MeshNode, glb_bytes, read_glb, write_glb
from clrender.export.mesh_colours import fit_vertex_colours, render_mesh
from clrender.metrics import psnr
from deps import require

trimesh = pytest.importorskip("trimesh")
ROOT = Path(__file__).resolve().parent.parent
VALIDATOR = ROOT / ".tools" / "gltf-validator"
COLOUR_ROUND_TRIP = 1e-3
HALF_CELL = 1.0 / 64        # the `tiny` extraction's grid: 64 cells over [-1, 1]


def validate(path: Path) -> dict:
    """The Khronos validator's issues of ``path``: numErrors, numWarnings, messages."""
    found = shutil.which("node") is not None and (VALIDATOR / "node_modules").is_dir()
    require(found, f"node and gltf-validator in {VALIDATOR} (.ci/install)")
    done = subprocess.run(["node", str(ROOT / "tests" / "gltf_validate.js"), str(path)],
                          capture_output=True, text=True, timeout=120,
                          env={"NODE_PATH": str(VALIDATOR / "node_modules"), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def views_around(n: int, size: int) -> list[Camera]:
    eyes = [(3 * np.cos(a) * np.cos(e), 3 * np.sin(a) * np.cos(e), 3 * np.sin(e))
            for a in np.linspace(0, 2 * np.pi, n // 2, endpoint=False) for e in (-0.5, 0.6)]
    return [Camera.from_fov(0.69, size, size, look_at(eye)) for eye in eyes]


def test_the_fit_reproduces_images_of_known_vertex_colours():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    truth = np.random.default_rng(0).uniform(0.1, 0.9, (len(sphere.vertices), 3))
    cams = views_around(12, 64)
    images = [render_mesh(sphere.vertices, sphere.faces, truth, c, (1, 1, 1)) for c in cams]
    fitted = fit_vertex_colours(sphere.vertices, sphere.faces, cams, images, smoothness=1e-6)
    again = [render_mesh(sphere.vertices, sphere.faces, fitted, c, (1, 1, 1)) for c in cams]
    assert min(psnr(a, b) for a, b in zip(again, images)) > 60.0
    assert np.median(np.abs(fitted - truth)) < 1e-4


def test_no_view_of_the_mesh_is_an_error():
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    away = Camera.from_fov(0.69, 16, 16, look_at([0, -3, 0], target=[0, -6, 0]))
    with pytest.raises(ValueError, match="no view sees the mesh"):
        fit_vertex_colours(sphere.vertices, sphere.faces, [away], [np.zeros((16, 16, 3))])


def test_the_file_round_trips_and_is_y_up(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(sphere.vertices, np.float32) * [1.0, 0.5, 0.25]     # tall along y: z small
    rgb = np.random.default_rng(1).uniform(0, 1, (len(v), 3)).astype(np.float32)
    cam = Camera.from_fov(0.69, 40, 30, look_at([0, -3, 1]))
    path = write_glb(tmp_path / "s.glb", [MeshNode("outer", v, sphere.faces, rgb)],
                     [("test_000", cam)])
    back = read_glb(path)
    assert np.array_equal(back["outer"]["POSITION"], v)
    assert np.array_equal(back["outer"]["indices"], sphere.faces)
    assert np.abs(back["outer"]["COLOR_0"] - rgb).max() < COLOUR_ROUND_TRIP
    assert back["cameras"] == ["test_000"]
    loaded = trimesh.load(path, process=False)
    mesh = loaded.geometry["outer"]
    assert np.ptp(mesh.vertices, axis=0) == pytest.approx(np.ptp(v, axis=0)[[0, 2, 1]])
    assert validate(path)["numErrors"] == 0


def test_a_mesh_without_triangles_is_refused():
    with pytest.raises(ValueError, match="'outer' has no triangles"):
        glb_bytes([MeshNode("outer", np.zeros((3, 3)), np.zeros((0, 3), int), np.zeros((3, 3)))])


@pytest.fixture(scope="module")
def student_glb(tiny_ndrf_student, tmp_path_factory):
    out = tmp_path_factory.mktemp("glb") / "student.glb"
    assert main(["export", str(tiny_ndrf_student["student"]), "--format", "glb", "--out",
                 str(out), "--data", str(tiny_ndrf_student["scene"]), "--cameras"]) == 0
    return out


def test_an_ndrf_student_exports_its_meshes_coloured(student_glb, tiny_ndrf_student):
    model = methods.load(tiny_ndrf_student["student"])
    loaded = trimesh.load(student_glb, process=False)
    assert sorted(loaded.geometry) == ["inner", "outer"]
    back = read_glb(student_glb)
    for k, name in enumerate(["outer", "inner"]):
        vertices, faces, _ = model.mesh(k)
        mesh = loaded.geometry[name]
        assert len(mesh.vertices) == len(vertices) and len(mesh.faces) == len(faces)
        assert mesh.visual.vertex_attributes["color"].shape == (len(vertices), 4)
        assert np.allclose(np.linalg.norm(mesh.vertex_normals, axis=1), 1.0, atol=1e-5)
        assert np.array_equal(back[name]["POSITION"], vertices)
        assert np.array_equal(back[name]["indices"], faces)
        colours = back[name]["COLOR_0"]
        assert colours.min() >= 0 and colours.max() <= 1 and colours.std() > 0
    assert len(back["cameras"]) == 2                                       # the test views
    report = validate(student_glb)
    assert report["numErrors"] == 0, report["messages"]


def test_an_ngprt_model_exports_its_surface(tiny_ndrf_student, tmp_path):
    teacher = tiny_ndrf_student["teacher"]
    out = tmp_path / "teacher.glb"
    assert main(["export", str(teacher), "--format", "glb", "--out", str(out), "--extraction",
                 "tiny", "--data", str(tiny_ndrf_student["scene"]), "--colours", "images"]) == 0
    back = read_glb(out)
    surface = back["surface"]
    assert len(surface["indices"]) > 0
    assert np.abs(surface["POSITION"]).max() <= 1.0 + HALF_CELL
    assert validate(out)["numErrors"] == 0


def test_a_threshold_that_leaves_no_triangles_is_one_line(tmp_path, capsys):
    """A random model whose density logits are 40 lower: alpha nowhere near 0.3."""
    import dataclasses

    from clrender.ngprt.baked import save_baked
    from clrender.ngprt.config import preset
    from clrender.ngprt.random_model import random_baked_model

    model = random_baked_model(preset("tiny"), seed=0)
    blocks = model.arrays["coarse_blocks"].copy()
    blocks[..., 0] -= 40.0
    thin = save_baked(dataclasses.replace(model, arrays={**model.arrays, "coarse_blocks": blocks}),
                      tmp_path / "thin.npz")
    assert main(["export", str(thin), "--format", "glb", "--out", str(tmp_path / "x.glb"),
                 "--extraction", "tiny"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "alpha never crosses threshold 0.3" in err
    assert not (tmp_path / "x.glb").exists()


def test_an_unbounded_model_exports_its_inner_box(tmp_path):
    from clrender.ngprt.baked import save_baked
    from clrender.ngprt.config import preset
    from clrender.ngprt.random_model import random_baked_model

    model = random_baked_model(preset("tiny", scene="unbounded"), seed=0,
                               shapes=[("sphere", np.zeros(3), np.full(3, 0.5))])
    path = save_baked(model, tmp_path / "unbounded.npz")
    out = tmp_path / "u.glb"
    assert main(["export", str(path), "--format", "glb", "--out", str(out),
                 "--extraction", "tiny"]) == 0
    surface = read_glb(out)["surface"]["POSITION"]
    assert len(surface) > 0 and np.abs(surface).max() <= 1.0 + HALF_CELL


@pytest.mark.parametrize("argv, message", [
    (["--format", "glb", "--out", "x.html"], "a .glb file is expected"),
    (["--out", "site", "--threshold", "0.1"], "--threshold: options of --format glb"),
    (["--format", "glb", "--out", "x.glb", "--cameras"], "--cameras needs the dataset"),
    (["--format", "glb", "--out", "x.glb", "--colours", "images"], "needs the dataset"),
])
def test_bad_export_options_are_one_line(argv, message, tiny_ndrf_student, tmp_path, capsys,
                                         monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(tiny_ndrf_student["student"]), *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert list(tmp_path.iterdir()) == []
