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

from ..geometry.boundary import (COMPLEMENT_COLUMNS, boundary_field, start_lattice_nodes, start_rows,
                                 start_values)
from ..geometry.local_boundary import blend_table
from ..geometry.local_data import local_data_bytes
from ..geometry.cage import Cage
from ..geometry.grid import voxelize
from ..kernel_cache import BIND_MODULES, compile_kernels
from ..solver.budget import chunk_columns, estimate_memory, plan_lanes
from ..solver.multigrid import Multigrid, coarsen
from ..solver.preconditioner import Jacobi
from ..solver.solve import solve_biharmonic
from .plan import GridPlan
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


def grid_columns(checked: Cage, points: np.ndarray, resolution: int, plan: GridPlan, handles: slice = slice(None),
                 progress=None) -> GridColumns:
    """Solve the handles ``handles`` of a checked cage on a grid at ``resolution`` as ``plan`` says and sample them at
    ``points``.

    A range short of the whole cage is solved with the rest of the cage as one more column (as the chunks of a bind
    too large for memory are), so that every solve checks partition of unity. On a CPU the handles are solved in
    chunks by the backend's threads at once, each chunk with that column, within the memory budget.

    Returns
    -------
    GridColumns

    Examples
    --------
    >>> part = grid_columns(cage, mesh_vertices, 32, GridPlan.of("cpu"), handles=slice(0, 20))  # doctest: +SKIP
    >>> part.weights.shape  # doctest: +SKIP
    (2089, 20)
    """
    first, stop, _ = handles.indices(checked.n_handles)
    tell = progress or (lambda stage, **info: None)
    seconds = {}
    t = time.perf_counter()
    tell("voxelising", resolution=resolution)
    grid = voxelize(checked, resolution, device=plan.backend, memory_budget=plan.memory_budget,
                    boundary=plan.boundary)
    layout = _chunk_layout(checked, grid, len(points), first, stop, plan)
    seconds["voxelize"] = time.perf_counter() - t

    t = time.perf_counter()
    if plan.multigrid:
        tell("multigrid", levels=len(layout.levels))
    preconditioner = (Multigrid(grid, device=plan.backend, levels=layout.levels, equation=plan.equation)
                      if plan.multigrid else Jacobi(grid, plan.equation, plan.backend))
    plan.backend.synchronize()
    seconds["setup"] = time.perf_counter() - t

    rounds = _Rounds(checked, points, grid, plan, layout, preconditioner, tell)
    if layout.lanes > 1:
        t = time.perf_counter()
        rounds.share_boundary_tables()
        seconds["boundary"] = time.perf_counter() - t
    weights, corners, reports = rounds.run(seconds)
    summary = GridSummary(grid.shape, grid.spacing, grid.resolution, grid.n_interior, grid.n_ring, grid.n_band,
                          grid.n_cut_off, grid.n_inside)
    return GridColumns(
        weights=weights, corners=corners, reports=reports, grid=summary,
        levels=preconditioner.level_sizes, multigrid_seconds=preconditioner.seconds,
        coarsest=preconditioner.coarsest, chunks=len(layout.chunks),
        threads=layout.lanes, memory_estimate=layout.memory_estimate, seconds=seconds)


@dataclass
class _ChunkLayout:
    """The chunks of handles a range is solved in, and the threads (lanes) that solve them at once."""

    chunks: list  # slices of the cage's handles
    lanes: int
    levels: list | None  # the multigrid's levels' sizes, formed before the plan counts them
    memory_estimate: int  # bytes: the largest chunk on every lane at once, and the tables the lanes share
    table: int  # bytes of the tables the lanes share
    complement: bool  # whether each chunk carries the rest of the cage as one more column


def _chunk_layout(checked: Cage, grid, n_points: int, first: int, stop: int, plan: GridPlan) -> _ChunkLayout:
    """The chunks that fit the memory budget, and on a CPU how many are solved at once (Warp runs a CPU launch on
    the calling thread, without the GIL). A partial range always carries the rest-of-the-cage column: the plan has
    room for it."""
    backend, n_range = plan.backend, stop - first
    partial = n_range < checked.n_handles
    # the levels' sizes first (cheap), so that the plan counts the hierarchy before it is formed
    levels = coarsen(grid, backend) if plan.multigrid else None
    estimate = estimate_memory(grid, n_points, preconditioner=plan.preconditioner, levels=levels, device=backend,
                               n_handles=n_range,
                               boundary_bytes=local_data_bytes(checked) if plan.local_data else (0, 0, 0))
    # lanes share one table of every handle's starting values (each chunk's would cost the whole search), and while
    # it is formed on a CPU the values at the nodes it is interpolated from
    table = 8 * (start_rows(grid, plan.boundary) + start_lattice_nodes(grid, plan.boundary, backend)) * checked.n_handles
    chunks, lanes = plan_lanes(estimate, n_range, plan.budget(), grid.resolution, backend.lanes(backend.threads),
                               name=checked.name, partial=partial, lane_table=table)
    chunks = [slice(first + c.start, first + c.stop) for c in chunks]
    total = estimate.total(lanes * chunk_columns(chunks) + (COMPLEMENT_COLUMNS if partial and len(chunks) == 1 else 0),
                           lanes) + (table if lanes > 1 else 0)
    return _ChunkLayout(chunks, lanes, levels, total, table, partial or len(chunks) > 1)


