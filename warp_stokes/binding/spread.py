"""One bind spread over several devices: each device solves a share of the cage's handles as a Ray task, on its own
grid and multigrid (:func:`warp_stokes.binding.columns.grid_columns`), and the driver gathers the weights.

``bind(..., device=["cuda:0", "cuda:1"])``, ``device="cuda:0,cuda:1"``, or ``device="cuda:all"`` (every GPU of the
Ray cluster); ``"cpu,cpu"`` runs the shares in CPU worker processes. Each CUDA task asks Ray for one GPU (Ray sets
``CUDA_VISIBLE_DEVICES`` and the task solves on its ``cuda:0``): a list says how many GPUs, Ray picks which. The
shares are contiguous ranges of handles of about equal size; each carries the rest of the cage as one more column,
as a bind's chunks do, and plans its own chunks for its device's memory. Every task voxelises and forms the
multigrid itself (the grid is the same on every device), so the setup is paid once per device, at the same time;
what travels back is the share's sampled weights (vertices x handles of the share, float32) and its solve reports.
The weights are those of a bind on one device that solves the same shares as its chunks.

Ray is an optional extra (``pip install "warp-stokes[ray]"``). A bind that finds Ray initialised
(``ray.init(address=...)``) runs on that cluster; otherwise it starts a local one and shuts it down when done.
"""

from __future__ import annotations

import logging
import os
import socket
import time
import warnings

import numpy as np

from ..cluster import require_ray, start_ray
from ..device import Backend, device_name
from ..errors import WarpStokesError
from .columns import GridColumns, grid_columns
from .plan import GridPlan

__all__ = ["spread_devices", "driver_device", "spread_columns", "ALL_GPUS"]

#: the device name that means every GPU of the Ray cluster
ALL_GPUS = "cuda:all"


def spread_devices(device) -> list[str] | None:
    """The devices a bind spreads its handles over, or None for a bind on one device.

    Parameters
    ----------
    device : None | str | warp Device | list of str
        A list (or tuple) of device names, names separated by commas, or ``"cuda:all"``; anything else is one
        device.

    Returns
    -------
    list of str, all ``"cpu"`` or all CUDA devices (``["cuda:all"]`` stays as it is: the cluster says how many), or
    None

    Raises
    ------
    WarpStokesError
        When the list mixes CPU and CUDA devices or names something else.

    Examples
    --------
    >>> spread_devices("cuda:0,cuda:1")
    ['cuda:0', 'cuda:1']
    >>> spread_devices("cpu") is None and spread_devices(["cpu"]) is None
    True
    """
    if isinstance(device, (list, tuple)):
        names = [str(d).strip() for d in device]
    elif isinstance(device, str) and ("," in device or device.strip() == ALL_GPUS):
        names = [d.strip() for d in device.split(",")]
    else:
        return None
    kinds = {"cpu" if name == "cpu" else "cuda" if name.startswith("cuda") else "?" for name in names}
    if not names or "?" in kinds or len(kinds) > 1 or "" in names or (ALL_GPUS in names and len(names) > 1):
        raise WarpStokesError(f"devices {','.join(names)!r}: name several devices of one kind (cpu,cpu or "
                              f"cuda:0,cuda:1), or {ALL_GPUS} for every GPU")
    if len(names) == 1 and names[0] != ALL_GPUS:
        return None
    return names


def driver_device(devices) -> str | None:
    """Where the bind's own steps (loading, the inside test, vertices beyond the grid) run when it spreads the solves
    over ``devices``: the CPU for CPU devices, else the default device (a GPU when the driver's machine has one)."""
    return "cpu" if devices[0] == "cpu" else None


