"""`bench.run --executor ray` (bench/modelcache/cluster.py) and the cache's safety for many writers
(bench/modelcache/cache.py): locks, stale locks, leftovers of killed writers, provenance.

The slow tests train `tiny` models of a small built-in scene on a local Ray instance (this
machine's cores). Tolerances: the Ray table's quality columns equal the in-process run's
exactly (==): a `tiny` task asks for one CPU and trains on one torch thread, the in-process
run is given one thread too, and CPU training on one thread is bit-reproducible, so both
runs bake the same bytes.
"""
from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from filelock import Timeout

from bench.modelcache import cache, cluster
from bench import options, run
from clrender.atomic import _TEMPORARY, atomic_folder, remove_leftovers
from clrender.data import make_scene
from deps import require

REPO = Path(__file__).resolve().parent.parent
QUALITY = ("PSNR", "SSIM", "LPIPS")


@pytest.fixture
def ray_installed():
    require(importlib.util.find_spec("ray") is not None, "ray (pip install 'clrender[cluster]')")


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    return make_scene("bounded", tmp_path_factory.mktemp("scene"), seed=1, n_train=8,
                      n_test=2, width=32, height=32)


def _table_args(scene, cache_dir, out, *extra, seeds: int = 2) -> list[str]:
    return ["ndrf-teacher", "--preset", "tiny", "--scene", str(scene), "--seeds", str(seeds),
            "--cache", str(cache_dir), "--out", str(out), "--repeats", "1", *extra]


def _quality(out: Path) -> list:
    """(row, model key, PSNR, SSIM, LPIPS) per row and seed of an ndrf-teacher table."""
    rows = json.loads((out / "ndrf-teacher.json").read_text())["rows"]
    return [(r["row"], p["model_key"], *(p[c] for c in QUALITY))
            for r in rows for p in r["per_seed"]]


def _trainings(cache_dir: Path) -> list[str]:
    """The model keys of every training the cache's log recorded."""
    lines = (cache_dir / "trainings.jsonl").read_text().splitlines()
    return [json.loads(line)["key"] for line in lines]


def _partial_files(cache_dir: Path) -> list[Path]:
    """Temporary files of atomic writes and scene folders left in the cache."""
    return [p for p in cache_dir.rglob("*")
            if (p.is_file() and _TEMPORARY.match(p.name)) or p.name.startswith(".tmp-scene-")]


