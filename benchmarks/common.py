"""What the benchmarks share: where the data is, the mesh/cage pairs by name, the warm-up bind, the device, peak
memory, kernel timing and Markdown tables.

The scripts import it as ``from common import ...`` after putting their own folder first on ``sys.path``. Nothing
here imports Warp or the package at import time: the scripts whose parent process only starts one process per case
(bench_large.py, bench_solver.py, ...) and every ``--help`` stay light.

Data: the real pairs come from ``WARP_STOKES_DATA`` (default ``../shared/data`` beside the repository), the arm from
``examples/arm``.
"""

from __future__ import annotations

import os
import resource
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("WARP_STOKES_DATA", REPO.parent / "shared" / "data"))
ARM = REPO / "examples" / "arm"
OGRE = DATA / "ogre_qmvc"
SMPL = DATA / "smpl_humanoid_neuralcages"
#: work folder of the scripts that write files (generated pairs, subdivided meshes) when none is given
WORK = Path("/tmp/warp_stokes_bench")

#: mesh and cage files of the pairs on disk, by name
PAIRS = {
    "arm": (ARM / "arm.obj", ARM / "arm_cage.obj"),
    "smpl": (SMPL / "model_rpose.obj", SMPL / "cage_rpose.obj"),
    "ogre": (OGRE / "Ogre.obj", OGRE / "cage_tri.obj"),
}
#: pairs made on the fly: ``sphere`` (OBJ files in a folder) and ``synthetic`` (arrays)
GENERATED = ("sphere", "synthetic")


# ---------------------------------------------------------------------------------------------------------------
# pairs


def sphere_pair(folder: Path = WORK) -> tuple[Path, Path]:
    """The icosphere pair of issue 20 as OBJ files in ``folder``: the cage ``icosphere(subdivisions=2, radius=1)``
    (162 handles) around the mesh ``icosphere(subdivisions=4, radius=0.9)``."""
    import trimesh

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    mesh, cage = folder / "sphere.obj", folder / "sphere_cage.obj"
    if not cage.exists():
        trimesh.creation.icosphere(subdivisions=4, radius=0.9).export(mesh)
        trimesh.creation.icosphere(subdivisions=2, radius=1.0).export(cage)
    return mesh, cage


def synthetic_pair():
    """An ellipsoid cage with 242 handles around a 10,242-vertex ellipsoid mesh, as ``((V, F), (V, F))`` arrays."""
    import trimesh

    cage = trimesh.creation.uv_sphere(radius=1.0, count=[12, 12])
    cage.vertices *= [2.0, 1.0, 0.8]
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.85)
    mesh.vertices *= [2.0, 1.0, 0.8]
    return (mesh.vertices, mesh.faces), (cage.vertices, cage.faces)


def pair(name: str, folder: Path = WORK):
    """Mesh and cage of a pair by name, as ``ws.bind`` takes them: the files of :data:`PAIRS` (arm, smpl, ogre),
    the sphere pair's OBJ files written in ``folder``, or the synthetic pair's arrays."""
    if name in PAIRS:
        return PAIRS[name]
    if name == "sphere":
        return sphere_pair(folder)
    if name == "synthetic":
        return synthetic_pair()
    raise SystemExit(f"unknown pair {name!r} (known: {', '.join([*PAIRS, *GENERATED])})")


def pair_files(name: str, folder: Path = WORK) -> tuple[Path, Path]:
    """Mesh and cage files of a pair by name: :func:`pair` for the pairs that are files (all but ``synthetic``)."""
    if name == "synthetic":
        raise SystemExit("the synthetic pair has no files: arm, smpl, ogre or sphere")
    return pair(name, folder)


# ---------------------------------------------------------------------------------------------------------------
# device and warm-up


def select_device(device=None):
    """``(device, name)``: the Warp device a benchmark runs on (``None``: CUDA when present, else the CPU; or
    ``"cpu"``, ``"cuda"``, ``"cuda:N"``) and its name for the output, e.g. ``"cuda:0 (NVIDIA H100 80GB HBM3)"``."""
    import warp_stokes as ws

    d = ws.resolve_device(device)
    return d, ws.device_name(d)


