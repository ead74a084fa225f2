"""Errors a user can cause, through ``clrender.cli.main`` in-process: a device that does not
exist, a missing extra, a bad file, a port in use. Each is one line on stderr, naming the
thing, and exit status 2."""
import socket
import sys

import pytest

from clrender import cli, extras
from clrender.ndrf.method import example_model as ndrf_example
from clrender.ngprt.method import example_model as ngprt_example

NO_DEVICE = "no-such-device"


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """{method: a random baked file} of each method."""
    root = tmp_path_factory.mktemp("models")
    return {"ngprt": ngprt_example(root / "ngprt.npz"), "ndrf": ndrf_example(root / "ndrf.npz")}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A built-in bounded scene of one 16x16 test view."""
    from clrender.data import make_scene

    return make_scene("bounded", tmp_path_factory.mktemp("scene") / "s", n_train=1, n_test=1,
                      width=16, height=16)


def one_line_error(capsys, argv, command: str) -> str:
    """Run ``clrender argv``: status 2 and one stderr line, ``clrender COMMAND: error: ...``,
    returned."""
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert err.startswith(f"clrender {command}: error: "), err
    return err


@pytest.mark.parametrize("method", ["ngprt", "ndrf"])
@pytest.mark.parametrize("command", ["render", "eval", "view"])
def test_every_command_that_renders_names_a_missing_device_in_one_line(
        command, method, models, scene, tmp_path, capsys):
    capsys.readouterr()
    argv = {"render": ["render", str(models[method]), "--out", str(tmp_path / "frames"),
                       "--frames", "2", "--width", "16", "--height", "16"],
            "eval": ["eval", str(models[method]), str(scene)],
            "view": ["view", str(models[method]), "--port", "0"]}[command]
    err = one_line_error(capsys, argv + ["--device", NO_DEVICE], command)
    assert f"no OpenCL device matches {NO_DEVICE!r}; devices that exist: [0] " in err
    assert not (tmp_path / "frames").exists()


def test_training_that_renders_on_the_device_checks_it_before_writing(models, scene, tmp_path,
                                                                     capsys, monkeypatch):
    """NDRF's distillation views are the teacher's OpenCL renders."""
    capsys.readouterr()
    monkeypatch.setenv("CLRENDER_DEVICE", NO_DEVICE)
    one_line_error(capsys, ["train", str(scene), "--method", "ndrf", "--teacher",
                            str(models["ngprt"]), "--preset", "tiny", "--out",
                            str(tmp_path / "run")], "train")
    assert not (tmp_path / "run").exists()


def test_info_names_a_missing_device_in_one_line_after_the_list(capsys):
    assert cli.main(["info", "--device", NO_DEVICE]) == 2
    out, err = capsys.readouterr()
    assert "[0]" in out and err.count("\n") == 1
    assert err.startswith(f"clrender info: error: no OpenCL device matches {NO_DEVICE!r}")


def test_the_device_variable_is_named_as_the_flag_is(models, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CLRENDER_DEVICE", NO_DEVICE)
    err = one_line_error(capsys, ["render", str(models["ngprt"]), "--out",
                                  str(tmp_path / "f"), "--frames", "1"], "render")
    assert repr(NO_DEVICE) in err


@pytest.mark.parametrize("argv, command, module, extra", [
    (["train", "DATA", "--out", "RUN"], "train", "torch", "train"),
    (["bake", "RUN", "--out", "m.npz"], "bake", "torch", "train"),
    (["scene", "make", "bounded", "OUT"], "scene", "embreex", "train"),
    (["eval", "MODEL", "DATA"], "eval", "skimage", "eval"),
    (["capture", "PHOTOS", "--out", "OUT"], "capture", "pycolmap", "capture"),
    (["view", "MODEL"], "view", "viser", "view"),
    (["render", "MODEL", "--out", "orbit.mp4"], "render", "imageio_ffmpeg", "video"),
    (["ndrf", "extract", "TEACHER", "--out", "OUT"], "ndrf", "skimage", "train"),
    (["export", "MODEL", "--format", "glb", "--out", "m.glb"], "export", "trimesh", "train"),
])
def test_a_missing_extra_is_named_in_one_line(argv, command, module, extra, monkeypatch,
                                              capsys):
    real = extras.importlib.util.find_spec
    monkeypatch.setattr(extras.importlib.util, "find_spec",
                        lambda name, *a: None if name == module else real(name, *a))
    err = one_line_error(capsys, argv, command)
    assert f"needs {module!r}, which is not installed: pip install 'clrender[{extra}]'" in err


def test_an_import_of_an_extras_package_that_fails_later_is_named_too(models, monkeypatch,
                                                                       capsys):
    """A module imported past the command's check (here NDRF's Embree hits, only imported
    when a render asks for them) is still one line naming its extra."""
    monkeypatch.setitem(sys.modules, "embreex", None)        # import embreex fails
    err = one_line_error(capsys, ["render", str(models["ndrf"]), "--out", "frames",
                                  "--hits", "embree"], "render")
    assert "needs 'embreex', which is not installed: pip install 'clrender[train]'" in err


@pytest.mark.parametrize("content, problem", [(b"not a zip", "not a baked model"),
                                              (None, "No such file")])
def test_a_bad_model_file_is_one_line_naming_it(content, problem, tmp_path, capsys):
    path = tmp_path / "model.npz"
    if content is not None:
        path.write_bytes(content)
    err = one_line_error(capsys, ["render", str(path), "--out", str(tmp_path / "f")],
                         "render")
    assert str(path) in err


def test_a_port_in_use_is_one_line(models, tmp_path, capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        err = one_line_error(capsys, ["export", str(models["ngprt"]), "--out",
                                      str(tmp_path / "site"), "--serve", "--port", str(port)],
                             "export")
    assert f"port {port} on 127.0.0.1 is in use" in err


def test_version_is_the_package_metadata(capsys):
    from importlib import metadata

    import clrender

    with pytest.raises(SystemExit) as stop:
        cli.main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out == f"clrender {metadata.version('clrender')}\n"
    assert clrender.__version__ == metadata.version("clrender")


@pytest.mark.parametrize("module", ["bench.run", "bench.train_curve"])
def test_the_benchmarks_name_a_missing_device_in_one_line(module, tmp_path, capsys):
    import importlib

    main = importlib.import_module(module).main
    argv = (["table4"] if module == "bench.run" else []) + [
        "--preset", "tiny", "--device", NO_DEVICE, "--out", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"{module}: error: no OpenCL device matches")
    assert not (tmp_path / "out").exists()
