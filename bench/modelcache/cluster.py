"""Table rows trained as Ray tasks (``python -m bench.run TABLE --executor ray``).

Every model a table needs that is not cached becomes one Ray task, with a resource request
from its preset (:data:`TASK_CPUS`, and one GPU where training runs on CUDA); a row's
teacher is a task of its own whose baked file the row's task takes as an argument (one per
seed, shared by every row that names it, as the cache shares it).

Where models go: a worker trains in a private temporary folder and returns the baked model
and its run folder (bytes, through Ray's object store) to the driver, which writes them into
its cache (bench/modelcache/cache.py) under the model's lock. The cache is then only ever written on
the driver's machine: file locks on network file systems are unreliable (``flock`` over NFS
depends on the server and mount options), so a cache shared by all nodes would have to
trust them; with the driver owning the cache, nodes need no shared file system other than a
readable copy of the dataset at the same path (checked against its fingerprint), and
several drivers (bench.run processes, with either executor) on one machine share the cache
safely. The cost: a killed worker's training starts again from step 0 (it resumes in
process, where the run folder is the cache's), and every model crosses the network once.

Faults: a task whose worker process or node dies is retried (:data:`MAX_RETRIES`); a task
that raises (a bad config, a missing file) is not, and fails the table with its own error
(:class:`TaskFailed`). Measuring stays on the driver (bench/run.py), after the training.
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from tqdm import tqdm

from bench.modelcache import cache, provenance

# CPU cores a training task asks for, per preset; torch runs that many threads.
TASK_CPUS = {"tiny": 1, "cpu": 2, "cpu-long": 2, "paper": 8}
# Retries of a task whose worker died (Ray's max_retries); its own exceptions are not retried.
MAX_RETRIES = 2
REPO = Path(__file__).resolve().parents[2]


class TaskFailed(RuntimeError):
    """A training task raised: the model it trained and the task's own error."""


def task_resources(preset: str, torch_device: str | None, cluster_gpus: float) -> dict:
    """The task's Ray resources: ``num_cpus`` from the preset and ``num_gpus=1`` where the
    torch device is CUDA (``--torch-device cuda...``, or none given and the cluster has
    GPUs: the worker's torch then picks CUDA)."""
    cuda = (torch_device or "").startswith("cuda") or (torch_device is None and cluster_gpus > 0)
    return {"num_cpus": TASK_CPUS.get(preset, 2), "num_gpus": 1 if cuda else 0}


def _train(plan: cache.ModelPlan, teacher_baked: bytes | None, torch_device: str | None,
           threads: int, revision: str):
    """The task body: train ``plan`` in a temporary folder; returns (the baked model's
    bytes, ({path relative to the model folder: bytes}, the cache record)); ``revision``:
    the driver's git revision (a cluster's workers run an uploaded copy without .git)."""
    import torch

    torch.set_num_threads(threads)
    found = cache.data_fingerprint(plan.data, plan.downscale)
    if found != plan.fingerprint:
        raise ValueError(f"{plan.data}: this node's copy of the dataset differs from the "
                         f"driver's (fingerprint {found[:12]}, expected {plan.fingerprint[:12]})")
    with tempfile.TemporaryDirectory(prefix="clrender-task-") as tmp:
        folder, teacher = Path(tmp) / "model", None
        if teacher_baked is not None:
            teacher = Path(tmp) / "teacher.npz"
            teacher.write_bytes(teacher_baked)
        record = cache.train_into(plan, folder, teacher, torch_device, progress=False,
                                  revision=revision)
        files = {str(f.relative_to(folder)): f.read_bytes()
                 for f in sorted(folder.rglob("*")) if f.is_file()}
    return files["model.npz"], (files, record)


def unique_plans(plans: list[cache.ModelPlan]) -> list[cache.ModelPlan]:
    """Every plan and teacher once (by key), each teacher before the models it teaches."""
    out: dict[str, cache.ModelPlan] = {}

    def add(plan):
        if plan.teacher is not None:
            add(plan.teacher)
        out.setdefault(plan.key, plan)

    for plan in plans:
        add(plan)
    return list(out.values())