def _descendants(pid: int) -> list[int]:
    """The processes below ``pid`` (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        kids = children.get(todo.pop(), [])
        out += kids
        todo += kids
    return out


def _training(pid: int) -> bool:
    """Whether process ``pid`` is a Ray task worker running ``_train`` with a run's
    log.jsonl open (mid-training)."""
    try:
        if Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0] != b"ray::_train":
            return False
        return any(os.readlink(fd).endswith("log.jsonl")
                   for fd in Path(f"/proc/{pid}/fd").iterdir())
    except OSError:
        return False


class _KillOnce(threading.Thread):
    """SIGKILLs the first Ray task worker of this process found training, once."""

    def __init__(self):
        super().__init__(daemon=True)
        self.killed, self.stop = [], threading.Event()

    def run(self):
        while not self.stop.is_set() and not self.killed:
            for pid in _descendants(os.getpid()):
                if _training(pid):
                    os.kill(pid, signal.SIGKILL)
                    self.killed.append(pid)
                    break
            time.sleep(0.2)


@pytest.mark.slow
def test_ray_table_equals_in_process_with_a_task_killed_once(ray_installed, small_scene,
                                                            tmp_path, one_torch_thread):
    killer = _KillOnce()
    killer.start()
    try:
        assert run.main(_table_args(small_scene, tmp_path / "c_ray", tmp_path / "o_ray",
                                    "--executor", "ray")) == 0
    finally:
        killer.stop.set()
    assert len(killer.killed) == 1                # a worker died mid-training, was retried
    assert run.main(_table_args(small_scene, tmp_path / "c_in", tmp_path / "o_in")) == 0
    ours, theirs = _quality(tmp_path / "o_ray"), _quality(tmp_path / "o_in")
    assert len(ours) == 4 and ours == theirs      # bit-identical models, same columns
    keys = {key for _, key, *_ in ours}
    assert sorted(_trainings(tmp_path / "c_ray")) == sorted(keys)   # each once, committed
    assert _partial_files(tmp_path / "c_ray") == []
    used = json.loads((tmp_path / "o_ray" / "ndrf-teacher.json").read_text())["cache"]
    assert set(used["models"]) == keys
    assert used["root"] == options.shown_path(tmp_path / "c_ray")   # ~/... under the home folder
    for trained_by in used["models"].values():
        assert trained_by["preset"] == "tiny" and trained_by["seed"] in (0, 1)
        assert trained_by["torch_threads"] == 1 and trained_by["versions"]["torch"]
        assert trained_by["host"] and trained_by["git_revision"]


@pytest.mark.slow
def test_two_processes_on_one_empty_cache_train_each_model_once(ray_installed, small_scene,
                                                               tmp_path):
    # One seed: the teacher and its student. The in-process run takes the teacher's lock
    # first, Ray's waits for it, and whichever is first to the student trains it.
    shared = tmp_path / "cache"
    procs = [subprocess.Popen([sys.executable, "-m", "bench.run",
                               *_table_args(small_scene, shared, tmp_path / name, *extra,
                                            seeds=1)],
                              cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True)
             for name, extra in (("o_in", ()), ("o_ray", ("--executor", "ray")))]
    try:
        errors = [p.communicate(timeout=1800)[1] for p in procs]
    finally:
        for p in procs:
            p.kill()
    assert [p.returncode for p in procs] == [0, 0], errors
    trained = _trainings(shared)
    assert len(trained) == 2 and len(set(trained)) == 2       # the teacher, the student
    assert _quality(tmp_path / "o_in") == _quality(tmp_path / "o_ray")
    assert _partial_files(shared) == []


def test_a_task_failing_for_its_own_reason_fails_with_its_error(ray_installed, small_scene,
                                                               tmp_path):
    plan = cache.plan_model(tmp_path, small_scene, cache.data_fingerprint(small_scene),
                            "tiny", "ngprt", {"variant": "separate-v", "L": 2})
    wrong = dataclasses.replace(plan, fingerprint="0" * 64)
    with cluster.Session() as session, pytest.raises(cluster.TaskFailed) as exc:
        session.train_all([wrong])
    message = str(exc.value)
    assert f"training ngprt (preset tiny, seed 0, model {plan.key}) failed: ValueError" in message
    assert "differs from the driver's" in message and "Traceback" not in message
    assert not plan.cached
    with plan.lock().acquire(timeout=0):          # released after the failure
        pass


def test_task_resources_from_the_preset_and_the_torch_device():
    assert cluster.task_resources("tiny", None, 0) == {"num_cpus": 1, "num_gpus": 0}
    assert cluster.task_resources("paper", "cuda", 0) == {"num_cpus": 8, "num_gpus": 1}
    assert cluster.task_resources("paper", None, 4.0) == {"num_cpus": 8, "num_gpus": 1}
    assert cluster.task_resources("cpu", "cpu", 4.0) == {"num_cpus": 2, "num_gpus": 0}


def test_the_default_executor_never_imports_ray():
    code = ("import sys; from bench import run; run.build_parser().parse_args(['table4']); "
            "assert 'ray' not in sys.modules, 'ray imported'")
    subprocess.run([sys.executable, "-c", code], cwd=REPO, check=True)


def test_address_needs_the_ray_executor(tmp_path, capsys):
    assert run.main(["table4", "--address", "auto", "--cache", str(tmp_path)]) == 2
    assert "--address is for --executor ray" in capsys.readouterr().err


def test_a_killed_holders_lock_is_recovered(tmp_path):
    path = tmp_path / "m" / ".lock"
    code = ("import sys, time; from pathlib import Path; from bench.modelcache import cache; "
            f"held = cache.lock(Path({str(path)!r})); held.acquire(); print('held', flush=True); "
            "time.sleep(120)")
    holder = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(Timeout):
            cache.lock(path).acquire(timeout=0.2)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with cache.lock(path).acquire(timeout=10):
        pass


def test_a_scene_two_threads_ask_for_is_made_once(tmp_path, monkeypatch):
    import clrender.data
    from clrender.data.scene import scene_key

    made = []

    def slow_make_scene(kind, out, seed):
        made.append(kind)
        time.sleep(0.5)
        (out / "transforms_train.json").write_text(json.dumps({"clrender": scene_key(kind, seed)}))
        return out

    monkeypatch.setattr(clrender.data, "make_scene", slow_make_scene)
    paths = []
    threads = [threading.Thread(target=lambda: paths.append(
        cache.resolve_scene("builtin-bounded", tmp_path))) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert made == ["bounded"] and len(paths) == 2 and paths[0] == paths[1]


def test_leftovers_of_a_killed_atomic_write_are_removed(tmp_path):
    target = tmp_path / "checkpoint.pt"
    code = ("import os; from clrender.atomic import atomic_write; "
            f"atomic_write({str(target)!r}, lambda tmp: (tmp.write_bytes(b'half'), os._exit(9)))")
    assert subprocess.run([sys.executable, "-c", code], cwd=REPO).returncode == 9
    (tmp_path / ".lock").write_text("")
    (tmp_path / "model.npz").write_bytes(b"whole")
    left = [p for p in tmp_path.iterdir() if p.name.startswith(".checkpoint.pt.")]
    assert len(left) == 1 and not target.exists()
    assert remove_leftovers(tmp_path) == left
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", "model.npz"]


def test_atomic_folder_appears_whole_or_not_at_all(tmp_path):
    target = tmp_path / "scene"

    def fail(folder):
        (folder / "a").write_text("x")
        raise RuntimeError("mid-way")

    with pytest.raises(RuntimeError, match="mid-way"):
        atomic_folder(target, fail)
    assert list(tmp_path.iterdir()) == []
    atomic_folder(target, lambda folder: (folder / "a").write_text("x"))
    assert (target / "a").read_text() == "x" and [p.name for p in tmp_path.iterdir()] == ["scene"]
    with pytest.raises(OSError):     # a folder with content is never replaced
        atomic_folder(target, lambda folder: (folder / "b").write_text("y"))
    assert [p.name for p in tmp_path.iterdir()] == ["scene"] and not (target / "b").exists()
