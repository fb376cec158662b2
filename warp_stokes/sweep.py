"""Resolution sweeps: bind one pair at several grid resolutions with Stokes and harmonic coordinates (and mean value
coordinates beside), and tabulate cost, exactness and convergence, for researchers who benchmark grid resolutions.

Each row: ``method, resolution, handles, vertices, seconds, peak_memory_bytes, memory_estimate_bytes, iterations,
pu_error, lp_error, weight_diff_max, weight_diff_rms`` (the largest and RMS per-vertex change of the weights against
the finest resolution of the same method; empty for the finest) and, with a pose, ``conformal_p95`` (the 95th
percentile of the deformation's per-triangle conformal distortion), and ``error``: empty, or the one line of a
solve that gave no weights (:class:`warp_stokes.ConvergenceError`; the sweep goes on). ``mvc`` (mean value
coordinates, evaluated at the vertices) has no grid: one row with an empty resolution. Peak memory is the device
memory pool's high-water mark on a GPU and the process's peak resident set on a CPU, each above its level when the
bind starts: each bind's own (on a CPU the heap earlier binds freed is handed back first, and a bind runs on one
thread unless ``threads`` says otherwise, so that its peak is the same from run to run).
"""

from __future__ import annotations

import csv
import io
import json
import os
import resource
import time
import warnings

import numpy as np

from .binding.pipeline import bind
from .binding.stats import identity_errors
from .device import Backend
from .kernel_cache import BIND_MODULES, compile_kernels
from .memory import reset_peak_memory
from .errors import ConvergenceError, WarpStokesError
from .geometry.cage import check_cage
from .io.outputs import atomic_output
from .io.load import load_surface
from .quality import deformation_quality, vertex_weight_difference

__all__ = ["sweep", "write_sweep", "format_sweep", "plot_sweep", "COLUMNS", "METHODS"]

COLUMNS = ("method", "resolution", "handles", "vertices", "seconds", "peak_memory_bytes", "memory_estimate_bytes",
           "iterations", "pu_error", "lp_error", "weight_diff_max", "weight_diff_rms", "conformal_p95", "error")
METHODS = ("stokes", "harmonic", "mvc")


def _status_kib(field: str) -> int | None:
    """A field of /proc/self/status in KiB (VmRSS, VmHWM), or None off Linux."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _hand_back_freed_heap() -> None:
    """Collect garbage and return the C heap's free pages to the system (glibc; a no-op elsewhere)."""
    import ctypes
    import ctypes.util
    import gc

    gc.collect()
    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class _PeakMemory:
    """Peak memory of one bind: Warp's memory-pool high-water mark above its level on a GPU (the mark reset first
    through the driver; None where it cannot be and an earlier peak was higher); on a CPU the process's peak resident
    set above its size at the start (Linux: the peak is reset first through /proc/self/clear_refs; elsewhere the
    growth of the maximum resident set, which only grows). On a CPU the heap that earlier binds freed is handed back
    to the system first (glibc's malloc_trim): a bind that reused it would not raise the resident set, and a sweep
    read 44 / 18 / 0 / 45 MB at n = 16 / 24 / 32 / 48."""

    def __init__(self, device):
        import warp as wp

        self.device = device
        if device.is_cuda:
            wp.synchronize_device(device)
            self.base = int(wp.get_mempool_used_mem_current(device))
            # the pool's mark is the process's: without a reset an earlier, larger bind would set it
            self.trusted = reset_peak_memory(device) or int(wp.get_mempool_used_mem_high(device)) <= self.base
            return
        _hand_back_freed_heap()
        try:
            with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
                fh.write("5")  # resets the peak resident set (VmHWM) to the current one
            self.base, self.linux = _status_kib("VmRSS") * 1024, True
        except (OSError, TypeError):
            self.base, self.linux = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, False

    def bytes(self) -> int:
        import warp as wp

        if self.device.is_cuda:
            wp.synchronize_device(self.device)
            return max(0, int(wp.get_mempool_used_mem_high(self.device)) - self.base) if self.trusted else None
        peak = _status_kib("VmHWM") * 1024 if self.linux else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        return max(0, peak - self.base)


