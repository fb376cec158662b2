"""Memory budget of a bind: what the solve will allocate, estimated before allocating it, and handle chunks.

Every large allocation is known once the grid is voxelised and its multigrid levels are coarsened (sizes, not
operators: :func:`warp_stokes.solver.multigrid.coarsen`). Per column (a handle, or the column that stands for
the rest of the cage in a chunk), in bytes, with N_a active, N_i interior nodes, N_l nodes of coarse level l, V
mesh vertices:

- the packed field (q, G): 16 N_a, for the whole chunk;
- the multigrid's work vectors, kept from one chunk to the next: 32 N_i on the fine level, 64 N_l on coarse ones;
- and the largest of what the stages add: the float64 MVC values while the boundary data is packed (8 N_a; a
  CPU with the local data adds 8 per node of even coordinates it interpolates the starting guess from), the
  CG vectors during the solve (residual, direction, and A p which the preconditioned residual then overwrites:
  48 N_i), the sampled weights (4 V).

Shared by all columns: the grid's node index (4 per lattice node), node coordinates (12 N_a) and stencil work
items (on a GPU 16 per patch, on a CPU 72 N_i: each interior node's neighbour rows), the multigrid hierarchy
(27 blocks of 64 B per coarse node, its diagonal, coordinates and lattice indices:
:func:`warp_stokes.solver.multigrid.hierarchy_bytes`), and per stage the node positions for the MVC
(24 N_a) or the sampling's per-vertex arrays (80 V); on the CPU, the multigrid's setup, which forms the coarsest
level's inverse on the host (4 float64 copies of its dense operator: 5 MB for the CPU's 100 nodes at most). The
local boundary data's normal derivatives (8 bytes per cage face and handle:
:func:`warp_stokes.geometry.local_data.local_data_bytes`, 384 MB for a cage of 4,898 handles) are on the device
while the boundary data is formed. Threads that solve chunks at once on the CPU (``lanes``) each hold their own stage
arrays and columns (:meth:`MemoryEstimate.total`). On the CPU the host arrays live in the same memory and are
counted too: the grid's (labels and index, 5 per lattice node, and 12 N_a), the weights of all handles (4 V per
handle), the mesh as loaded and its per-vertex checks (about 120 V), the sampled columns' host copy (4 V per
column), the host's copy of the local data's normal derivatives, kept throughout, and each ring and band row's blend
of faces (296 bytes: :func:`warp_stokes.geometry.local_boundary.blend_table`), formed once for every chunk.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..geometry.boundary import COMPLEMENT_COLUMNS, start_lattice_nodes
from ..device import Backend
from ..memory import available_memory, memory_size  # noqa: F401 (available_memory re-exported)
from ..errors import ResolutionError
from ..geometry.grid import DEVICE_NODE_BYTES, HOST_NODE_BYTES, Grid
from ..geometry.local_boundary import BLEND_ROW_BYTES
from ..kernels.stencil_cpu import NEIGHBOURS
from . import multigrid
from .multigrid import coarsest_nodes_for, hierarchy_bytes

__all__ = ["MemoryEstimate", "estimate_memory", "available_memory", "plan_chunks", "plan_lanes", "chunk_columns"]

VEC4 = 16
#: coarse level size over the next finer one, used when the levels are not given: the largest ratio measured with
#: the earlier coarsening, whose levels shrank by 5-7; the present one's shrink by about 8, so the figure stays an
#: upper bound
COARSENING_RATIO = 0.19
#: bytes per coarse node held by the hierarchy and its lattice index (4 B per lattice node, about 8 lattice nodes
#: per coarse node for a bulky cage; less for a thin one), when the levels are not given
COARSE_NODE_BYTES = multigrid.COARSE_NODE_BYTES + 4 * 8


#: what each thread beyond the first adds whatever its chunk (its stack's and its malloc arena's pages, its
#: launches' arguments, its solve's small arrays): without it, binds on many threads peaked up to 2-3 MB a thread
#: beyond the plan (small grids less)
LANE_BYTES = 3 * 2**20


@dataclass
class MemoryEstimate:
    """Bytes a bind will allocate on its device.

    Attributes
    ----------
    per_handle : int, bytes per column of the stage that needs the most per column
    shared : int, bytes independent of the columns (grid arrays, multigrid hierarchy, the largest stage's share)
    stages : list of (shared, per_column) pairs, optional
        What each stage adds to the arrays that live throughout; when given, :meth:`total` is exact: the largest
        stage, rather than the larger share plus the larger per-column cost.
    base : int, bytes that live throughout (only used with ``stages``)
    fixed : int, bytes that a smaller resolution need not save (the largest dense inverse of a coarsest level, the
        local boundary data's arrays)
    """

    per_handle: int
    shared: int
    stages: list = field(default_factory=list)
    base: int = 0
    fixed: int = 0

    def total(self, n_columns: int, lanes: int = 1) -> int:
        """Peak bytes with ``n_columns`` columns solved at once, by ``lanes`` threads that each solve their share
        (the stages with columns are the lanes': each lane's arrays are its own, and each may be in its largest
        stage at once; the stages without, before the lanes start, happen once)."""
        per_lane = -(-int(n_columns) // max(1, int(lanes)))
        threads = LANE_BYTES * (lanes - 1)
        if self.stages:
            in_lanes = lanes * max((s + per_lane * c for s, c in self.stages if c > 0), default=0)
            return int(self.base + threads + max([in_lanes] + [s for s, c in self.stages if c == 0]))
        return int(self.shared + (lanes - 1) * (self.shared - self.base) + n_columns * self.per_handle + threads)


def estimate_memory(grid: Grid, n_vertices: int = 0, preconditioner: str = "multigrid", levels=None,
                    device=None, n_handles: int = 0, boundary_bytes: tuple = (0, 0, 0)) -> MemoryEstimate:
    """Estimate the memory of solving and sampling on ``grid``, before allocating it.

    Parameters
    ----------
    grid : Grid
    n_vertices : int, mesh vertices to sample
    preconditioner : "multigrid" | "jacobi"
    levels : list of multigrid levels (:func:`warp_stokes.solver.multigrid.coarsen`), optional
        Their sizes make the hierarchy's share exact; without them coarse levels are estimated from
        ``COARSENING_RATIO``.
    device : None | str | Backend, where the bind runs; on the CPU the grid's host arrays count too, and so do the mesh's
    n_handles : int, all the cage's handles: on the CPU the bind's weights (4 bytes per vertex and handle) live in
        the same memory throughout
    boundary_bytes : (kept, work, device_work), the boundary data's arrays of the whole cage
        (:func:`warp_stokes.geometry.local_data.local_data_bytes`; zeros for MVC): ``kept`` on the device while
        the boundary data is formed, and on the CPU also held by the host throughout, ``work`` on the host and
        ``device_work`` on a GPU while they are computed. They do not shrink with the resolution.

    Returns
    -------
    MemoryEstimate

    Examples
    --------
    >>> est = estimate_memory(grid, n_vertices=26155)   # doctest: +SKIP
    >>> est.total(118) / 2**30                           # doctest: +SKIP
    1.9
    """
    backend = Backend.of(device)
    n_int, n_act, n_v = grid.n_interior, grid.n_active, int(n_vertices)
    kept, local_work, device_work = (int(b) for b in (tuple(boundary_bytes) + (0, 0, 0))[:3])
    nodes = int(np.prod(grid.shape))
    multigrid = preconditioner == "multigrid"
    if not multigrid:
        coarse, hierarchy, dense = 0.0, 0, 0
    else:
        limit = coarsest_nodes_for(backend)
        if levels is None:  # coarsen by the typical ratio until the coarsest level's size
            sizes = [float(n_int)]
            while sizes[-1] > limit:
                sizes.append(sizes[-1] * COARSENING_RATIO)
            coarse = sum(sizes[1:])
            hierarchy = COARSE_NODE_BYTES * coarse + 4 * (4 * sizes[-1]) ** 2
        else:
            sizes = [lev.n for lev in levels]
            coarse, hierarchy = float(sum(sizes[1:])), hierarchy_bytes(levels)
        # the coarsest level's dense inverse (float32) does not shrink with the resolution: at most this
        dense = 4 * (4 * limit) ** 2
    work = (2 * VEC4 * n_int + 4 * VEC4 * coarse) if multigrid else 0.0
    on_cpu = backend.on_cpu
    if on_cpu:  # the node loop's neighbour rows: 18 int32 per interior node
        work_items = 4 * NEIGHBOURS * n_int
    else:  # the patch walks: an item per 2 x 2 columns and up to 64 planes, fewer than one per 16 nodes; the
        # smoother step's 1 x 2: one per 8
        work_items = 16 * n_int / 16 + 16 * n_int / 8
    base = DEVICE_NODE_BYTES * nodes + 12 * n_act + work_items + hierarchy
    if on_cpu:
        # the grid's host arrays; the weights of all handles; the mesh as loaded (float64 vertices, about two
        # int64 triangles per vertex), its classification and the vertex-sized arrays of the checks
        base += HOST_NODE_BYTES * nodes + 12 * n_act + 4 * n_v * int(n_handles) + 120 * n_v + kept
        if kept:  # the local data's blend of each ring and band row, kept for every chunk
            base += BLEND_ROW_BYTES * (n_act - n_int)
    field_bytes = VEC4 * n_act
    # a CPU with the local data interpolates the starting guess from MVC at nodes of even coordinates (their own
    # values and positions beside the rows')
    lattice = start_lattice_nodes(grid, "local", backend) if kept else 0
    stages = [
        # boundary data: positions, MVC values in float64, the local data's normal derivatives (the device's copy;
        # a CPU reads the host's, but measured its peak as if it copied them: counted)
        (24 * (n_act + lattice) + kept, field_bytes + work + 8 * (n_act + lattice)),
        (0, field_bytes + work + 3 * VEC4 * n_int),  # solve: CG vectors
        # sampling: per-vertex cells and weights (on the CPU also their host copy)
        (80 * n_v, field_bytes + work + (8 if on_cpu else 4) * n_v),
    ]
    # the local data computed (while voxelising): the graph, a group's arrays
    stages.append((local_work if on_cpu else device_work, 0))
    if on_cpu:
        if multigrid:
            # the coarsest inverse formed on the host (the multigrid's setup): the float64 operator, LAPACK's copy
            # of it and the inverse it writes, and the Cholesky factor that proves it positive definite
            unknowns = 4 * sizes[-1]
            stages.append((4 * 8 * unknowns**2, 0))
    stages = [(int(math.ceil(s)), int(math.ceil(c))) for s, c in stages]
    return MemoryEstimate(
        per_handle=max(c for _, c in stages),
        shared=int(math.ceil(base)) + max(s for s, _ in stages),
        stages=stages,
        base=int(math.ceil(base)),
        fixed=int(dense + kept * (2 if on_cpu else 1)),
    )


def plan_chunks(estimate: MemoryEstimate, n_handles: int, budget: int, resolution: int,
                name: str = "the cage") -> list[slice]:
    """Split the handles into chunks that fit the budget (one chunk when all fit).

    A chunk's field carries :data:`~warp_stokes.geometry.boundary.COMPLEMENT_COLUMNS` more columns than it has handles
    (the rest of the cage, for the solver's identity check), which the chunk sizes leave room for.

    Raises
    ------
    ResolutionError
        When not even one handle (with the complement columns) fits; the message names a resolution that would
        fit (memory grows with the cube of the resolution).

    Examples
    --------
    >>> plan_chunks(MemoryEstimate(per_handle=100, shared=1000), 10, budget=1800, resolution=64)
    [slice(0, 5, None), slice(5, 10, None)]
    """
    if estimate.total(n_handles) <= budget:
        return [slice(0, n_handles)]
    # the most columns that fit (total() grows with the columns)
    lo, hi = 0, n_handles
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if estimate.total(mid) <= budget else (lo, mid - 1)
    per_chunk = lo - COMPLEMENT_COLUMNS
    if per_chunk < 1:
        need = estimate.total(1 + COMPLEMENT_COLUMNS)
        # what grows with the resolution grows with its cube (interior) or square (ring, band, vertices' cells):
        # scaling by the square root of the excess is safe for both
        if budget <= estimate.fixed:
            raise ResolutionError(
                f"{name}: the cage's boundary data and the coarsest level need {memory_size(estimate.fixed)} at "
                f"any resolution (they grow with the cage's faces times its handles), but the memory budget is "
                f"{memory_size(budget)}; raise the budget, or use a cage with fewer handles or boundary 'mvc'"
            )
        ratio = max(budget - estimate.fixed, 0) / max(need - estimate.fixed, 1)
        fits = max(int(resolution * ratio ** 0.5), 8)
        error = ResolutionError(
            f"{name}: resolution {resolution} needs at least {memory_size(need)} to solve one handle at a time "
            f"(with the column of the rest of the cage that checks it), but the memory budget is "
            f"{memory_size(budget)}; resolution {fits} or less would fit"
        )
        # resolution "auto" tries the cube root's (the interior's) estimate, closer and sometimes too much: it is
        # planned again there, and tried coarser again if it does not fit
        error.fits = max(int(resolution * ratio ** (1.0 / 3.0)), 8)
        raise error
    n_chunks = -(-n_handles // per_chunk)
    size = -(-n_handles // n_chunks)  # balanced chunks
    return [slice(s, min(s + size, n_handles)) for s in range(0, n_handles, size)]


def plan_lanes(estimate: MemoryEstimate, n_handles: int, budget: int, resolution: int, lanes: int,
               name: str = "the cage", partial: bool = False, lane_table: int = 0) -> tuple[list[slice], int]:
    """Chunks of handles for ``lanes`` threads that solve a chunk each at once, within the budget, and how many
    lanes run: one chunk per lane when all fit together, else smaller chunks taken in turn (fewer lanes where not
    even one handle per lane fits). Every chunk carries the complement column when there are several (or the range
    is ``partial``); with one lane this is :func:`plan_chunks`. ``lane_table``: bytes that several lanes share
    and one does not need (the starting values of every handle).

    Raises
    ------
    ResolutionError
        As :func:`plan_chunks`, when not even one handle fits.

    Examples
    --------
    >>> estimate = MemoryEstimate(per_handle=10**6, shared=10**7)
    >>> plan_lanes(estimate, 10, budget=40 * 10**6, resolution=64, lanes=2)
    ([slice(0, 5, None), slice(5, 10, None)], 2)
    >>> plan_lanes(estimate, 10, budget=33 * 10**6, resolution=64, lanes=2)
    ([slice(0, 3, None), slice(3, 6, None), slice(6, 8, None), slice(8, 10, None)], 2)
    >>> plan_lanes(estimate, 10, budget=18 * 10**6, resolution=64, lanes=2)
    ([slice(0, 5, None), slice(5, 10, None)], 1)
    """
    lanes = max(1, min(int(lanes), n_handles))
    extra = COMPLEMENT_COLUMNS if partial else 0
    budget_of_lanes = budget - lane_table
    while lanes > 1:
        if estimate.total(n_handles + lanes * COMPLEMENT_COLUMNS, lanes) <= budget_of_lanes:
            return _split(n_handles, lanes), lanes  # one chunk per lane
        # the most columns that fit at once, shared by the lanes, each chunk with its complement column
        lo, hi = 0, n_handles + lanes * COMPLEMENT_COLUMNS
        while lo < hi:
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if estimate.total(mid, lanes) <= budget_of_lanes else (lo, mid - 1)
        per_chunk = lo // lanes - COMPLEMENT_COLUMNS
        if per_chunk >= 1:
            # balanced, in rounds that keep every lane busy
            n_chunks = -(-(-(-n_handles // per_chunk)) // lanes) * lanes
            return _split(n_handles, min(n_chunks, n_handles)), lanes
        lanes -= 1
    planned = plan_chunks(estimate, n_handles + extra, budget, resolution, name=name)
    return [slice(c.start, min(c.stop, n_handles)) for c in planned if c.start < n_handles], 1


def _split(n: int, parts: int) -> list[slice]:
    """``parts`` consecutive slices of ``range(n)`` whose sizes differ by one at most, the larger first."""
    size, larger = divmod(n, parts)
    bounds = np.cumsum([0] + [size + (k < larger) for k in range(parts)])
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def chunk_columns(chunks: list[slice]) -> int:
    """Columns of the largest chunk's field: its handles, plus the complement columns when there are chunks."""
    largest = max(c.stop - c.start for c in chunks)
    return largest + (COMPLEMENT_COLUMNS if len(chunks) > 1 else 0)
