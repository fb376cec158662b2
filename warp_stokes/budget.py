"""Memory budget of a bind: what the solve will allocate, estimated before allocating it, and handle chunks.

Per handle, the arrays are known exactly once the grid is voxelised: the packed field (16 B per active node),
the float64 MVC values while the boundary data is packed (8 B per active node), five CG vectors (16 B per
interior node each: right-hand side, residual, preconditioned residual, direction, operator applied to it)
and the multigrid work vectors (2 per fine node, 4 per coarse node). Shared by all handles: the grid's index
arrays, the multigrid hierarchy and the transient assembled fine operator used to form the first Galerkin
product (calibrated per fine node, see tests/test_budget.py and benchmarks/RESULTS.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .boundary import COMPLEMENT_COLUMNS
from .device import available_memory, resolve_device  # noqa: F401 (re-exported)
from .errors import ResolutionError
from .grid import Grid

__all__ = ["MemoryEstimate", "estimate_memory", "available_memory", "plan_chunks", "chunk_columns"]

VEC4 = 16
#: coarse level size over the next finer one (measured 0.15-0.19 on the real cages at n = 64-96)
COARSENING_RATIO = 0.19
#: bytes per fine interior node held by the hierarchy and by the setup's transient fine operator and products:
#: fine operator blocks (19 x 68 B) with their triplets (19 x 72 B), the prolongation and its transpose
#: (3.3 blocks of 68 B each), the product A P (about 12 blocks), coarse operators (about 22 blocks per coarse
#: node), inverse diagonal blocks (64 B per node per level)
SETUP_BYTES_PER_NODE = 19 * 72 + 19 * 68 + 2 * 3.3 * 68 + 64
HIERARCHY_BYTES_PER_NODE = 2 * 3.3 * 68 + 64 + (COARSENING_RATIO / (1 - COARSENING_RATIO)) * (27 * 68 + 64)


@dataclass
class MemoryEstimate:
    """Bytes a bind will allocate on its device.

    Attributes
    ----------
    per_handle : int, bytes that scale with the number of handles solved at once (per handle)
    shared : int, bytes independent of the handles (grid arrays, multigrid hierarchy, setup transients)
    """

    per_handle: int
    shared: int

    def total(self, n_handles: int) -> int:
        return int(self.shared + n_handles * self.per_handle)


def estimate_memory(grid: Grid, n_vertices: int = 0, preconditioner: str = "multigrid") -> MemoryEstimate:
    """Estimate the device memory of solving and sampling on ``grid``, before allocating it.

    Parameters
    ----------
    grid : Grid
    n_vertices : int, mesh vertices to sample (their weights are held on the device per handle)
    preconditioner : "multigrid" | "jacobi"

    Returns
    -------
    MemoryEstimate

    Examples
    --------
    >>> est = estimate_memory(grid, n_vertices=26155)   # doctest: +SKIP
    >>> est.total(118) / 2**30                           # doctest: +SKIP
    1.9
    """
    n_int, n_act = grid.n_interior, grid.n_active
    coarse = n_int * COARSENING_RATIO / (1 - COARSENING_RATIO) if preconditioner == "multigrid" else 0.0
    work = 2 * VEC4 * n_int + 4 * VEC4 * coarse if preconditioner == "multigrid" else 0
    field = VEC4 * n_act
    # the MVC values (8 B) exist while the field is packed, before the CG vectors are allocated
    per_handle = field + max(8 * n_act, 5 * VEC4 * n_int + work) + 4 * n_vertices
    nodes = int(np.prod(grid.shape))
    shared = 4 * nodes + 12 * n_act + 24 * n_int + 40 * n_vertices  # index, node lists, identity check, sampling
    if preconditioner == "multigrid":
        shared += 4 * nodes + max(SETUP_BYTES_PER_NODE, HIERARCHY_BYTES_PER_NODE) * n_int
    return MemoryEstimate(per_handle=int(math.ceil(per_handle)), shared=int(math.ceil(shared)))


def plan_chunks(estimate: MemoryEstimate, n_handles: int, budget: int, resolution: int,
                name: str = "the cage") -> list[slice]:
    """Split the handles into chunks that fit the budget (one chunk when all fit).

    A chunk's field carries :data:`~warp_stokes.boundary.COMPLEMENT_COLUMNS` more columns than it has handles
    (the rest of the cage, for the solver's identity check), which the chunk sizes leave room for.

    Raises
    ------
    ResolutionError
        When not even one handle (with the complement columns) fits; the message names a resolution that would
        fit (memory grows with the cube of the resolution).

    Examples
    --------
    >>> plan_chunks(MemoryEstimate(per_handle=100, shared=1000), 10, budget=1800, resolution=64)
    [slice(0, 4, None), slice(4, 8, None), slice(8, 10, None)]
    """
    room = budget - estimate.shared
    columns = int(room // estimate.per_handle) if room > 0 else 0
    if columns >= n_handles:
        return [slice(0, n_handles)]
    per_chunk = columns - COMPLEMENT_COLUMNS
    if per_chunk < 1:
        need = estimate.total(1 + COMPLEMENT_COLUMNS)
        fits = int(resolution * (budget / need) ** (1.0 / 3.0) * 0.95)
        raise ResolutionError(
            f"{name}: resolution {resolution} needs at least {need / 2**30:.2f} GiB to solve one handle at a time "
            f"(with the {COMPLEMENT_COLUMNS} columns that check it), but the memory budget is "
            f"{budget / 2**30:.2f} GiB; resolution {max(fits, 8)} or less would fit"
        )
    n_chunks = -(-n_handles // per_chunk)
    size = -(-n_handles // n_chunks)  # balanced chunks
    return [slice(s, min(s + size, n_handles)) for s in range(0, n_handles, size)]


def chunk_columns(chunks: list[slice]) -> int:
    """Columns of the largest chunk's field: its handles, plus the complement columns when there are chunks."""
    largest = max(c.stop - c.start for c in chunks)
    return largest + (COMPLEMENT_COLUMNS if len(chunks) > 1 else 0)
