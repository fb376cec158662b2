"""The grid part of a bind, for a range of the cage's handles on one device: voxelise, plan the chunks that fit the
memory, form the multigrid, and for each chunk the boundary data, the solve and the sampling at the vertices.

:func:`warp_stokes.bind` runs it for all handles on its device; a bind spread over several devices
(:mod:`warp_stokes.binding.spread`) runs it for a share of the handles on each.
"""

from __future__ import annotations

import contextlib
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import warp as wp

from ..geometry.boundary import (COMPLEMENT_COLUMNS, boundary_field, start_lattice_nodes, start_rows,
                                 start_values)
from ..geometry.local_boundary import blend_table
from ..geometry.local_data import boundary_settings, local_data_bytes
from ..geometry.cage import Cage
from ..geometry.grid import voxelize
from ..device import BIND_MODULES, compile_kernels, cpu_threads
from ..solver.budget import available_memory, chunk_columns, estimate_memory, plan_lanes
from ..solver.multigrid import Multigrid, coarsen
from ..solver.solve import solve_biharmonic
from .sample import sample_weights

__all__ = ["GridColumns", "GridSummary", "grid_columns"]


class _Abandoned(Exception):
    """Raised in a lane told to stop: the bind was left by its main thread (the lane's result is never read)."""


class GridSummary(NamedTuple):
    """What a binding's stats and warnings need of its grid (a Grid's arrays stay on the process that made it)."""

    shape: tuple
    spacing: float
    resolution: int
    n_interior: int
    n_ring: int
    n_band: int
    n_cut_off: int
    n_inside: int


@dataclass
class GridColumns:
    """The weights of a range of handles at the mesh's vertices, and how they were computed.

    Attributes
    ----------
    weights : (V, handles in the range) float32; rows of vertices beyond the grid's band are zero
    corners : (V, 8) int32, the rows of each vertex's sampling cell (see :func:`warp_stokes.sample_weights`)
    reports : list of SolveReport, one per chunk
    grid : GridSummary
    levels : list of int, the multigrid's level sizes (the interior alone with the Jacobi preconditioner)
    multigrid_seconds : dict, the multigrid's setup time by phase
    coarsest : dict or None, the multigrid's coarsest operator (``Multigrid.coarsest``: unknowns, condition, ...)
    chunks : int, chunks the range was solved in
    threads : int, chunks solved at once (threads, on a CPU)
    memory_estimate : int, bytes the plan counted: the largest chunk, on each thread (lane) at once, and the tables
        the lanes share
    seconds : dict, time by phase: voxelize, setup, boundary, solve, sample
    devices : list of dict, where the range was solved when a bind spreads over several devices (empty otherwise)
    warnings : list of str, what the range's solve warned of, where it ran in another process (a spread bind)
    """

    weights: np.ndarray
    corners: np.ndarray
    reports: list
    grid: GridSummary
    levels: list
    multigrid_seconds: dict
    coarsest: dict | None
    chunks: int
    memory_estimate: int
    threads: int = 1
    seconds: dict = field(default_factory=dict)
    devices: list = field(default_factory=list)
    warnings: list = field(default_factory=list)