def _row(method, resolution, weights, surface, cage, pose, seconds, peak, estimate, iterations) -> dict:
    pu, lp = identity_errors(weights, cage.vertices, surface.vertices)
    row = dict.fromkeys(COLUMNS)
    row.update(method=method, resolution=resolution, handles=cage.n_handles, vertices=len(surface.vertices),
               seconds=seconds, peak_memory_bytes=peak, memory_estimate_bytes=estimate, iterations=iterations,
               pu_error=pu, lp_error=lp)
    if pose is not None and len(surface.faces):
        quality = deformation_quality(weights, surface.vertices, surface.faces, cage, pose)
        row["conformal_p95"] = quality["regions"]["all"]["conformal"]["p95"]
    return row


def sweep(mesh, cage, resolutions, methods=("stokes",), pose=None, device=None, tol: float = 1e-6,
          threads: int | None = 1) -> list[dict]:
    """Bind ``mesh`` to ``cage`` at each resolution with each method; one row per bind (see the module docstring).

    Parameters
    ----------
    mesh, cage : what :func:`warp_stokes.bind` takes
    resolutions : iterable of int
    methods : iterable of "stokes" | "harmonic" | "mvc"
    pose : deformed cage (path, (L, 3) array), optional: adds ``conformal_p95``
    device : None | str
    tol : float
    threads : int or None
        A CPU bind's threads: one by default, so that each row's peak memory is the same from run to run and grows
        with the resolution; None for every core (faster; a bind's peak then depends on how the threads' stages
        overlap, up to the estimate).

    Returns
    -------
    list of dict, in the order of the methods, each method's rows from the coarsest resolution up

    Examples
    --------
    >>> rows = sweep("arm.obj", "arm_cage.obj", [16, 24, 32], methods=["stokes", "mvc"])  # doctest: +SKIP
    """
    methods = list(dict.fromkeys(methods))
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise WarpStokesError(f"methods must be among {', '.join(METHODS)}, got {', '.join(unknown) or 'none'}")
    resolutions = sorted({int(r) for r in resolutions})
    if any(m != "mvc" for m in methods) and not resolutions:
        raise WarpStokesError("a sweep needs at least one resolution")
    backend = Backend.of(device)
    device = backend.device
    surface, checked = load_surface(mesh), check_cage(cage)
    rows, weights = [], {method: {} for method in methods}
    # the kernels loaded before any row is measured: the first harmonic row's peak was the Laplace module's load
    # (60 MB at n = 16 on a CPU, for an estimate of 7)
    compile_kernels(device, modules=BIND_MODULES + (("laplace",) if "harmonic" in methods else ()))
    for method in methods:
        if method == "mvc":
            peak = _PeakMemory(device)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                binding = bind(surface, checked, device=backend, method="mvc")
            rows.append(_row("mvc", None, binding.weights, surface, checked, pose, binding.stats.seconds["total"],
                             peak.bytes(), None, None))
            continue
        for resolution in resolutions:
            peak = _PeakMemory(device)
            start = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    binding = bind(surface, checked, resolution=resolution, device=backend, tol=tol, method=method,
                                   threads=threads)
                except ConvergenceError as exc:  # a row that says so; the sweep goes on
                    row = dict.fromkeys(COLUMNS)
                    row.update(method=method, resolution=resolution, handles=checked.n_handles,
                               vertices=len(surface.vertices), seconds=time.perf_counter() - start,
                               peak_memory_bytes=peak.bytes(), error=str(exc),
                               iterations=exc.report.iterations if exc.report is not None else None)
                    rows.append(row)
                    continue
            weights[method][resolution] = binding.weights
            rows.append(_row(method, resolution, binding.weights, surface, checked, pose,
                             binding.stats.seconds["total"], peak.bytes(), binding.stats.memory_estimate_bytes,
                             binding.stats.solver.iterations))
    for row in rows:
        mine = weights[row["method"]]
        if mine and row["resolution"] != max(mine):
            largest, _ = vertex_weight_difference(mine[row["resolution"]], mine[max(mine)])
            row["weight_diff_max"] = float(largest.max())
            row["weight_diff_rms"] = float(np.sqrt(np.mean(largest**2)))
    for row in rows:
        row["device"] = backend.name
    return rows


def format_sweep(rows: list[dict]) -> str:
    """The rows as a text table."""
    def cell(value):
        if value is None:
            return "-"
        if isinstance(value, float):
            return f"{value:.3g}"
        return str(value)

    columns = [c for c in COLUMNS if any(r.get(c) is not None for r in rows)]
    table = [columns] + [[cell(r.get(c)) for c in columns] for r in rows]
    widths = [max(len(line[k]) for line in table) for k in range(len(columns))]
    return "\n".join("  ".join(v.ljust(w) for v, w in zip(line, widths)).rstrip() for line in table)