def spread_columns(checked, points: np.ndarray, resolution: int, devices: list[str], plan: GridPlan) -> GridColumns:
    """The weights of all handles, their shares solved as Ray tasks on ``devices`` (see the module docstring).

    Parameters
    ----------
    checked : Cage
    points : (V, 3) the mesh's vertices
    resolution : int
    devices : list of str, from :func:`spread_devices`
    plan : GridPlan, the bind's (each share's on its own device; a CPU share on its part of the threads)

    Returns
    -------
    GridColumns, with ``devices``: per share, the device, the GPUs Ray gave it, host, process, handle range and
    seconds. What a share warned of (a solve that did not converge, say) is warned of here, once.

    Examples
    --------
    >>> part = spread_columns(cage, vertices, 64, ["cuda:0", "cuda:1"])  # doctest: +SKIP
    """
    ray = require_ray("a bind spread over several devices needs")
    on_cpu = devices[0] == "cpu"
    started = not ray.is_initialized()
    if started:
        start_ray(ray, num_cpus=len(devices) if on_cpu else None, num_gpus=0 if on_cpu else None,
                  include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    try:
        gpus = int(ray.cluster_resources().get("GPU", 0))
        if not on_cpu and gpus == 0:
            raise WarpStokesError(f"devices {','.join(devices)}: the Ray cluster has no GPU")
        count = gpus if devices == [ALL_GPUS] else len(devices)
        if not on_cpu and count > gpus:
            raise WarpStokesError(f"devices {','.join(devices)}: {count} GPUs named, the Ray cluster has {gpus}")
        shares = [s for s in np.array_split(np.arange(checked.n_handles), count) if len(s)]
        resources = {"num_cpus": 1, "num_gpus": 0} if on_cpu else {"num_cpus": 1, "num_gpus": 1}
        # the shares run at once: a CPU share on its part of this host's threads
        threads = max(1, plan.backend.threads // len(shares)) if on_cpu else None
        task = ray.remote(_solve_share).options(**resources)
        start = time.perf_counter()
        refs = [task.remote(checked, points, resolution, slice(int(s[0]), int(s[-1]) + 1),
                            "cpu" if on_cpu else "cuda:0", threads, plan) for s in shares]
        try:
            parts = ray.get(refs)
        except ray.exceptions.RayTaskError as exc:  # the task's own error, not Ray's wrapping of it
            cause = getattr(exc, "cause", None)
            raise (cause if isinstance(cause, Exception) else WarpStokesError(_first_line(exc))) from None
        except ray.exceptions.RayError as exc:  # a worker that died (killed, out of memory), a lost node
            raise WarpStokesError(f"a share's Ray task failed: {type(exc).__name__}: {_first_line(exc)}") from None
        wall = time.perf_counter() - start
    finally:
        if started:
            ray.shutdown()
    for message in dict.fromkeys(m for part in parts for m in part.warnings):  # the shares' warnings, once each
        warnings.warn(message, stacklevel=3)
    return _gathered(parts, wall)


def _first_line(exc) -> str:
    return (str(exc).strip().splitlines() or [""])[0]


def _solve_share(checked, points, resolution: int, handles: slice, device: str, threads: int | None,
                 plan: GridPlan) -> GridColumns:
    """One share of the handles, in a Ray worker process; what it warned of travels back with it."""
    import ray

    plan = plan.on(Backend.of(device, threads))  # a new process: its own device
    resolved = plan.backend.device
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        part = grid_columns(checked, points, resolution, plan, handles=handles)
    part.warnings = list(dict.fromkeys(str(w.message) for w in caught))
    # the GPUs Ray gave the task: its "cuda:0" is the first of them (CUDA_VISIBLE_DEVICES)
    gpus = [str(g) for g in ray.get_gpu_ids()] if resolved.is_cuda else []
    part.devices = [{"device": device_name(resolved), "gpus": gpus, "host": socket.gethostname(),
                     "pid": os.getpid(), "handles": [handles.start, handles.stop],
                     "seconds": round(sum(part.seconds.values()), 4)}]
    return part


def _gathered(parts: list[GridColumns], wall: float) -> GridColumns:
    """The shares' columns side by side; phases timed as the slowest share's (they ran at once), with the spread's
    wall time, transfers and worker start included, as ``spread``."""
    first = parts[0]
    if any(p.grid != first.grid for p in parts):
        raise WarpStokesError("the devices voxelised the cage differently; bind on one device")
    seconds = {phase: max(p.seconds[phase] for p in parts) for phase in first.seconds}
    seconds["spread"] = max(0.0, wall - sum(seconds.values()))
    return GridColumns(
        weights=np.concatenate([p.weights for p in parts], axis=1), corners=first.corners,
        reports=[r for p in parts for r in p.reports], grid=first.grid, levels=first.levels,
        multigrid_seconds=first.multigrid_seconds, coarsest=first.coarsest, chunks=sum(p.chunks for p in parts),
        threads=sum(p.threads for p in parts),
        memory_estimate=max(p.memory_estimate for p in parts), seconds=seconds,
        devices=[d for p in parts for d in p.devices])
