"""Choosing the Warp device: CUDA when present, else the CPU."""

from __future__ import annotations

import os
import sys
import tempfile

import numpy as np
import warp as wp

from .errors import WarpStokesError

# Warp prints a banner on initialisation; a library should stay quiet unless asked.
wp.config.log_level = wp.LOG_WARNING

__all__ = ["resolve_device", "init_warp", "device_name", "available_memory", "memory_size", "cpu_threads",
           "cgroup_cpu_limit", "in_threads", "reduction_threads", "require_ray", "compile_kernels", "kernels_compiled",
           "announce_compilation"]


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
    """A readable name such as ``"cuda:0 (NVIDIA H100 80GB HBM3)"`` or ``"cpu"``."""
    d = resolve_device(device)
    return f"{d.alias} ({d.name})" if d.is_cuda else d.alias


def available_memory(device=None) -> int:
    """Bytes a bind may use on ``device``: 90% of the free memory of a CUDA device, half the available RAM on
    the CPU."""
    d = resolve_device(device)
    if d.is_cuda:
        return int(0.9 * d.free_memory)
    try:
        return int(0.5 * os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def cgroup_cpu_limit(root: str = "/sys/fs/cgroup", membership: str = "/proc/self/cgroup") -> int | None:
    """The cores a container's CPU quota allows this process (Linux control groups: ``cpu.max`` of v2, the CFS
    quota and period of v1; the tightest along the process's group and its parents), rounded up; None without a
    quota. A container limited to 2 CPUs on a 64-core host still has all 64 in its affinity: threads beyond the
    quota only wait.

    Examples
    --------
    >>> cgroup_cpu_limit(root="/nonexistent") is None
    True
    """
    import math

    def words(path):
        try:
            with open(path, encoding="ascii") as fh:
                return fh.read().split()
        except (OSError, UnicodeDecodeError):
            return []

    def upwards(folder, group):  # the group's folder and its parents' up to the hierarchy's root
        path = group.strip("/")
        while True:
            yield os.path.join(folder, path)
            if not path:
                return
            path = os.path.dirname(path)

    groups = {}  # controllers ("" for the v2 hierarchy, "cpu,cpuacct" for v1's) -> the process's group
    try:
        with open(membership, encoding="utf-8") as fh:
            lines = fh.read().splitlines()
    except (OSError, UnicodeDecodeError):
        lines = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) == 3:
            groups[parts[1]] = parts[2]
    limits = []
    if "" in groups:
        for here in upwards(root, groups[""]):
            values = words(os.path.join(here, "cpu.max"))
            if len(values) == 2 and values[0] != "max":
                limits.append(int(values[0]) / int(values[1]))
    v1 = next((group for controllers, group in groups.items() if "cpu" in controllers.split(",")), None)
    if v1 is not None:
        for here in upwards(os.path.join(root, "cpu"), v1):
            quota = words(os.path.join(here, "cpu.cfs_quota_us"))
            period = words(os.path.join(here, "cpu.cfs_period_us"))
            if quota and period and int(quota[0]) > 0 and int(period[0]) > 0:
                limits.append(int(quota[0]) / int(period[0]))
    return max(1, math.ceil(min(limits))) if limits else None


def cpu_threads(threads: int | None = None) -> int:
    """Threads a CPU bind solves with: ``threads`` when given, else every core this process may run on (its CPU
    affinity, which a batch's workers and containers narrow, within a container's CPU quota:
    :func:`cgroup_cpu_limit`).

    Examples
    --------
    >>> cpu_threads(3), cpu_threads() >= 1
    (3, True)
    """
    if threads is not None:
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
            raise WarpStokesError(f"threads must be a positive number of threads, got {threads!r}")
        return int(threads)
    try:
        cores = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)
    try:
        quota = cgroup_cpu_limit()
    except (OSError, ValueError, ZeroDivisionError):  # an unreadable or malformed group: the affinity alone
        quota = None
    return cores if quota is None else min(cores, quota)


#: ranges per thread in :func:`in_threads` (the ogre's nodes at n = 128 on 16 threads, one slab each: 0.04 to 0.34 s)
RANGES_PER_THREAD = 4


