"""What a binding records beside its weights: a typed report (:class:`BindStats`, with the grid's, the resolution
choice's and the solver's figures as their own records), the settings, and the parts and asset it came from.

The report is written to a binding file as a record of format :data:`STATS_FORMAT` and read back whole
(:meth:`BindStats.from_record`); the flat stats of format-1 binding files are read into the same types."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .. import __version__
from ..device import Backend
from ..geometry.cage import Cage
from ..geometry.topology import bounding_diagonal
from ..io.scene import Scene

__all__ = ["BindStats", "GridStats", "SolverStats", "ResolutionChoice", "STATS_FORMAT", "identity_errors",
           "grid_stats", "solver_stats", "mvc_stats", "settings_record", "parts_record", "asset_record"]

#: the version of the stats record a binding file holds (1: the flat record of bindings written before 0.3)
STATS_FORMAT = 2


def identity_errors(weights: np.ndarray, handles: np.ndarray, points: np.ndarray, rows: int = 1 << 16):
    """The largest deviation from partition of unity, max |sum_l w_l - 1|, and from linear precision,
    max |sum_l w_l (c_l - o) - (p - o)| relative to the handles' bounding-box diagonal, o its centre (as the solver
    measures it: weights do not change when cage and mesh move together, and in world coordinates far from the origin
    the float32 weights' rounding times the coordinates would read as an error), in float64 sums over blocks of
    ``rows`` vertices (a float64 copy of all weights would double a large mesh's peak memory).

    Examples
    --------
    >>> c = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> identity_errors(np.array([[0.25, 0.25, 0.25, 0.25]], np.float32), c, np.array([[0.25, 0.25, 0.25]]))
    (0.0, 0.0)
    """
    handles = np.asarray(handles, dtype=np.float64)
    diag = bounding_diagonal(handles)
    centre = 0.5 * (handles.min(axis=0) + handles.max(axis=0))
    handles = handles - centre
    pu = lp = 0.0
    for start in range(0, len(weights), rows):
        w = weights[start : start + rows].astype(np.float64)
        if len(w):
            pu = max(pu, float(np.abs(w.sum(axis=1) - 1.0).max()))
            lp = max(lp, float(np.linalg.norm(w @ handles - (points[start : start + rows] - centre),
                                              axis=1).max()) / diag)
    return pu, lp


def parts_record(scene: Scene) -> list:
    return [{"path": p.path, "vertices": len(p.surface.vertices), "normals": p.normals,
             "to_world": np.asarray(p.to_world, dtype=np.float64).tolist()} for p in scene.parts]


def asset_record(scene: Scene):
    return None if scene.asset is None else {"path": scene.asset, **scene.metadata}


@dataclass
class GridStats:
    """The grid a bind solved on."""

    shape: list  # nodes along x, y, z
    spacing: float
    interior_nodes: int
    ring_nodes: int  # cut-off nodes included
    cut_off_nodes: int  # interior nodes that thin wedges of the cage cut off (they took the boundary data)
    band_nodes: int


@dataclass
class ResolutionChoice:
    """What resolution a bind was asked for and, for "auto", what it chose and why."""

    requested: "int | str"
    chosen: int | None = None  # "auto": the resolution bound at
    needed: int | None = None  # what the cage (and the mesh's thin parts) ask for
    cap: int | None = None  # the device kind's cap on "auto"
    thin_parts: int | None = None  # the resolution that resolves the mesh's thin parts, when that was tried
    memory_fits: int | None = None  # the finest that fit the memory budget, when the budget stopped "auto"
    memory_budget_bytes: int | None = None  # the budget, when it stopped "auto" short of ``needed``


@dataclass
class SolverStats:
    """How the handles were solved: the preconditioner, its hierarchy, the chunks and what every solve reported."""

    preconditioner: str  # "multigrid" | "jacobi": the one asked for
    levels: list  # the multigrid's level sizes (the interior alone with Jacobi)
    chunks: int
    threads: int  # chunks solved at once (CPU threads)
    iterations: int  # the most any chunk took
    restarts: int
    rounds: list  # the first chunk's rounds of CG: (iterations, residual, identity error) at each restart
    residual: float  # the largest relative residual
    identity_error: float  # the largest deviation from partition of unity and linear precision at the nodes
    converged: bool
    chunk_iterations: list = field(default_factory=list)
    chunk_rounds: list = field(default_factory=list)
    preconditioners: list = field(default_factory=list)  # what ended each chunk's solve
    recoveries: list = field(default_factory=list)  # each switch of preconditioner after a fault, with its chunk
    coarsest_operator: dict | None = None  # the multigrid's coarsest operator (unknowns, condition, ...)
    multigrid_seconds: dict = field(default_factory=dict)  # the multigrid's setup time by phase
    devices: list | None = None  # where each share was solved, for a bind spread over several devices


@dataclass
class BindStats:
    """What a bind measured: the report a :class:`~warp_stokes.binding.store.Binding` carries as ``stats``.

    ``grid``, ``resolution`` and ``solver`` are None for mean value coordinates (no grid, no solve); ``seconds`` holds
    the time by phase (voxelize, setup, boundary, solve, sample, or mvc; total); ``made_cage`` what
    :func:`warp_stokes.make_cage` recorded when the bind made its cage.

    Examples
    --------
    >>> s = BindStats(device="cpu", method="mvc", handles=4, vertices=1)
    >>> BindStats.from_record(s.record()) == s, s.converged
    (True, True)
    """

    device: str
    method: str
    handles: int
    vertices: int
    vertices_outside_cage: int = 0
    vertices_beyond_band: int = 0
    vertices_in_thin_features: int = 0
    grid: GridStats | None = None
    resolution: ResolutionChoice | None = None
    solver: SolverStats | None = None
    memory_estimate_bytes: int = 0
    partition_of_unity_error: float = 0.0
    linear_precision_error: float = 0.0
    seconds: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    made_cage: dict | None = None

    @property
    def converged(self) -> bool:
        """Whether every solve reached its tolerance (always, without a solve)."""
        return self.solver is None or self.solver.converged

    def record(self) -> dict:
        """The report as plain JSON values, with its format (:data:`STATS_FORMAT`)."""
        return {"format": STATS_FORMAT, **dataclasses.asdict(self)}

    @classmethod
    def from_record(cls, record: dict) -> "BindStats":
        """The report from :meth:`record`, or from the flat stats of a format-1 binding file. The record's fields
        are checked by :func:`warp_stokes.binding.record.check_metadata` first."""
        if record.get("format") != STATS_FORMAT:
            return _from_flat(record)
        values = {k: v for k, v in record.items() if k != "format"}
        for name, kind in (("grid", GridStats), ("resolution", ResolutionChoice), ("solver", SolverStats)):
            if values.get(name) is not None:
                values[name] = kind(**values[name])
        return cls(**values)


def _from_flat(flat: dict) -> BindStats:
    """The typed report of a format-1 binding's flat stats (every key optional but the four BindStats requires)."""
    grid = solver = resolution = None
    if flat.get("grid_shape"):
        grid = GridStats(list(flat["grid_shape"]), flat.get("spacing", 0.0), flat.get("interior_nodes", 0),
                         flat.get("ring_nodes", 0), flat.get("cut_off_nodes", 0), flat.get("band_nodes", 0))
    if isinstance(flat.get("resolution"), dict):
        known = {f.name for f in dataclasses.fields(ResolutionChoice)}
        resolution = ResolutionChoice(**{k: v for k, v in flat["resolution"].items() if k in known})
    if flat.get("solver"):
        solver = SolverStats(
            flat["solver"], list(flat.get("levels", [])), flat.get("chunks", 1), flat.get("threads", 1),
            flat.get("iterations", 0), flat.get("restarts", 0), list(flat.get("solver_rounds", [])), flat.get("residual", 0.0),
            flat.get("identity_error", 0.0), bool(flat.get("converged", True)), list(flat.get("chunk_iterations", [])),
            list(flat.get("chunk_rounds", [])), list(flat.get("preconditioners", [])),
            list(flat.get("recoveries", [])), flat.get("coarsest_operator"), dict(flat.get("multigrid_seconds", {})),
            flat.get("devices"))
    return BindStats(
        flat["device"], flat.get("method", "stokes"), flat["handles"], flat["vertices"],
        flat.get("vertices_outside_cage", 0), flat.get("vertices_beyond_band", 0),
        flat.get("vertices_in_thin_features", 0), grid, resolution, solver, flat.get("memory_estimate_bytes", 0),
        flat.get("partition_of_unity_error", 0.0), flat.get("linear_precision_error", 0.0),
        dict(flat.get("seconds", {})), list(flat.get("warnings", [])), flat.get("made_cage"))


def grid_stats(grid) -> GridStats:
    """What the grid is, for the binding's stats."""
    return GridStats(list(grid.shape), grid.spacing, grid.n_interior, grid.n_ring, grid.n_cut_off, grid.n_band)


def mvc_stats(checked: Cage, surface, inside, backend: Backend, pu_error: float, lp_error: float,
              seconds: dict) -> BindStats:
    """The stats of a binding by mean value coordinates: no grid, no solve."""
    return BindStats(
        device=backend.name, method="mvc", handles=checked.n_handles, vertices=len(surface.vertices),
        vertices_outside_cage=int((~inside).sum()),
        # the float32 weights and one float64 block of rows on the device
        memory_estimate_bytes=(4 * len(surface.vertices) + 8 * min(len(surface.vertices), 1 << 16))
        * checked.n_handles,
        partition_of_unity_error=pu_error, linear_precision_error=lp_error, seconds=seconds,
        warnings=list(checked.notes))


def settings_record(resolution, plan, surface, checked: Cage, scene: Scene, cage_prim) -> dict:
    """The settings a binding was made with (``plan``: its :class:`~warp_stokes.binding.plan.GridPlan`), and where
    its inputs came from."""
    grid = plan.equation is not None
    local = grid and plan.local_data
    return {
        "method": plan.method,
        "resolution": int(resolution) if grid else None,
        "tol": plan.tol if grid else None,
        "max_iterations": plan.max_iterations if grid else None,
        "solver": plan.preconditioner if grid else None,
        "boundary": str(plan.boundary) if grid else None,
        "sampling": plan.sampling if grid else None,
        # the local data's parameters, to rebuild it (warp_stokes.show solves a handle again)
        "boundary_settings": dataclasses.asdict(plan.boundary) if local else None,
        "mesh": surface.name,
        "cage": checked.name,
        "cage_prim": cage_prim,
        "mesh_prims": [p.path for p in scene.parts] if scene.asset else None,
        "rest_time": scene.metadata.get("rest_time"),
        "cage_flipped": checked.flipped,
        "cage_handles": ("the cage's vertices, in its order" if checked.source_index is None else
                         f"{len(checked.source_index)} vertices merged into {checked.n_handles} handles, in order of "
                         "first appearance (map: cage_source_index)"),
        "warp_version": wp.config.version,
        "warp_stokes_version": __version__,
    }


def solver_stats(part, preconditioner: str) -> SolverStats:
    """The solve reports of all chunks of a grid part (:class:`~warp_stokes.binding.columns.GridColumns`), summed
    up: ``recoveries`` lists each switch of preconditioner after a fault (with its chunk), ``preconditioners`` what
    ended each chunk's solve."""
    reports = part.reports
    return SolverStats(
        preconditioner=preconditioner, levels=list(part.levels), chunks=part.chunks, threads=part.threads,
        iterations=max(r.iterations for r in reports), restarts=max(r.restarts for r in reports),
        rounds=reports[0].rounds, residual=max(r.residual for r in reports),
        identity_error=max(r.identity_error for r in reports), converged=all(r.converged for r in reports),
        chunk_iterations=[r.iterations for r in reports], chunk_rounds=[r.rounds for r in reports],
        preconditioners=[r.preconditioner for r in reports],
        recoveries=[{"chunk": k, **event} for k, r in enumerate(reports) for event in (r.recoveries or [])],
        coarsest_operator=part.coarsest, multigrid_seconds=dict(part.multigrid_seconds),
        devices=part.devices or None)
