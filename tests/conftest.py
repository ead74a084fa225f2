"""Shared fixtures."""
import pytest


@pytest.fixture
def one_torch_thread():
    """torch on one thread for the test: CPU training is then bit-reproducible (with two
    threads, reductions may add in another order and runs differ by ~1e-5 after 20 steps)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def tiny_ndrf_student(tmp_path_factory):
    """A `tiny` NDRF student of the built-in bounded scene (40x40 pixels) and its `tiny`
    NGP-RT teacher, trained once per session: {"scene", "teacher", "student"} paths."""
    from clrender.data import make_scene
    from clrender.ndrf.train import bake_run, train
    from clrender.ngprt.bake import bake_run as bake_teacher
    from clrender.ngprt.train import train as train_teacher

    root = tmp_path_factory.mktemp("tiny_ndrf")
    scene = make_scene("bounded", root / "scene", seed=1, n_train=12, n_test=2,
                       width=40, height=40)
    teacher = bake_teacher(train_teacher(scene, root / "teacher", preset="tiny",
                                         progress=False), root / "teacher.npz")
    run = train(scene, root / "run", teacher=teacher, preset="tiny", progress=False)
    return {"scene": scene, "teacher": teacher, "student": bake_run(run, root / "ndrf.npz")}
