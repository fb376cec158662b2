"""Choosing the Warp device, once: CUDA when present, else the CPU. What is chosen travels as a :class:`Backend`,
the device and the CPU threads that share its work, made where a command or a public function starts
(:meth:`Backend.of`); nothing below resolves a device again."""

from __future__ import annotations

import os
import sys
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass

import warp as wp

from .errors import WarpStokesError
from .kernel_cache import compile_kernels
from .memory import available_memory
from .threads import cpu_threads

# Warp prints a banner on initialisation; a library should stay quiet unless asked.
wp.config.log_level = wp.LOG_WARNING

__all__ = ["Backend", "resolve_device", "init_warp", "device_name", "cuda_device_count"]


def resolve_device(device=None) -> wp.context.Device:
    """The Warp device to run on.

    Parameters
    ----------
    device : None | str | warp Device
        ``None`` picks ``"cuda:0"`` when a CUDA device is present, else ``"cpu"``; ``"cuda"`` means the
        current CUDA device.

    Returns
    -------
    warp Device

    Raises
    ------
    WarpStokesError
        When the device does not exist (e.g. ``"cuda"`` on a machine without a GPU).

    Examples
    --------
    >>> resolve_device("cpu").alias
    'cpu'
    """
    if isinstance(device, wp.Device):  # resolved already, where a command or bind() started
        return device
    init_warp()
    if device is None:
        device = "cuda:0" if wp.is_cuda_available() else "cpu"
    if isinstance(device, str) and device.startswith("cuda") and not wp.is_cuda_available():
        raise WarpStokesError(f"device {device!r} is not available: no CUDA driver or GPU was found on this "
                              "machine (use --device cpu, or leave the device out)")
    try:
        return wp.get_device(device)
    except Exception as exc:
        available = ", ".join(d.alias for d in wp.get_devices())
        raise WarpStokesError(f"device {device!r} is not available ({exc}); available: {available}") from None


#: what Warp's native start-up prints on every machine without a GPU: a CPU command should not (a request for
#: CUDA there is answered by resolve_device's own error)
_NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"


def init_warp() -> None:
    """``wp.init()``, without Warp's start-up warning that no CUDA driver was found; anything else it prints on
    stderr is passed on. Its native code writes to file descriptor 2, so that is what is redirected, once."""
    if any(getattr(sys.modules.get(name), "runtime", None) is not None for name in ("warp._src.context", "warp.context")):
        return  # initialised already
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no usable stderr (embedded interpreters): just initialise
        wp.init()
        return
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        text = captured.read().decode(errors="replace")
    rest = "".join(line for line in text.splitlines(True) if _NO_DRIVER not in line)
    if rest:
        sys.stderr.write(rest)


def device_name(device) -> str:
    """A readable name such as ``"cuda:0 (NVIDIA H200)"`` or ``"cpu"`` (``device``: a Warp device or its alias)."""
    d = wp.get_device(device)
    return f"{d.alias} ({d.name})" if d.is_cuda else d.alias


def cuda_device_count() -> int:
    """CUDA devices this process can see (0 without a driver): a batch on Ray starts one worker per GPU."""
    init_warp()
    return int(wp.get_cuda_device_count()) if wp.is_cuda_available() else 0


#: ranges per thread in :meth:`Backend.in_threads`: the work along a lattice's slabs is uneven (a body's slabs or the
#: empty ones beside it), and threads that take ranges as they come free even it out
RANGES_PER_THREAD = 4

# Thread pools of Backend.in_threads that no call is using, by their number of threads: a call takes one (or makes
# one) and gives it back when its work is done, so that its threads are started once, not on every call (starting
# and joining them took about 1.3 ms a call on 2 cores, against 0.1 ms to hand work to running ones). Calls at once
# (several lanes, or a call inside another's work) each have a pool of their own, as when each made its own.
_IDLE_POOLS: dict[int, list[ThreadPoolExecutor]] = {}
_IDLE_LOCK = threading.Lock()


def _forget_idle_pools() -> None:
    """In a process forked from this one the pools' threads do not exist: it makes its own."""
    global _IDLE_LOCK
    _IDLE_POOLS.clear()
    _IDLE_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_idle_pools)


def _take_pool(lanes: int) -> ThreadPoolExecutor:
    with _IDLE_LOCK:
        idle = _IDLE_POOLS.get(lanes)
        if idle:
            return idle.pop()
    return ThreadPoolExecutor(max_workers=lanes, thread_name_prefix="warp-stokes")


def _give_back(lanes: int, pool: ThreadPoolExecutor) -> None:
    with _IDLE_LOCK:
        _IDLE_POOLS.setdefault(lanes, []).append(pool)