def in_threads(n: int, work, device=None, threads: int | None = None, modules=()) -> None:
    """``work(start, stop)`` over consecutive ranges that cover ``range(n)``: on a CPU shared out between ``threads``
    threads (default :func:`cpu_threads`; Warp runs a CPU launch on the thread that makes it, without the GIL, so
    launches over disjoint ranges run at once), elsewhere once over all of it. Warp's default device is one for all
    threads: it is held at ``device`` meanwhile, so that a scope inside ``work`` finds and restores that. The kernel
    modules ``work`` launches (names as in :data:`KERNEL_MODULES`) are loaded first, on this thread: Warp's module
    loading is not made for several threads at once.

    Examples
    --------
    >>> seen = []
    >>> in_threads(10, lambda a, b: seen.append((a, b)), "cpu", threads=2)
    >>> sorted(seen)
    [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    """
    d = resolve_device(device)
    lanes = min(cpu_threads(threads), n) if d.is_cpu else 1
    if lanes <= 1:
        if n > 0:
            work(0, n)
        return
    from concurrent.futures import ThreadPoolExecutor

    if modules:
        compile_kernels(d, modules=modules)
    # RANGES_PER_THREAD ranges a thread, taken as threads come free: the work is uneven along the ranges (slabs of
    # nodes through a body or beside it)
    size = -(-n // (lanes * RANGES_PER_THREAD))
    ranges = [(a, min(a + size, n)) for a in range(0, n, size)]
    with wp.ScopedDevice(d), ThreadPoolExecutor(max_workers=lanes, thread_name_prefix="warp-stokes") as pool:
        list(pool.map(lambda r: work(*r), ranges))


def reduction_threads(n_rows: int, n_cols: int, device) -> int:
    """Threads per column for column reductions (``kernels.cg.column_dots``): enough to fill a GPU, few on the
    CPU (its launches are serial)."""
    if resolve_device(device).is_cuda:
        return int(max(1, min(n_rows, -(-(1 << 17) // n_cols))))
    return int(max(1, min(n_rows, 16)))


def require_ray(what: str = "--workers and --ray-address need"):
    """The ``ray`` module, or a WarpStokesError saying how to install it (``what`` names what needs it)."""
    try:
        import ray
    except ImportError:
        raise WarpStokesError(f'{what} Ray, an optional extra: pip install "warp-stokes[ray]"') from None
    return ray


def start_ray(ray, **options) -> None:
    """``ray.init(**options)``, a failure to start or join the cluster (a raylet that does not start, an address with
    no cluster) one WarpStokesError saying so."""
    try:
        ray.init(**options)
    except Exception as exc:  # Ray raises ConnectionError, RuntimeError and plain Exceptions
        where = f"join the Ray cluster at {options['address']}" if options.get("address") else "start Ray"
        text = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise WarpStokesError(f"could not {where} ({text})") from None


def cuda_device_count() -> int:
    """CUDA devices this process can see (0 without a driver): a batch on Ray starts one worker per GPU."""
    init_warp()
    return int(wp.get_cuda_device_count()) if wp.is_cuda_available() else 0


#: the package's kernel modules (warp_stokes.kernels.*): what a first run on a machine compiles (laplace is left out:
#: only harmonic coordinates compile it)
KERNEL_MODULES = ("cg", "cg_cpu", "checks", "deform", "intersect", "labels", "local_boundary", "multigrid",
                  "multigrid_cpu", "mvc", "sample", "stencil", "stencil_cpu", "voxel")
#: the modules a bind compiles (deforming compiles "deform" on first use: a bind's process never does)
BIND_MODULES = tuple(m for m in KERNEL_MODULES if m != "deform")


def _warp_modules(modules, device) -> list[tuple]:
    """The Warp modules behind the package's kernel modules ``modules`` that run on ``device``'s kind, with the
    block size their kernels launch with (None: Warp's default): each Python module's own, and the modules of its
    kernels compiled alone (``module="unique"``, e.g. the stencil's walks, launched in blocks of ``BLOCK_DIM``). A
    module that names the kinds it runs on (``DEVICE_KINDS``, e.g. the CPU's node loops) is left out elsewhere, and
    so are kernels a module lists as ``CUDA_ONLY`` on a CPU (the GPU's patch walks) and as ``CPU_ONLY`` on a GPU."""
    import importlib

    kind = "cpu" if device.is_cpu else "cuda"
    found = []
    for name in modules:
        if name == "labels":  # constants only: nothing to compile
            continue
        python_module = importlib.import_module(f"{__package__}.kernels.{name}")
        if kind not in getattr(python_module, "DEVICE_KINDS", (kind,)):
            continue
        skipped = getattr(python_module, "CUDA_ONLY" if kind == "cpu" else "CPU_ONLY", ())
        own = wp.get_module(python_module.__name__)
        found.append((own, None))
        block_dim = getattr(python_module, "BLOCK_DIM", None)
        found += [(k.module, block_dim) for k in vars(python_module).values()
                  if isinstance(k, wp.Kernel) and k.module is not own and not any(k is c for c in skipped)]
    return found


def kernels_compiled(device=None, modules=KERNEL_MODULES) -> bool:
    """Whether Warp's kernel cache on this machine holds the package's kernels for the device's kind (CPU object
    files, or CUDA binaries). A first run compiles them; commands say so before they start.

    Examples
    --------
    >>> isinstance(kernels_compiled("cpu"), bool)
    True
    """
    d = resolve_device(device)
    cache = wp.config.kernel_cache_dir
    if not cache or not os.path.isdir(cache):
        return False
    suffixes = (".o",) if d.is_cpu else (".cubin", ".ptx")
    entries = os.listdir(cache)
    for module, _ in _warp_modules(modules, d):
        prefix = f"wp_{module.name}_"
        folders = [os.path.join(cache, e) for e in entries if e.startswith(prefix)]
        if not any(f.endswith(suffixes) for folder in folders if os.path.isdir(folder) for f in os.listdir(folder)):
            return False
    return True


def compile_kernels(device=None, modules=KERNEL_MODULES, workers: int | None = None) -> None:
    """Compile the package's kernels ``modules`` for ``device`` (or load them from Warp's cache) now, on ``workers``
    threads at once (default: one per CPU core), instead of one module after another at their first launches.

    Examples
    --------
    >>> compile_kernels("cpu", modules=("cg",))
    """
    d = resolve_device(device)
    by_block = {}
    for module, block_dim in _warp_modules(modules, d):
        by_block.setdefault(block_dim, []).append(module)
    workers = workers or os.cpu_count() or 1
    for block_dim, group in by_block.items():
        wp.force_load(d, modules=group, block_dim=block_dim, max_workers=workers)


def announce_compilation(device=None, harmonic: bool = False, stream=None, modules=BIND_MODULES) -> None:
    """Before a first run's kernel compilation: one line on ``stream`` (default stderr), so that a wait is not taken
    for a hang, then the compilation itself, all modules at once (:func:`compile_kernels`). Nothing when the cache
    holds all of ``modules`` (a bind's, by default; ``harmonic``: the Laplace kernels count too)."""
    resolved = resolve_device(device)
    modules = tuple(modules) + (("laplace",) if harmonic else ())
    if not kernels_compiled(resolved, modules):
        took = "about 10 s on a 2-core CPU" if resolved.is_cpu else "5-10 s"
        print(f"warp-stokes: compiling the kernels for {resolved.alias} (first run on this machine, {took}; "
              "later runs load them from Warp's cache)", file=stream or sys.stderr, flush=True)
        compile_kernels(resolved, modules)


#: CU_MEMPOOL_ATTR_USED_MEM_HIGH of the CUDA driver API (cuda.h)
_USED_MEM_HIGH = 8


def reset_peak_memory(device) -> bool:
    """Reset the high-water mark of a CUDA device's memory pool (the one Warp allocates from) to its current use,
    so that ``wp.get_mempool_used_mem_high`` measures what follows. Warp only reads the mark; the driver resets it
    (``cuMemPoolSetAttribute``, which accepts 0 only: the mark then restarts from the current use). Returns False
    where that is not possible (a CPU device, no driver library, the pool not in use): the caller must not trust a
    mark that an earlier, larger peak may have set."""
    import ctypes
    import ctypes.util

    d = resolve_device(device)
    if not d.is_cuda or not wp.is_mempool_enabled(d):
        return False
    try:
        cuda = ctypes.CDLL(ctypes.util.find_library("cuda") or "libcuda.so.1")
        handle, pool, zero = ctypes.c_int(), ctypes.c_void_p(), ctypes.c_uint64(0)
        if cuda.cuDeviceGet(ctypes.byref(handle), ctypes.c_int(d.ordinal)) != 0:
            return False
        if cuda.cuDeviceGetMemPool(ctypes.byref(pool), handle) != 0:  # the pool the device allocates from now
            return False
        wp.synchronize_device(d)
        return cuda.cuMemPoolSetAttribute(pool, ctypes.c_int(_USED_MEM_HIGH), ctypes.byref(zero)) == 0
    except (OSError, AttributeError):
        return False


def memory_size(n_bytes: float) -> str:
    """Bytes as people read them: GiB from 1 GiB up, else MiB.

    Examples
    --------
    >>> memory_size(3 * 2**30), memory_size(10e6)
    ('3.00 GiB', '9.5 MiB')
    """
    return f"{n_bytes / 2**30:.2f} GiB" if n_bytes >= 2**30 else f"{n_bytes / 2**20:.1f} MiB"