def grid_columns(checked: Cage, points: np.ndarray, resolution: int, device, handles: slice = slice(None),
                 solver: str = "multigrid", tol: float = 1e-6, max_iterations: int | None = None, boundary="local",
                 sampling: str = "hermite", memory_budget: int | None = None,
                 equation: str = "biharmonic", progress=None, threads: int | None = None) -> GridColumns:
    """Solve the handles ``handles`` of a checked cage on a grid at ``resolution`` on ``device`` and sample them at
    ``points`` (arguments as in :func:`warp_stokes.bind`, the device resolved).

    A range short of the whole cage is solved with the rest of the cage as one more column (as the chunks of a bind
    too large for memory are), so that every solve checks partition of unity. On a CPU the handles are solved in
    chunks by ``threads`` threads at once (default: every core this process may use, :func:`cpu_threads`), each
    chunk with that column, within the memory budget.

    Returns
    -------
    GridColumns

    Examples
    --------
    >>> part = grid_columns(cage, mesh_vertices, 32, device, handles=slice(0, 20))  # doctest: +SKIP
    >>> part.weights.shape  # doctest: +SKIP
    (2089, 20)
    """
    first, stop, _ = handles.indices(checked.n_handles)
    n_range = stop - first
    partial = n_range < checked.n_handles
    seconds = {}
    tell = progress or (lambda stage, **info: None)
    t = time.perf_counter()
    tell("voxelising", resolution=resolution)
    grid = voxelize(checked, resolution, device=device, memory_budget=memory_budget, boundary=boundary,
                    threads=threads)
    # the levels' sizes first (cheap), so that the plan counts the hierarchy before it is formed
    levels = coarsen(grid, device) if solver == "multigrid" else None
    estimate = estimate_memory(grid, len(points), preconditioner=solver, levels=levels, device=device,
                               n_handles=n_range,
                               boundary_bytes=(0, 0, 0) if boundary_settings(boundary) == "mvc" else local_data_bytes(checked))
    budget = available_memory(device) if memory_budget is None else int(memory_budget)
    # on a CPU, chunks solved at once by threads (Warp runs a CPU launch on the calling thread, without the GIL); a
    # partial range always carries the rest-of-the-cage column: the plan has room for it
    lanes = cpu_threads(threads) if wp.get_device(device).is_cpu else 1
    # lanes share one table of every handle's starting values (each chunk's would cost the whole search), and while
    # it is formed on a CPU the values at the nodes it is interpolated from
    table = 8 * (start_rows(grid, boundary_settings(boundary))
                 + start_lattice_nodes(grid, boundary_settings(boundary), device)) * checked.n_handles
    chunks, lanes = plan_lanes(estimate, n_range, budget, resolution, lanes, name=checked.name, partial=partial,
                               lane_table=table)
    chunks = [slice(first + c.start, first + c.stop) for c in chunks]
    seconds["voxelize"] = time.perf_counter() - t

    t = time.perf_counter()
    if solver == "multigrid":
        tell("multigrid", levels=len(levels))
    preconditioner = (Multigrid(grid, device=device, levels=levels, equation=equation, threads=threads)
                      if solver == "multigrid" else "jacobi")
    wp.synchronize_device(device)
    seconds["setup"] = time.perf_counter() - t

    weights = np.empty((len(points), n_range), dtype=np.float32)
    complement = partial or len(chunks) > 1
    starts = None
    if lanes > 1:
        t = time.perf_counter()
        tell("boundary data", threads=lanes)
        # the modules the lanes launch, loaded here: Warp's module loading is not made for several threads at once
        compile_kernels(device, modules=BIND_MODULES + (("laplace",) if equation == "laplace" else ()))
        starts = start_values(grid, checked, device=device, threads=lanes, data=boundary)
        if boundary_settings(boundary) != "mvc":  # the rows' blend of faces, formed on every thread before the lanes
            blend_table(grid, checked, slice(grid.n_interior, grid.n_active), device, threads=lanes)
        if solver == "multigrid":
            preconditioner.coarse_inverse  # formed here: the lanes' views, made on their threads, share it
        seconds["start_values"] = time.perf_counter() - t

    lanes_own = threading.local()  # each lane's view of the multigrid (its work vectors and smoother bounds)
    # set when the main thread leaves the rounds early (Ctrl-C, an error in another lane): the lanes then stop at their
    # next iteration or stage, instead of the interrupt waiting for every running solve to finish
    abandoned = threading.Event()

    def lane_tell(stage: str, **info) -> None:
        if abandoned.is_set():
            raise _Abandoned
        tell(stage, **info)

    def part_of(k: int) -> dict:
        return {"chunk": k + 1, "chunks": len(chunks)} if len(chunks) > 1 else {}

    def form(k: int) -> tuple:
        """Chunk k's field: the boundary data (a chunk carries the rest of the cage in one more column, so that
        its solve checks partition of unity); and its seconds."""
        t = time.perf_counter()
        lane_tell("boundary data", **part_of(k))
        field_ = boundary_field(grid, checked, device=device, handles=chunks[k], complement=complement,
                                data=boundary, start=starts, threads=lanes)
        wp.synchronize_device(device)
        return field_, time.perf_counter() - t

    def solve(k: int, field_):
        """Chunk k's solve, on this thread's view of the multigrid; its report."""
        mine = preconditioner
        if lanes > 1 and solver == "multigrid":
            if getattr(lanes_own, "multigrid", None) is None:
                lanes_own.multigrid = preconditioner.lane()
            mine = lanes_own.multigrid
        return solve_biharmonic(
            grid, field_, tol=tol, max_iterations=max_iterations, handles=checked.vertices,
            chunk=chunks[k] if complement else None, preconditioner=mine, device=device, equation=equation,
            progress=lambda iteration, residual: lane_tell("solving", iteration=iteration, residual=residual,
                                                           **part_of(k)),
        )

    def sample(k: int, field_) -> tuple:
        """Chunk k's weights at the vertices, into ``weights``; the cells' corners and the seconds."""
        t = time.perf_counter()
        lane_tell("sampling", **part_of(k))
        chunk = chunks[k]
        sampled_columns, corners = sample_weights(grid, field_, points, device=device, method=sampling)
        weights[:, chunk.start - first: chunk.stop - first] = sampled_columns[:, : chunk.stop - chunk.start]
        return corners, time.perf_counter() - t

    # rounds of `lanes` chunks, each stage of a round on its threads at once: the lanes are in the same stage
    # together, so that a bind's peak memory is the plan's (every lane in its largest stage) from run to run
    reports, corners = [], None
    seconds["boundary"] = seconds["solve"] = seconds["sample"] = 0.0
    with contextlib.ExitStack() as stack:
        if lanes > 1:
            # Warp's default device is one for all threads, and each ScopedDevice restores the one it found: set
            # here for the lanes, every lane's scope finds and restores the CPU (on a GPU host, a lane's array on the
            # GPU was an illegal memory access)
            stack.enter_context(wp.ScopedDevice(device))
            pool = stack.enter_context(ThreadPoolExecutor(max_workers=lanes, thread_name_prefix="warp-stokes-chunk"))
            run = pool.map
        else:
            run = map
        # on the way out (the pool's shutdown waits for its running lanes), the lanes are told to stop
        stack.callback(abandoned.set)
        for first_k in range(0, len(chunks), lanes):
            ks = range(first_k, min(first_k + lanes, len(chunks)))
            formed = list(run(form, ks))
            seconds["boundary"] += max(spent for _, spent in formed)
            fields = [field_ for field_, _ in formed]
            del formed
            solved = list(run(solve, ks, fields))
            seconds["solve"] += max(report.seconds for report in solved)
            reports += solved
            sampled = list(run(sample, ks, fields))
            seconds["sample"] += max(spent for _, spent in sampled)
            corners = sampled[-1][0]
            del fields, sampled
    seconds["boundary"] += seconds.pop("start_values", 0.0)
    summary = GridSummary(grid.shape, grid.spacing, grid.resolution, grid.n_interior, grid.n_ring, grid.n_band,
                          grid.n_cut_off, grid.n_inside)
    return GridColumns(
        weights=weights, corners=corners, reports=reports, grid=summary,
        levels=preconditioner.level_sizes if solver == "multigrid" else [grid.n_interior],
        multigrid_seconds=preconditioner.seconds if solver == "multigrid" else {},
        coarsest=preconditioner.coarsest if solver == "multigrid" else None, chunks=len(chunks), threads=lanes,
        memory_estimate=estimate.total(lanes * chunk_columns(chunks)
                                       + (COMPLEMENT_COLUMNS if partial and len(chunks) == 1 else 0), lanes)
        + (table if lanes > 1 else 0),
        seconds=seconds)