def warm_up(device=None, mesh=None, cage=None, resolution: int = 16, **options):
    """A bind that compiles and loads every kernel on ``device`` before anything is measured, warnings silenced:
    the bundled arm at n = 16 unless a pair (and the size to time) is given. Returns the binding."""
    import warp_stokes as ws

    if mesh is None:
        mesh, cage = PAIRS["arm"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ws.bind(mesh, cage, resolution=resolution, device=device, **options)


# ---------------------------------------------------------------------------------------------------------------
# memory


def _pooled(device):
    import warp as wp

    import warp_stokes as ws

    d = ws.resolve_device(device)
    return d if d.is_cuda and wp.is_mempool_enabled(d) else None


def pool_used(device) -> int | None:
    """Bytes in use in Warp's memory pool of a CUDA device (synchronised first); None off CUDA or without a pool."""
    import warp as wp

    d = _pooled(device)
    if d is None:
        return None
    wp.synchronize_device(d)
    return wp.get_mempool_used_mem_current(d)


def pool_high(device) -> int | None:
    """High-water mark of Warp's memory pool of a CUDA device, in bytes, since the process started; None off CUDA
    or without a pool."""
    import warp as wp

    d = _pooled(device)
    if d is None:
        return None
    wp.synchronize_device(d)
    return wp.get_mempool_used_mem_high(d)


class DevicePeak:
    """Peak device memory over a ``with`` block: ``.bytes`` is the high-water mark of Warp's memory pool above its
    level on entry (NaN off CUDA). The mark is reset on entry through the driver
    (:func:`warp_stokes.device.reset_peak_memory`); where it cannot be, the mark is the process's and the block's own
    peak must be the highest so far (warm up at a smaller size, or run each case in a fresh process)."""

    def __init__(self, device):
        self.device = device
        self.bytes = float("nan")

    def __enter__(self):
        from warp_stokes.memory import reset_peak_memory

        self._base = pool_used(self.device)
        if self._base is not None:
            reset_peak_memory(self.device)
        return self

    def __exit__(self, *exc):
        if self._base is not None:
            self.bytes = pool_high(self.device) - self._base
        return False


class GpuBusy:
    """How busy each GPU was over a ``with`` block, from ``nvidia-smi``'s ``utilization.gpu`` (the share of its last
    sample period in which a kernel ran, as NVML counts it) read every ``period_ms``; :meth:`fraction` averages it per
    GPU over a window of the block (seconds since the epoch). Empty where there is no ``nvidia-smi``. A coarse
    figure (NVML's own sample period is 1/6 s to 1 s), for telling an idle GPU from a busy one."""

    def __init__(self, period_ms: int = 100):
        self.period_ms = period_ms
        self.samples: list[tuple[float, int, float]] = []  # (time, GPU index, busy 0..1)

    def __enter__(self):
        import shutil
        import subprocess
        import threading

        self._process = None
        if shutil.which("nvidia-smi"):
            self._process = subprocess.Popen(
                ["nvidia-smi", "--query-gpu=index,utilization.gpu", "--format=csv,noheader,nounits",
                 f"-lms={self.period_ms}"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            self._reader = threading.Thread(target=self._read, daemon=True)
            self._reader.start()
        return self

    def _read(self) -> None:
        for line in self._process.stdout:
            cells = [c.strip() for c in line.split(",")]
            if len(cells) == 2 and cells[0].isdigit() and cells[1].replace(".", "", 1).isdigit():
                self.samples.append((time.time(), int(cells[0]), float(cells[1]) / 100.0))

    def __exit__(self, *exc):
        if self._process is not None:
            self._process.terminate()
            self._process.wait()
            self._reader.join(timeout=2)
        return False

    def fraction(self, start: float | None = None, end: float | None = None) -> dict[int, float]:
        """The mean busy share per GPU index over [start, end] (the whole block by default)."""
        by_gpu: dict[int, list[float]] = {}
        for when, gpu, busy in self.samples:
            if (start is None or when >= start) and (end is None or when <= end):
                by_gpu.setdefault(gpu, []).append(busy)
        return {gpu: sum(v) / len(v) for gpu, v in sorted(by_gpu.items())}


def busy_text(fractions: dict[int, float]) -> str:
    """``{0: 0.62, 1: 0.58}`` as ``"62 / 58"`` (per cent, GPU by GPU); "-" without samples."""
    return " / ".join(f"{100 * f:.0f}" for f in fractions.values()) or "-"


def max_rss() -> int:
    """The process's maximum resident set size so far, in bytes (``ru_maxrss`` is in KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


class HostPeak:
    """Peak host memory over a ``with`` block: ``.bytes`` is the growth of the process's maximum resident set size
    (``.before`` its value on entry). Max RSS only grows past the highest peak so far: a block below an earlier
    peak reads 0."""

    def __init__(self):
        self.before = self.bytes = 0

    def __enter__(self):
        self.before = max_rss()
        return self

    def __exit__(self, *exc):
        self.bytes = max_rss() - self.before
        return False


# ---------------------------------------------------------------------------------------------------------------
# kernel timing


def copy_bandwidth(device, nbytes: int = 2 << 30, repeats: int = 20) -> float:
    """Device-to-device copy bandwidth of a CUDA device (bytes read + written per second), median of ``repeats``."""
    import numpy as np
    import warp as wp

    n = nbytes // 16
    a = wp.zeros(n, dtype=wp.vec4f, device=device)
    b = wp.empty(n, dtype=wp.vec4f, device=device)
    wp.copy(b, a)
    times = []
    for _ in range(repeats):
        start, end = wp.Event(device, enable_timing=True), wp.Event(device, enable_timing=True)
        wp.record_event(start)
        wp.copy(b, a)
        wp.record_event(end)
        wp.synchronize_device(device)
        times.append(wp.get_event_elapsed_time(start, end) / 1e3)
    return 2 * n * 16 / float(np.median(times))


def time_kernel(device, launch, repeats: int = 20) -> float:
    """Seconds of one call of ``launch`` after one untimed call: the median of ``repeats`` timed with CUDA events
    on a CUDA device, the mean of 3 wall-clock calls on the CPU."""
    import numpy as np
    import warp as wp

    launch()
    if not wp.get_device(device).is_cuda:
        t = time.perf_counter()
        for _ in range(3):
            launch()
        return (time.perf_counter() - t) / 3
    times = []
    for _ in range(repeats):
        start, end = wp.Event(device, enable_timing=True), wp.Event(device, enable_timing=True)
        wp.record_event(start)
        launch()
        wp.record_event(end)
        wp.synchronize_device(device)
        times.append(wp.get_event_elapsed_time(start, end) / 1e3)
    return float(np.median(times))


# ---------------------------------------------------------------------------------------------------------------
# Markdown tables


def table_head(columns) -> str:
    """A Markdown table's header and rule lines."""
    return "| " + " | ".join(map(str, columns)) + " |\n" + "|" + "---|" * len(columns)


def table_row(cells) -> str:
    """One Markdown table row (each cell through ``str``)."""
    return "| " + " | ".join(map(str, cells)) + " |"


def markdown_table(columns, rows) -> str:
    """A whole Markdown table: header, rule and one line per row."""
    return "\n".join([table_head(columns), *(table_row(r) for r in rows)])
