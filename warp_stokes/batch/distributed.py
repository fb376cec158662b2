"""Batches on Ray: assets bound in parallel by long-lived Ray worker processes, on one host or a cluster.

``run_batch(..., workers=N)`` starts a new local Ray cluster with N worker slots (on a GPU host, default one per GPU:
each worker asks for ``num_gpus=1``, Ray sets ``CUDA_VISIBLE_DEVICES``, and the worker's Warp sees only its GPU);
``ray_address=...`` joins a running cluster instead (one worker per CPU slot, or per GPU). A batch with nothing to do
(everything up to date) starts or joins no cluster. A new local cluster is started by a child process
(:class:`LocalHead`) while this one binds the first assets itself: Ray starts its processes by forking, and a fork
while this process is inside a multithreaded BLAS call can leave that call waiting for ever (it did, twice in about
a dozen batches on 2 cores, when this process started Ray on a thread of its own while binding).

The driver reads the manifest, skips up-to-date assets and holds the folder's lock. Each worker is a Ray actor
(:class:`BindWorker`) made at the start: it imports, starts Warp on its device and loads the kernels once, while the
others do the same, then binds one asset at a time, the next handed to it as soon as it is done. It binds with
:func:`warp_stokes.batch.asset.bind_one`, which writes the asset's outputs under temporary names in the output folder
and renames them together (outputs go to a filesystem that the workers share with the driver), and returns its
:class:`Result` with the host, process and device.

Failures stay per asset: an error in a bind is that asset's result. A worker whose process dies (killed, out of
memory, its node lost) is started again by Ray where there is room, and gets assets again once it answers; the asset
it was binding goes back to the front of the queue, for any worker, and fails after dying with its worker
:data:`TASK_RETRIES` + 1 times. Progress goes to stderr, one line per asset as it starts (the worker says so on a Ray
queue) and as it finishes, with the counts done / running / failed.

Ray is an optional extra: ``pip install "warp-stokes[ray]"``.
"""

from __future__ import annotations

import collections
import contextlib
import importlib
import logging
import math
import os
import signal
import threading
import time

from ..cluster import require_ray, start_ray
from ..errors import WarpStokesError
from ..threads import cpu_threads
from ..io.outputs import remove_temporaries_of
from .asset import Result, bind_one, outputs_of, up_to_date, warn_for

__all__ = ["run_on_ray", "require_ray", "BindWorker", "TASK_RETRIES", "KILL_ONCE_VARIABLE"]

#: times an asset is bound again after its worker process died while binding it
TASK_RETRIES = 2
#: for fault-tolerance tests: a path in this environment variable makes the first asset's call that finds the file there
#: remove it and kill its own worker process (SIGKILL), as a crash would
KILL_ONCE_VARIABLE = "WARP_STOKES_KILL_WORKER_ONCE"


class BindWorker:
    """One worker slot of a batch on Ray, as a Ray actor: a process started once per slot that warms up as soon as it
    is made (imports the bind's modules, starts Warp on its device, loads a bind's kernels), then binds the assets it
    is handed one after another. Ray starts it again when its process dies; the batch hands its asset to another
    worker (see the module docstring).

    Parameters
    ----------
    device : str, the device the worker binds on (``"cuda:0"``: the GPU Ray gave it)
    threads : int | None, a CPU bind's threads
    harmonic : bool, load the Laplace kernels too (an asset of the batch binds harmonic coordinates)
    """

    def __init__(self, device: str, threads: int | None = None, harmonic: bool = False):
        import socket

        self.device, self.threads = device, threads
        self.host, self.pid = socket.gethostname(), os.getpid()
        with contextlib.suppress(Exception):  # a worker that cannot warm up says why in its first asset's result
            from ..device import Backend
            from ..kernel_cache import BIND_MODULES, compile_kernels

            backend = Backend.of(device, threads)
            compile_kernels(backend.device, BIND_MODULES + (("laplace",) if harmonic else ()))
            importlib.import_module("..binding.pipeline", __package__)  # a bind's other imports: now, not at the first

    def where(self) -> tuple[str, int]:
        """(host, pid): once it answers, the worker is up and warm."""
        return self.host, self.pid

    def bind(self, asset, outdir: str, started=None, k: int = 0, inputs=None, unreadable: str | None = None,
             digest: str | None = None) -> Result:
        """One asset (:func:`warp_stokes.batch.asset.bind_one`); it says it started on ``started`` (a Ray queue, or
        None)."""
        if started is not None:
            with contextlib.suppress(Exception):  # a lost progress line must not fail the asset
                started.put_nowait((k, self.host, self.pid, time.time()))
        marker = os.environ.get(KILL_ONCE_VARIABLE)
        if marker:
            try:
                os.unlink(marker)
            except FileNotFoundError:
                pass
            else:
                os.kill(os.getpid(), signal.SIGKILL)
        return bind_one(asset, outdir, self.device, threads=self.threads, inputs=inputs, unreadable=unreadable,
                        digest=digest)


