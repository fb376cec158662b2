"""The multigrid levels' nodes: which lattice nodes each coarser level keeps, found before any operator is formed
(so that the memory plan can count the hierarchy), and what the levels' operators will take."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..device import Backend
from ..geometry.grid import Grid, lattice_counts, lattice_rows
from ..kernels import multigrid as mg_kernels

__all__ = ["Level", "coarsen", "coarsest_nodes_for", "lattice_shift", "hierarchy_bytes", "COARSEST_NODES",
           "COARSEST_NODES_CPU", "COARSE_NODE_BYTES"]

#: on a GPU, coarsen until a level has at most this many nodes; it is then inverted densely on the host (1600 x 1600
#: floats at most: 10 MiB on the device). A lower limit adds a level below and costs CG iterations (one at n = 80 on
#: a bulky cage, measured)
COARSEST_NODES = 400
#: on a CPU the inverse's host work (float64 copies, 32 (4m)^2 bytes: 82 MB at 400 nodes) is the bind's own memory,
#: more than a small grid's solve: at 400 a bind's peak did not grow with n but zig-zagged. At 100 it grows with n,
#: with the same iterations beyond the smallest grids and the same weights to float32 rounding
#: (measured: benchmarks/RESULTS.md)
COARSEST_NODES_CPU = 100


def coarsest_nodes_for(device) -> int:
    """The size at which coarsening stops on ``device``: :data:`COARSEST_NODES_CPU` on a CPU, else
    :data:`COARSEST_NODES`.

    Examples
    --------
    >>> coarsest_nodes_for("cpu")
    100
    """
    return Backend.of(device).pick(cpu=COARSEST_NODES_CPU, gpu=COARSEST_NODES)


#: device bytes per node of a coarse level: 27 blocks of the operator and its neighbours' rows, the diagonal's
#: inverse, its coordinates
COARSE_NODE_BYTES = 27 * 64 + 27 * 4 + 64 + 12


@dataclass
class Level:
    n: int  # unknown nodes
    ijk: np.ndarray  # (n, 3) lattice coordinates at this level
    index: wp.array  # lattice -> row (rows >= n are not unknowns of this level), or -1
    ijk_device: wp.array | None = None  # ijk on the device
    blocks: wp.array | None = None  # (n, 27) mat44f operator blocks; None on the fine level (the 19-point stencil)
    rows: wp.array | None = None  # (n, 27) int32 rows of each node's neighbours (-1: none); coarse levels
    inv_diag: wp.array | None = None  # (n,) mat44 inverses of the diagonal blocks ((1,) on the fine level)
    lmax: float = 0.0
    work: dict = field(default_factory=dict)
    shift: tuple = (0, 0, 0)  # this level's node c sits on the finer level's node 2c + shift


def coarsen(grid: Grid, device=None, coarsest_nodes: int | None = None) -> list[Level]:
    """The nodes of every multigrid level, before any operator is formed (cheap: a pass over each lattice).

    Parameters
    ----------
    grid : Grid
    device : None | str | Backend
    coarsest_nodes : int, optional, coarsening stops at a level with at most this many nodes (default by the
        device: :func:`coarsest_nodes_for`)

    Returns
    -------
    list of Level, finest first: the interior nodes of ``grid``, then the kept nodes of each coarser lattice

    Examples
    --------
    >>> levels = coarsen(grid, device="cpu")    # doctest: +SKIP
    >>> [lev.n for lev in levels]                # doctest: +SKIP
    [16563, 2077, 268]
    """
    backend = Backend.of(device)
    coarsest_nodes = coarsest_nodes_for(backend) if coarsest_nodes is None else int(coarsest_nodes)
    arrays = grid.device_arrays(backend)
    n0 = grid.n_interior
    fine = Level(n=n0, ijk=grid.active_ijk[:n0], index=arrays["index"], ijk_device=arrays["active_ijk"][:n0])
    levels = [fine]
    shape = np.array(grid.shape)
    with backend.scope():
        while levels[-1].n > coarsest_nodes:
            lev = levels[-1]
            shift = lattice_shift(lev)
            coarse_shape = tuple(int(s) for s in shape // 2 + 1)
            kept = wp.empty(coarse_shape, dtype=wp.int8)
            wp.launch(mg_kernels.coarse_nodes, dim=coarse_shape, inputs=[lev.index, lev.n, wp.vec3i(*shift)],
                      outputs=[kept])
            counts, per_class = lattice_counts(kept)
            n = int(per_class[0])
            # every unknown kept: all of one parity, no two neighbours, and the level's operator block diagonal
            if n == 0 or n >= lev.n:
                break
            index, ijk = lattice_rows(kept, counts, n)
            del kept, counts
            levels.append(Level(n=n, ijk=ijk.numpy(), index=index, ijk_device=ijk, shift=shift))
            shape = np.array(coarse_shape)
    return levels


def lattice_shift(level: Level) -> tuple:
    """Where the next coarser lattice sits on ``level``'s: its node c on ``level``'s node 2c + shift, each of the
    shift's components 0 or 1. No shift unless another would keep more than twice the coarse nodes
    (:func:`warp_stokes.kernels.multigrid.coarse_nodes` keeps a node over each unknown of the shift's parities): a
    thin sheet of unknowns at odd coordinates keeps coarsening. At least 1/16 of the unknowns become coarse nodes.

    Parameters
    ----------
    level : Level, with its node coordinates on the device (``ijk_device``); counted on the current device

    Returns
    -------
    tuple of 3 int

    Examples
    --------
    >>> lattice_shift(levels[0])   # doctest: +SKIP
    (0, 0, 0)
    """
    counts = wp.zeros(8, dtype=wp.int32)
    wp.launch(mg_kernels.parity_counts, dim=level.n, inputs=[level.ijk_device], outputs=[counts])
    counts = counts.numpy()
    best = int(np.argmax(counts))
    if 2 * counts[0] >= counts[best]:
        return (0, 0, 0)
    return (best & 1, (best >> 1) & 1, (best >> 2) & 1)


def hierarchy_bytes(levels: list[Level]) -> int:
    """Device bytes of the operators a :class:`Multigrid` forms on ``levels`` (coarse blocks, diagonals, node
    coordinates, lattice indices, the coarsest level's dense inverse), shared by all handles."""
    total = 64 * (128 + 64) + 64  # the prolongation's table (64 blocks, float64 and float32), the fine diagonal block
    for lev in levels[1:]:
        total += COARSE_NODE_BYTES * lev.n + 4 * lev.index.size
    coarsest = 4 * levels[-1].n
    return int(total + 4 * coarsest * coarsest)