@dataclass(frozen=True)
class Backend:
    """Where a computation runs: a Warp device, and on a CPU the threads that share its launches (Warp runs a CPU
    launch on the thread that makes it, without the GIL, so launches over disjoint ranges run at once).

    The one place the CPU-or-GPU choice is made: a kernel with CPU and GPU twins is taken with :meth:`pick`, and
    :attr:`on_cpu` says which launch shape to use where the twins differ in more than the kernel.

    Attributes
    ----------
    device : warp Device
    threads : int, CPU threads (1 on a GPU, whose launches fill it alone)

    Examples
    --------
    >>> cpu = Backend.of("cpu", threads=2)
    >>> cpu.alias, cpu.threads, cpu.pick(cpu="node loop", gpu="patch walk")
    ('cpu', 2, 'node loop')
    >>> Backend.of(cpu) is cpu
    True
    """

    device: wp.context.Device
    threads: int = 1

    @classmethod
    def of(cls, device=None, threads: int | None = None) -> "Backend":
        """The backend for what a user gave: None (CUDA when present, else the CPU), a device's name (``"cpu"``,
        ``"cuda"``, ``"cuda:1"``), a Warp device, or a Backend (returned as it is, ``threads`` ignored). On a CPU,
        ``threads`` threads (default: every core the process may use, :func:`warp_stokes.threads.cpu_threads`)."""
        if isinstance(device, Backend):
            return device
        resolved = resolve_device(device)
        if resolved.is_cpu:
            return cls(resolved, cpu_threads(threads))
        if threads is not None:
            cpu_threads(threads)  # a bad number is refused on every device
        return cls(resolved, 1)

    @property
    def on_cpu(self) -> bool:
        return self.device.is_cpu

    @property
    def kind(self) -> str:
        """``"cpu"`` or ``"cuda"``."""
        return "cpu" if self.device.is_cpu else "cuda"

    @property
    def alias(self) -> str:
        return self.device.alias

    @property
    def name(self) -> str:
        """A readable name such as ``"cuda:0 (NVIDIA H200)"`` or ``"cpu"``."""
        return device_name(self.device)

    def pick(self, cpu, gpu):
        """``cpu`` on a CPU, else ``gpu``: the twin of a kernel (or a module of kernels, or a constant) for this
        device."""
        return cpu if self.device.is_cpu else gpu

    def lanes(self, n: int) -> int:
        """Threads that share ``n`` pieces of work at once: at most :attr:`threads`, 1 on a GPU."""
        return max(1, min(self.threads, int(n)))

    def with_threads(self, threads: int) -> "Backend":
        """The same device with ``threads`` threads (a CPU's lanes, each solving a chunk on one thread)."""
        return Backend(self.device, self.pick(cpu=cpu_threads(threads), gpu=1))

    def available_memory(self) -> int:
        """Bytes a bind may use here (:func:`warp_stokes.memory.available_memory`)."""
        return available_memory(self.device)

    def scope(self) -> wp.ScopedDevice:
        return wp.ScopedDevice(self.device)

    def synchronize(self) -> None:
        wp.synchronize_device(self.device)

    def reduction_threads(self, n_rows: int, n_cols: int) -> int:
        """Threads per column for column reductions (``kernels.cg.column_dots``): enough to fill a GPU, few on the
        CPU (its launches are serial)."""
        return int(max(1, min(n_rows, self.pick(cpu=16, gpu=-(-(1 << 17) // n_cols)))))

    def in_threads(self, n: int, work, modules=()) -> None:
        """``work(start, stop)`` over consecutive ranges that cover ``range(n)``: on a CPU shared out between the
        backend's threads, elsewhere once over all of it. Warp's default device is one for all threads: it is held
        at this device meanwhile, so that a scope inside ``work`` finds and restores that. The kernel modules
        ``work`` launches (names as in :data:`warp_stokes.kernel_cache.KERNEL_MODULES`) are loaded first, on this
        thread: Warp's module loading is not made for several threads at once. The call returns (or raises the first
        range's error) once every range is done; its threads are kept for the next call.

        Examples
        --------
        >>> seen = []
        >>> Backend.of("cpu", threads=2).in_threads(10, lambda a, b: seen.append((a, b)))
        >>> sorted(seen)
        [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
        """
        lanes = self.lanes(n)
        if lanes <= 1:
            if n > 0:
                work(0, n)
            return
        if modules:
            compile_kernels(self.device, modules=modules)
        size = -(-n // (lanes * RANGES_PER_THREAD))
        ranges = [(a, min(a + size, n)) for a in range(0, n, size)]
        pool = _take_pool(lanes)
        try:
            with self.scope():
                done = [pool.submit(work, a, b) for a, b in ranges]
                try:
                    for future in done:
                        future.result()
                finally:  # on an error or an interrupt too: no range left running
                    wait(done)
        finally:
            _give_back(lanes, pool)
