"""Batches on Ray: assets bound in parallel by Ray worker processes, on one host or a cluster.

``run_batch(..., workers=N)`` starts a local Ray cluster with N worker slots (on a GPU host, default one per GPU:
each task asks for ``num_gpus=1``, Ray sets ``CUDA_VISIBLE_DEVICES``, and the worker's Warp sees only its GPU);
``ray_address=...`` joins a running cluster instead. The driver reads the manifest, skips up-to-date assets and
holds the folder's lock; each task binds one asset with :func:`warp_stokes.batch.run.bind_one`, which writes the
asset's outputs under temporary names in the output folder and renames them together (outputs go to a filesystem
that the workers share with the driver), and returns its :class:`Result` with the host, process and device.

Failures stay per asset: an error in a bind is that asset's result; a worker that dies (killed, out of memory) is
retried by Ray (:data:`TASK_RETRIES` times), and then reported as failed. Progress goes to stderr, one line per
asset finished, with the counts done / running / failed.

Ray is an optional extra: ``pip install "warp-stokes[ray]"``.
"""

from __future__ import annotations

import contextlib
import glob
import logging
import os
import signal

from ..device import require_ray
from .run import Result, bind_one, earlier_records, skipped, warn_for

__all__ = ["run_on_ray", "require_ray", "TASK_RETRIES", "KILL_ONCE_VARIABLE"]

#: times Ray runs a task again after its worker process died
TASK_RETRIES = 2
#: for fault-tolerance tests: a path in this environment variable makes the first task that finds the file there
#: remove it and kill its own worker process (SIGKILL), as a crash would
KILL_ONCE_VARIABLE = "WARP_STOKES_KILL_WORKER_ONCE"


def _bind_task(asset, outdir: str, device) -> Result:
    """One asset, in a Ray worker process."""
    marker = os.environ.get(KILL_ONCE_VARIABLE)
    if marker:
        try:
            os.unlink(marker)
        except FileNotFoundError:
            pass
        else:
            os.kill(os.getpid(), signal.SIGKILL)
    return bind_one(asset, outdir, device)


def _start(ray, workers: int | None, address: str | None, device) -> bool:
    """Connect to Ray; True when this call started a local cluster (which the batch then shuts down)."""
    if ray.is_initialized():
        return False
    env = {KILL_ONCE_VARIABLE: os.environ[KILL_ONCE_VARIABLE]} if os.environ.get(KILL_ONCE_VARIABLE) else {}
    options = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.ERROR,
               "runtime_env": {"env_vars": env} if env else None}
    if address is not None:
        ray.init(address=address, **options)
        return True
    on_cpu = device is not None and str(device).startswith("cpu")
    if workers is None:
        from ..device import cuda_device_count

        workers = (0 if on_cpu else cuda_device_count()) or os.cpu_count() or 1
    ray.init(num_cpus=int(workers), num_gpus=None if not on_cpu else 0, **options)
    return True


def _task_options(ray, workers: int | None, device) -> tuple[dict, str | None]:
    """Ray resources per task, and the device the task binds on: a whole GPU each when the cluster has GPUs (a
    share when more workers than GPUs are asked for), one CPU otherwise."""
    gpus = float(ray.cluster_resources().get("GPU", 0))
    if gpus > 0 and not (device is not None and str(device).startswith("cpu")):
        share = 1.0 if workers is None else min(1.0, gpus / max(1, int(workers)))
        return {"num_gpus": share, "num_cpus": 1}, "cuda:0"  # CUDA_VISIBLE_DEVICES leaves one: cuda:0
    return {"num_gpus": 0, "num_cpus": 1}, "cpu" if device is None else device


def _line(stream, done: int, total: int, running: int, failed: int, result: Result) -> None:
    where = f"{result.host} pid {result.pid}" + (f" {result.device}" if result.device else "")
    print(f"[{done}/{total} done, {running} running, {failed} failed] {result.name}: {result.status} "
          f"({where}, {result.seconds:.1f} s)" + (f": {result.error}" if result.error else ""), file=stream,
          flush=True)


def run_on_ray(assets, outdir: str, manifest, force: bool, device, progress, workers: int | None,
               address: str | None) -> list[Result]:
    """Bind the assets as Ray tasks; the results in manifest order (see the module docstring)."""
    ray = require_ray()
    started = _start(ray, workers, address, device)
    try:
        options, task_device = _task_options(ray, workers, device)
        task = ray.remote(_bind_task).options(max_retries=TASK_RETRIES, retry_exceptions=False, **options)
        results: list[Result | None] = [None] * len(assets)
        pending = {}
        earlier = earlier_records(outdir)
        for k, asset in enumerate(assets):
            results[k] = skipped(asset, outdir, manifest, force, earlier)
            if results[k] is None:
                pending[task.remote(asset, outdir, task_device)] = k
        total, failed = len(assets), 0
        done = sum(r is not None for r in results)
        while pending:
            finished, _ = ray.wait(list(pending), num_returns=1)
            k = pending.pop(finished[0])
            try:
                result = ray.get(finished[0])
            except Exception as exc:  # the task could not run: its worker died every time, or it failed to start
                reason = " ".join(str(exc).split())[:300]
                died = isinstance(exc, (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError))
                what = f"its worker died ({TASK_RETRIES + 1} tries)" if died else "the Ray task failed"
                result = Result(assets[k].name, "failed", resolution=assets[k].resolution, outputs=[],
                                error=f"{what}: {type(exc).__name__}: {reason}")
            results[k] = result
            done += 1
            failed += result.status == "failed"
            warn_for(result)
            if progress:
                _line(progress, done, total, len(pending), failed, result)
        # no task runs any more and the folder is locked: what dead workers left is removed
        for stale in glob.glob(os.path.join(outdir, ".tmp-*")):
            with contextlib.suppress(OSError):
                os.unlink(stale)
        return results
    finally:
        if started:
            ray.shutdown()