def _options() -> dict:
    env = {KILL_ONCE_VARIABLE: os.environ[KILL_ONCE_VARIABLE]} if os.environ.get(KILL_ONCE_VARIABLE) else {}
    return {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.ERROR,
            "runtime_env": {"env_vars": env} if env else None}


#: the child process that starts a new local cluster for the batch: it prints the cluster's address (or why it could
#: not start one) and keeps the cluster up until its standard input closes (the batch is done, or gone)
_HEAD = """
import json, os, sys
options = json.loads(sys.argv[1])
try:
    import ray
    context = ray.init(address="local", **options)
except Exception as exc:
    print("error", " ".join(str(exc).split())[:200] or type(exc).__name__, flush=True)
    sys.exit(1)
print("address", context.address_info["gcs_address"], os.environ.get("RAY_AUTH_MODE", ""), flush=True)
sys.stdin.read()
ray.shutdown()
"""


class LocalHead:
    """A new local Ray cluster for one batch, started by a child process while this one binds the first assets.

    Ray starts its processes by forking; this process may by then be inside a multithreaded BLAS call (a bind's
    coarsest level), and a fork there can leave that call waiting for ever. The child forks instead, from a single
    thread. ``address()`` is None until the cluster is up; :meth:`close` ends it (the child shuts the cluster down
    when its standard input closes, also when this process dies).

    Parameters
    ----------
    cpus : int, the cluster's CPU slots: one per worker (Ray starts that many idle worker processes at once, so
        not every core of a large host)
    gpus : int | None, its GPUs (None: as many as Ray finds)
    """

    def __init__(self, cpus: int, gpus: int | None):
        import json
        import subprocess
        import sys

        options = {"num_cpus": int(cpus), "include_dashboard": False, "logging_level": logging.ERROR}
        if gpus is not None:
            options["num_gpus"] = int(gpus)
        self.process = subprocess.Popen([sys.executable, "-c", _HEAD, json.dumps(options)], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self._said: list[str] = []  # the child's one line, read on a thread of its own (pipes cannot be polled
        self._ready = threading.Event()  # on every system)
        threading.Thread(target=self._read, daemon=True).start()
        self._address = None
        self.auth_mode = ""  # the cluster's RAY_AUTH_MODE, once it is up

    def _read(self) -> None:
        with contextlib.suppress(Exception):  # a pipe closed under it: the child ended, as wait() says
            self._said.append(self.process.stdout.readline())
        self._ready.set()

    def address(self, wait: float | None = 0.0) -> str | None:
        """The cluster's address once it is up, else None (after ``wait`` seconds; None: until it is).

        Raises
        ------
        WarpStokesError
            When the child could not start the cluster.
        """
        if self._address is None and self._ready.wait(wait):
            line = (self._said or [""])[0].split(maxsplit=1)
            if len(line) == 2 and line[0] == "address":
                self._address, *mode = line[1].split()
                self.auth_mode = mode[0] if mode else ""
            else:
                why = line[1].strip() if len(line) == 2 else f"its process ended, exit code {self.process.wait()}"
                raise WarpStokesError(f"could not start Ray ({why})")
        return self._address

    def close(self) -> None:
        """End the cluster: the child shuts it down and ends by itself, after this returns (a second or two; Ray's
        processes stop gracefully, which takes that long). The batch does not wait for it."""
        with contextlib.suppress(OSError):
            self.process.stdin.close()
        # (its output is closed once it has ended: the reading thread may still be waiting on it)
        for ended in [p for p in _ENDING if p.poll() is not None]:
            ended.stdout.close()
            _ENDING.remove(ended)
        _ENDING.append(self.process)


#: local clusters' child processes still shutting down after their batch (kept to be reaped, not warned of)
_ENDING: list = []


def _use_auth_mode(mode: str) -> None:
    """Join a cluster with the authentication it was started with: a new local cluster uses a token by default
    (Ray 2.5x, ``RAY_AUTH_MODE=token``, the token in ``~/.ray/auth_token``), and ``ray.init(address=...)`` looks for
    one only when told to. The process stays in token mode after, as one that ran ``ray.init(address="local")``
    does (Ray keeps what it read)."""
    if mode != "token" or os.environ.get("RAY_AUTH_MODE") == "token":
        return
    os.environ["RAY_AUTH_MODE"] = "token"
    with contextlib.suppress(ImportError):
        from ray._raylet import Config

        Config.initialize("")  # Ray's configuration, read once at import, read again


def _slots(ray, workers: int | None, device, local: bool) -> tuple[int, dict, str | None, int | None]:
    """How many workers, the Ray resources of each, the device each binds on, and a CPU bind's threads: one per GPU
    when the cluster has GPUs (a share of one when more workers than GPUs are asked for), one per CPU slot
    otherwise, each taking one CPU slot (Ray sets ``OMP_NUM_THREADS=1`` for it: BLAS on one thread, which gives the
    weights of a bind in one process bit for bit, measured on one H200). On a local cluster of CPU workers, each
    bind's threads are this host's cores over the workers (the machine full, not oversubscribed); on a joined
    cluster one thread per worker, as its slot says."""
    resources = ray.cluster_resources()
    gpus = float(resources.get("GPU", 0))
    if gpus > 0 and not _on_cpu(device):
        count = int(gpus) if workers is None else max(1, int(workers))
        # a share must fit on one GPU with the others there: 3 workers on 2 GPUs take half of one each (two on one,
        # one on the other), not two thirds (one a GPU, the third never placed); Ray counts in ten-thousandths, so
        # the share is rounded down (six sixths rounded up would not fit on one)
        share = 1.0 if count <= gpus else math.floor(10_000 / math.ceil(count / gpus)) / 10_000
        return count, {"num_gpus": share, "num_cpus": 1}, "cuda:0", None  # CUDA_VISIBLE_DEVICES leaves one: cuda:0
    slots = max(1, int(resources.get("CPU", 1)))
    threads = max(1, cpu_threads() // slots) if local else 1
    return slots, {"num_gpus": 0, "num_cpus": 1}, "cpu" if device is None else device, threads


def _counts(done: int, total: int, running: int, failed: int) -> str:
    return f"[{done}/{total} done, {running} running, {failed} failed]"


def _line(stream, done: int, total: int, running: int, failed: int, result: Result) -> None:
    where = f"{result.host} pid {result.pid}" + (f" {result.device}" if result.device else "")
    print(f"{_counts(done, total, running, failed)} {result.name}: {result.status} "
          f"({where}, {result.seconds:.1f} s)" + (f": {result.error}" if result.error else ""), file=stream,
          flush=True)


def _died(ray, exc: Exception) -> bool:
    """Whether a call failed because its worker's process or node died (or is being started again)."""
    kinds = tuple(getattr(ray.exceptions, name) for name in ("WorkerCrashedError", "NodeDiedError", "RayActorError",
                                                             "ActorUnavailableError") if hasattr(ray.exceptions, name))
    return isinstance(exc, kinds)


def _failed(asset, why: str) -> Result:
    return Result(asset.name, "failed", resolution=asset.resolution, outputs=[], error=why)


def _started_queue(ray, progress):
    """A queue the workers put (asset index, host, pid, time) on as they start an asset, when progress is shown;
    else None."""
    if not progress:
        return None
    from ray.util.queue import Queue

    # it takes no CPU slot: the workers have them all
    return Queue(actor_options={"num_cpus": 0})


def _drain(queue) -> list:
    """What the workers said since the last call (nothing when there is no queue or it is gone)."""
    if queue is None:
        return []
    try:
        return queue.get_nowait_batch(queue.qsize())
    except Exception:  # the queue's actor died: no start lines, the batch goes on
        return []


def _local_slots(workers: int | None, device) -> tuple[int, int | None]:
    """A new local cluster's workers (on a GPU host, default one per GPU; else one per core) and GPUs (None: as many
    as Ray finds; 0 for a CPU batch)."""
    on_cpu = _on_cpu(device)
    if workers is None:
        from ..device import cuda_device_count

        workers = (0 if on_cpu else cuda_device_count()) or os.cpu_count() or 1
    return int(workers), 0 if on_cpu else None


def _on_cpu(device) -> bool:
    """Whether the batch was asked to bind on CPUs (default: the GPUs where there are some)."""
    return device is not None and str(device).startswith("cpu")


class _Progress:
    """The batch's results as they come, and its progress lines: each asset as it starts (on which host and process)
    and as it finishes, with the counts done / running / failed, in the order it happened."""

    def __init__(self, assets, results: list, stream):
        self.assets, self.results, self.stream = assets, results, stream
        self.done, self.failed = sum(r is not None for r in results), 0
        self.running: set[int] = set()
        self.began: dict[int, float] = {}  # asset -> when it last started (the binding host's clock)
        self.workers_seen = set()  # (host, pid) of every process that bound an asset

    def say(self, events) -> None:
        """``events``: (asset, (host, pid, time)) for a start, (asset, Result) for an end."""
        timed = []
        for k, what in events:
            if isinstance(what, tuple):
                self.began[k] = what[2]
                self.workers_seen.add(what[:2])
                timed.append((what[2], 0, k, what))
            else:
                if what.host and what.pid:
                    self.workers_seen.add((what.host, what.pid))
                # it ended its bind's seconds after it started (the same clock), else now
                timed.append((self.began[k] + what.seconds if k in self.began else time.time(), 1, k, what))
        for _, _, k, what in sorted(timed, key=lambda e: e[:3]):
            if isinstance(what, tuple):  # started
                if self.results[k] is not None:  # a start said after the asset's end: nothing to say
                    continue
                again = k in self.running  # bound again after its worker died
                self.running.add(k)
                if self.stream:
                    print(f"{self._counts()} {self.assets[k].name}: {'started again' if again else 'started'} "
                          f"({what[0]} pid {what[1]})", file=self.stream, flush=True)
                continue
            self.running.discard(k)
            self.results[k] = what
            self.done += 1
            self.failed += what.status == "failed"
            warn_for(what)
            if self.stream:
                _line(self.stream, self.done, len(self.assets), len(self.running), self.failed, what)

    def _counts(self) -> str:
        return _counts(self.done, len(self.assets), len(self.running), self.failed)


def run_on_ray(assets, outdir: str, manifest, force: bool, device, progress, workers: int | None,
               address: str | None, inputs: dict | None = None, unreadable: dict | None = None) -> list[Result]:
    """Bind the assets on Ray workers; the results in manifest order (see the module docstring)."""
    import socket

    ray = require_ray()
    inputs, unreadable = inputs or {}, unreadable or {}
    digests, results = up_to_date(assets, outdir, force, inputs)
    todo = [k for k, r in enumerate(results) if r is None]
    if not todo:  # everything up to date: no cluster to start or join
        return results
    said = _Progress(assets, results, progress)
    waiting = collections.deque(todo)
    me = (socket.gethostname(), os.getpid())
    ours, head = not ray.is_initialized(), None  # else: a cluster this process is connected to, left as it is
    try:
        if ours and address is not None:
            start_ray(ray, address=address, **_options())
        elif ours:
            from ..binding.spread import spread_devices

            slots, gpus = _local_slots(workers, device)
            head = LocalHead(slots, gpus)
            # until the cluster is up, this process binds, as one of its workers would (not a bind spread over
            # several devices: that would start Ray here)
            binds_here = spread_devices(device) is None
            if binds_here:
                on_cpu = gpus == 0 or not _has_cuda()
                here_device = (device or "cpu") if on_cpu else (device or "cuda:0")
                threads = max(1, cpu_threads() // slots) if on_cpu else None
            try:
                while binds_here and waiting and head.address() is None:
                    k = waiting.popleft()
                    said.say([(k, (*me, time.time()))])
                    said.say([(k, bind_one(assets[k], outdir, here_device, threads=threads,
                                           inputs=inputs.get(assets[k].name),
                                           unreadable=unreadable.get(assets[k].name), digest=digests[k]))])
                if waiting:
                    up = head.address(wait=None)
                    _use_auth_mode(head.auth_mode)
                    start_ray(ray, address=up, **_options())
            except WarpStokesError as exc:  # no cluster: what is bound stays, the rest fails saying why
                while waiting:
                    k = waiting.popleft()
                    said.say([(k, _failed(assets[k], str(exc)))])
        if waiting:
            _bind_on_workers(ray, assets, outdir, said, waiting, workers, device, local=head is not None,
                             inputs=inputs, unreadable=unreadable, digests=digests)
        # no worker binds any more and the folder is locked: what this batch's workers left (a worker killed
        # mid-write, on any host) is removed; nothing of anyone else's
        remove_temporaries_of(outdir, said.workers_seen - {me})
        return results
    finally:
        if ours and ray.is_initialized():
            ray.shutdown()
        if head is not None:
            head.close()


def _has_cuda() -> bool:
    from ..device import cuda_device_count

    return cuda_device_count() > 0


def _bind_on_workers(ray, assets, outdir: str, said: _Progress, waiting, workers, device, local: bool, inputs,
                     unreadable, digests) -> None:
    """The ``waiting`` assets bound by :class:`BindWorker` actors, one per slot of the cluster ``ray`` is connected
    to, said on ``said`` as they start and end; the actors and the progress queue are ended after (on a cluster
    that stays up, their slots are given back)."""
    count, options, worker_device, threads = _slots(ray, workers, device, local=local)
    harmonic = any(assets[k].method == "harmonic" for k in waiting)
    folder = os.path.abspath(outdir)  # a worker's working folder is not this process's (another host's, even)
    # Ray starts a dead worker again, but does not run its call again: the asset goes to whichever worker is free
    # (a call queued behind one that kills its worker would otherwise be charged that death too, and a worker
    # waiting for a slot to start again in would hold its asset for ever)
    worker = ray.remote(BindWorker).options(max_restarts=-1, max_task_retries=0, **options)
    pool = [worker.remote(worker_device, threads, harmonic) for _ in range(min(count, len(waiting)))]
    started = _started_queue(ray, said.stream)
    deaths = collections.Counter()  # asset -> times its worker died while binding it
    try:
        # a worker gets an asset once it has answered (is up and warm: a worker a joined cluster has no room for
        # gets none; one started again answers again), then each time it is done with one
        greetings = {w.where.remote(): i for i, w in enumerate(pool)}
        free: collections.deque[int] = collections.deque()
        pending = {}  # call -> (asset, worker)

        def hand() -> None:
            while waiting and free:
                i, k = free.popleft(), waiting.popleft()
                call = pool[i].bind.remote(assets[k], folder, started, k, inputs.get(assets[k].name),
                                           unreadable.get(assets[k].name), digests[k])
                pending[call] = (k, i)

        while pending or (waiting and greetings):
            calls = list(pending) + list(greetings)
            # with progress, at least every half second what started and finished meanwhile
            finished, rest = ray.wait(calls, num_returns=1, timeout=None if started is None else 0.5)
            if finished and rest:  # and all else that is done by now
                finished += ray.wait(rest, num_returns=len(rest), timeout=0)[0]
            events = [(k, (host, pid, when)) for k, host, pid, when in _drain(started)]
            for call in finished:
                if call in greetings:
                    i = greetings.pop(call)
                    try:
                        said.workers_seen.add(tuple(ray.get(call)))
                    except Exception:  # it could not start: the assets go to the others
                        continue
                    free.append(i)
                    continue
                k, i = pending.pop(call)
                try:
                    result = ray.get(call)
                except Exception as exc:
                    if not _died(ray, exc):
                        reason = " ".join(str(exc).split())[:300]
                        events.append((k, _failed(assets[k], f"the Ray call failed: {type(exc).__name__}: {reason}")))
                        free.append(i)
                        continue
                    # it gets assets again once Ray has started it again (a call to it meanwhile would fail)
                    greetings[pool[i].where.options(max_task_retries=-1).remote()] = i
                    deaths[k] += 1
                    if deaths[k] > TASK_RETRIES:
                        events.append((k, _failed(assets[k], f"its worker died ({deaths[k]} tries)")))
                    else:
                        waiting.appendleft(k)
                    continue
                if result.outputs:  # as this process names them
                    result.outputs = outputs_of(assets[k], outdir)
                events.append((k, result))
                free.append(i)
            hand()
            said.say(events)
        while waiting:  # no worker ever started
            k = waiting.popleft()
            said.say([(k, _failed(assets[k], "no Ray worker could start"))])
    finally:
        for actor in pool:
            with contextlib.suppress(Exception):
                ray.kill(actor)
        if started is not None:
            with contextlib.suppress(Exception):
                started.shutdown()