class Session:
    """A connection to Ray (``address``: None starts a local instance on this machine's
    cores; ``auto`` or ``ray://host:port`` joins a cluster), used as a context manager."""

    def __init__(self, address: str | None = None, torch_device: str | None = None):
        self.address, self.torch_device = address, torch_device

    def __enter__(self) -> "Session":
        from clrender.extras import require

        require("cluster", "--executor ray", modules=("ray",))
        import ray

        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        # Workers import bench/ (not an installed package): from this checkout locally,
        # from an uploaded copy of it on a cluster.
        env = ({"env_vars": {"PYTHONPATH": os.pathsep.join(
                   [str(REPO)] + [p for p in [os.environ.get("PYTHONPATH")] if p])}}
               if self.address is None else
               {"working_dir": str(REPO), "excludes": [".venv", ".git", "results", "*.npz"]})
        ray.init(address=self.address, runtime_env=env, log_to_driver=False,
                 include_dashboard=False, logging_level="WARNING")
        self.ray, self.gpus = ray, ray.cluster_resources().get("GPU", 0.0)
        self.revision = provenance.git_revision()
        self.remote = ray.remote(max_retries=MAX_RETRIES, num_returns=2)(_train)
        return self

    def __exit__(self, *exc) -> None:
        self.ray.shutdown()

    def train_all(self, plans: list[cache.ModelPlan], desc: str = "train") -> None:
        """Cache every model of ``plans`` (and their teachers): one task per model no
        process has cached or is training, waiting for those another process trains.
        One progress bar: models done / total, tasks running, found cached."""
        pending, cached = unique_plans(plans), 0
        running: dict = {}            # ObjectRef of (files, record) -> (plan, held lock)
        baked: dict = {}              # teacher's key -> ObjectRef of its baked bytes
        self._teachers = {p.teacher.key for p in pending if p.teacher is not None}
        with tqdm(total=len(pending), desc=desc, unit="model") as bar:
            try:
                while pending or running:
                    for plan in list(pending):
                        if self._start(plan, running, baked):
                            pending.remove(plan)
                            if plan.cached:   # before, or by another process meanwhile
                                cached += 1
                                bar.update()
                    bar.set_postfix(running=len(running), cached=cached)
                    self._collect(running, bar)
            finally:
                for ref, (plan, held) in running.items():
                    self.ray.cancel(ref, force=True)
                    held.release()

    def _start(self, plan, running: dict, baked: dict) -> bool:
        """Submit ``plan``'s task (True), or find it cached (True), or leave it for later
        (False: its teacher is not ready, or another process holds its lock)."""
        from filelock import Timeout

        if plan.cached:
            return True
        teacher = plan.teacher
        if teacher is not None and teacher.key not in baked:
            if not teacher.cached:
                return False          # another process trains it: wait for its meta.json
            baked[teacher.key] = self.ray.put((teacher.folder / "model.npz").read_bytes())
        held = plan.lock()
        try:
            held.acquire(timeout=0)
        except Timeout:
            return False
        if plan.cached:               # finished by another process since we looked
            held.release()
            return True
        res = task_resources(plan.preset, self.torch_device, self.gpus)
        bytes_ref, rest_ref = self.remote.options(**res).remote(
            plan, None if teacher is None else baked[teacher.key], self.torch_device,
            res["num_cpus"], self.revision)
        if plan.key in self._teachers:     # students' bytes are not kept in the store
            baked[plan.key] = bytes_ref
        running[rest_ref] = (plan, held)
        return True

    def _collect(self, running: dict, bar) -> None:
        """Store the results of finished tasks in the cache (or wait a second)."""
        if not running:
            time.sleep(1.0)           # only other processes' trainings are left
            return
        done, _ = self.ray.wait(list(running), num_returns=1, timeout=1.0)
        for ref in done:
            plan, held = running.pop(ref)
            try:
                files, record = self.ray.get(ref)
                cache.commit(plan, files, record)
            except self.ray.exceptions.RayError as e:   # its own error, or retries spent
                cause = getattr(e, "cause", None) or e
                raise TaskFailed(f"training {plan.method} (preset {plan.preset}, seed "
                                 f"{plan.seed}, model {plan.key}) failed: "
                                 f"{type(cause).__name__}: {cause}") from None
            finally:
                held.release()
            bar.update()