def write_sweep(rows: list[dict], folder) -> tuple[str, str]:
    """Write ``folder/sweep.csv`` and ``folder/sweep.json`` (the same rows; empty cells for what does not apply),
    each under a temporary name renamed when complete. Returns their paths."""
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    columns = list(COLUMNS) + ["device"]
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({c: "" if row.get(c) is None else row.get(c) for c in columns})
    paths = os.path.join(folder, "sweep.csv"), os.path.join(folder, "sweep.json")
    with atomic_output(paths[0], ".csv") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text.getvalue())
    with atomic_output(paths[1], ".json") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump({"columns": columns, "rows": [{c: row.get(c) for c in columns} for row in rows]}, fh, indent=1)
    return paths


def plot_sweep(rows: list[dict], folder) -> tuple[str, str]:
    """Draw ``folder/convergence.png`` (the weights' largest and RMS change against the finest resolution, log-log,
    per grid method) and ``folder/cost.png`` (seconds and peak memory against the resolution), headless (Agg) and
    deterministic; each written under a temporary name. Needs matplotlib (``pip install "warp-stokes[plot]"``).

    Returns
    -------
    the two paths
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise WarpStokesError('the pictures need matplotlib: pip install "warp-stokes[plot]"') from None
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    grid_rows = [r for r in rows if r.get("resolution") is not None]
    methods = list(dict.fromkeys(r["method"] for r in grid_rows))
    paths = os.path.join(folder, "convergence.png"), os.path.join(folder, "cost.png")
    with plt.rc_context({"svg.hashsalt": "warp-stokes", "figure.dpi": 100}):
        figure, axes = plt.subplots(figsize=(6, 4.5))
        for method in methods:
            mine = [r for r in grid_rows if r["method"] == method and r.get("weight_diff_rms") is not None]
            if mine:
                n = [r["resolution"] for r in mine]
                axes.loglog(n, [r["weight_diff_max"] for r in mine], "o-", label=f"{method}: max over vertices")
                axes.loglog(n, [r["weight_diff_rms"] for r in mine], "s--", label=f"{method}: RMS over vertices")
        _integer_ticks(axes, sorted({r["resolution"] for r in grid_rows}))
        axes.set_xlabel("resolution (cells along the cage's longest axis)")
        axes.set_ylabel("change of the weights against the finest resolution")
        axes.set_title(f"Convergence ({rows[0]['handles']} handles, {rows[0]['vertices']} vertices)")
        axes.grid(True, which="both", alpha=0.3)
        axes.legend(fontsize=8)
        figure.tight_layout()
        with atomic_output(paths[0], ".png") as tmp:
            figure.savefig(tmp, format="png")
        plt.close(figure)
        figure, (seconds, memory) = plt.subplots(1, 2, figsize=(10, 4))
        for method in methods:
            mine = [r for r in grid_rows if r["method"] == method]
            n = [r["resolution"] for r in mine]
            seconds.loglog(n, [r["seconds"] for r in mine], "o-", label=method)
            measured = [(r["resolution"], r["peak_memory_bytes"] / 2**20) for r in mine if r["peak_memory_bytes"]]
            if measured:
                memory.loglog(*zip(*measured), "o-", label=f"{method}: peak")
            memory.loglog(n, [(r["memory_estimate_bytes"] or 1) / 2**20 for r in mine], "s--",
                          label=f"{method}: estimate")
        seconds.set_xlabel("resolution")
        seconds.set_ylabel("seconds per bind")
        memory.set_xlabel("resolution")
        memory.set_ylabel("MiB")
        for axes in (seconds, memory):
            _integer_ticks(axes, sorted({r["resolution"] for r in grid_rows}))
            axes.grid(True, which="both", alpha=0.3)
            axes.legend(fontsize=8)
        figure.suptitle(f"Cost on {rows[0].get('device', '')}")
        figure.tight_layout()
        with atomic_output(paths[1], ".png") as tmp:
            figure.savefig(tmp, format="png")
        plt.close(figure)
    return paths


def _integer_ticks(axes, resolutions) -> None:
    """The resolutions themselves as the x ticks of a log axis, written as integers."""
    from matplotlib.ticker import FixedLocator, NullLocator, ScalarFormatter

    axes.xaxis.set_major_locator(FixedLocator(resolutions))
    axes.xaxis.set_minor_locator(NullLocator())
    axes.xaxis.set_major_formatter(ScalarFormatter())