class _Rounds:
    """The chunks' stages (boundary data, solve, sampling) in rounds of ``lanes`` chunks, each stage of a round on
    its threads at once: the lanes are in the same stage together, so that a bind's peak memory is the plan's (every
    lane in its largest stage) from run to run."""

    def __init__(self, checked: Cage, points: np.ndarray, grid, plan: GridPlan, layout: _ChunkLayout,
                 preconditioner, tell):
        self.checked, self.points, self.grid, self.plan, self.layout = checked, points, grid, plan, layout
        self.preconditioner, self.tell = preconditioner, tell
        # the boundary data's backend: each field's blend and starting guess on as many threads as chunks run at once
        self.backend = plan.backend.with_threads(layout.lanes)
        self.first = layout.chunks[0].start
        self.weights = np.empty((len(points), layout.chunks[-1].stop - self.first), dtype=np.float32)
        self.starts = None
        self.own = threading.local()  # each lane's view of the multigrid (its work vectors and smoother bounds)
        # set when the main thread leaves the rounds early (Ctrl-C, an error in another lane): the lanes then stop at
        # their next iteration or stage, instead of the interrupt waiting for every running solve to finish
        self.abandoned = threading.Event()

    def share_boundary_tables(self) -> None:
        """Before the lanes: every handle's starting values, the rows' blend of faces and the coarsest inverse,
        formed once on all threads and shared (the lanes' modules loaded here: Warp's module loading is not made for
        several threads at once)."""
        plan, grid, backend = self.plan, self.grid, self.backend
        self.tell("boundary data", threads=self.layout.lanes)
        compile_kernels(backend.device, modules=BIND_MODULES + plan.equation.kernel_modules)
        self.starts = start_values(grid, self.checked, device=backend, data=plan.boundary)
        if plan.local_data:
            blend_table(grid, self.checked, slice(grid.n_interior, grid.n_active), backend)
        if plan.multigrid:
            self.preconditioner.coarse_inverse  # formed here: the lanes' views, made on their threads, share it

    def _tell(self, stage: str, k: int, **info) -> None:
        if self.abandoned.is_set():
            raise _Abandoned
        chunks = self.layout.chunks
        self.tell(stage, **info, **({"chunk": k + 1, "chunks": len(chunks)} if len(chunks) > 1 else {}))

    def form(self, k: int) -> tuple:
        """Chunk k's field: the boundary data (a chunk carries the rest of the cage in one more column, so that
        its solve checks partition of unity); and its seconds."""
        t = time.perf_counter()
        self._tell("boundary data", k)
        field_ = boundary_field(self.grid, self.checked, device=self.backend, handles=self.layout.chunks[k],
                                complement=self.layout.complement, data=self.plan.boundary, start=self.starts)
        self.backend.synchronize()
        return field_, time.perf_counter() - t

    def solve(self, k: int, field_):
        """Chunk k's solve, on this thread's view of the multigrid; its report."""
        mine = self.preconditioner
        if self.layout.lanes > 1:
            if getattr(self.own, "preconditioner", None) is None:
                self.own.preconditioner = self.preconditioner.lane()
            mine = self.own.preconditioner
        plan, chunk = self.plan, self.layout.chunks[k]
        return solve_biharmonic(
            self.grid, field_, tol=plan.tol, max_iterations=plan.max_iterations, handles=self.checked.vertices,
            chunk=chunk if self.layout.complement else None, preconditioner=mine, device=plan.backend,
            equation=plan.equation,
            progress=lambda iteration, residual: self._tell("solving", k, iteration=iteration, residual=residual))

    def sample(self, k: int, field_) -> tuple:
        """Chunk k's weights at the vertices, into ``weights``; the cells' corners and the seconds."""
        t = time.perf_counter()
        self._tell("sampling", k)
        chunk = self.layout.chunks[k]
        columns, corners = sample_weights(self.grid, field_, self.points, device=self.plan.backend,
                                          method=self.plan.sampling)
        self.weights[:, chunk.start - self.first: chunk.stop - self.first] = columns[:, : chunk.stop - chunk.start]
        return corners, time.perf_counter() - t

    def run(self, seconds: dict) -> tuple:
        """Every chunk's stages; the weights, the corners and the solve reports (``seconds`` gains each stage's
        time, a round's slowest lane's)."""
        lanes, chunks = self.layout.lanes, self.layout.chunks
        reports, corners = [], None
        for stage in ("boundary", "solve", "sample"):
            seconds.setdefault(stage, 0.0)
        with contextlib.ExitStack() as stack:
            if lanes > 1:
                # Warp's default device is one for all threads, and each ScopedDevice restores the one it found: set
                # here for the lanes, every lane's scope finds and restores the CPU (on a GPU host, a lane's array
                # on the GPU was an illegal memory access)
                stack.enter_context(self.plan.backend.scope())
                pool = stack.enter_context(ThreadPoolExecutor(max_workers=lanes,
                                                              thread_name_prefix="warp-stokes-chunk"))
                run = pool.map
            else:
                run = map
            # on the way out (the pool's shutdown waits for its running lanes), the lanes are told to stop
            stack.callback(self.abandoned.set)
            for first_k in range(0, len(chunks), lanes):
                ks = range(first_k, min(first_k + lanes, len(chunks)))
                formed = list(run(self.form, ks))
                seconds["boundary"] += max(spent for _, spent in formed)
                fields = [field_ for field_, _ in formed]
                del formed
                solved = list(run(self.solve, ks, fields))
                seconds["solve"] += max(report.seconds for report in solved)
                reports += solved
                sampled = list(run(self.sample, ks, fields))
                seconds["sample"] += max(spent for _, spent in sampled)
                corners = sampled[-1][0]
                del fields, sampled
        return self.weights, corners, reports
