"""Resolution sweeps: bind one pair at several grid resolutions (and with mean value coordinates beside), and
tabulate cost, exactness and convergence, for researchers who benchmark grid resolutions.

Each row: ``method, resolution, handles, vertices, seconds, peak_memory_bytes, memory_estimate_bytes, iterations,
pu_error, lp_error, weight_diff_max, weight_diff_rms`` (the largest and RMS per-vertex change of the weights against
the finest resolution of the same method; empty for the finest) and, with a pose, ``conformal_p95`` (the 95th
percentile of the deformation's per-triangle conformal distortion). ``mvc`` (mean value coordinates, evaluated at the
vertices) has no grid: one row with an empty resolution. Peak memory is the device memory pool's high-water mark
on a GPU and the growth of the process's maximum resident set on a CPU (which only grows: rows are bound from the
coarsest resolution up).
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

from .binding import bind
from .binding.stats import identity_errors
from .device import device_name, resolve_device
from .errors import WarpStokesError
from .geometry.boundary import mean_value_coordinates
from .geometry.cage import check_cage
from .io.files import atomic_output
from .io.load import load_surface
from .quality import deformation_quality, vertex_weight_difference

__all__ = ["sweep", "write_sweep", "format_sweep", "COLUMNS", "METHODS"]

COLUMNS = ("method", "resolution", "handles", "vertices", "seconds", "peak_memory_bytes", "memory_estimate_bytes",
           "iterations", "pu_error", "lp_error", "weight_diff_max", "weight_diff_rms", "conformal_p95")
METHODS = ("stokes", "mvc")


def _peak_bytes(device) -> int:
    import warp as wp

    if device.is_cuda:
        return int(wp.get_mempool_used_mem_high(device))
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


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


def sweep(mesh, cage, resolutions, methods=("stokes",), pose=None, device=None, tol: float = 1e-6) -> list[dict]:
    """Bind ``mesh`` to ``cage`` at each resolution with each method; one row per bind (see the module docstring).

    Parameters
    ----------
    mesh, cage : what :func:`warp_stokes.bind` takes
    resolutions : iterable of int
    methods : iterable of "stokes" | "mvc"
    pose : deformed cage (path, (L, 3) array), optional: adds ``conformal_p95``
    device : None | str
    tol : float

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
    if "stokes" in methods and not resolutions:
        raise WarpStokesError("a sweep needs at least one resolution")
    device = resolve_device(device)
    surface, checked = load_surface(mesh), check_cage(cage)
    rows, weights = [], {}
    for method in methods:
        if method == "mvc":
            start, before = time.perf_counter(), _peak_bytes(device)
            w = mean_value_coordinates(checked, surface.vertices, device=device).astype(np.float32)
            seconds = time.perf_counter() - start
            rows.append(_row("mvc", None, w, surface, checked, pose, seconds, max(0, _peak_bytes(device) - before),
                             None, None))
            continue
        for resolution in resolutions:
            import warp as wp

            if device.is_cuda:
                wp.synchronize_device(device)
            # the high-water marks only grow: rows go from the coarsest resolution up, so each is its bind's peak
            base = int(wp.get_mempool_used_mem_current(device)) if device.is_cuda else _peak_bytes(device)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                binding = bind(surface, checked, resolution=resolution, device=device, tol=tol)
            peak = _peak_bytes(device) - base
            weights[resolution] = binding.weights
            rows.append(_row("stokes", resolution, binding.weights, surface, checked, pose,
                             binding.stats["seconds"]["total"], max(0, peak), binding.stats["memory_estimate_bytes"],
                             binding.stats["iterations"]))
    if weights:
        finest = weights[max(weights)]
        for row in rows:
            if row["method"] == "stokes" and row["resolution"] != max(weights):
                largest, _ = vertex_weight_difference(weights[row["resolution"]], finest)
                row["weight_diff_max"] = float(largest.max())
                row["weight_diff_rms"] = float(np.sqrt(np.mean(largest**2)))
    for row in rows:
        row["device"] = device_name(device)
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
