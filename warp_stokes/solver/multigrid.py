"""Geometric multigrid for the compact coupled scheme, used as the preconditioner of the batched CG.

One V-cycle for all handles at once (every handle a column of the level arrays):

- levels: interior nodes of the grid, then nodes of lattices of spacing 2h, 4h, ...; a coarse node is kept where
  the finer node under it is an unknown, which makes every coarse operator positive definite by construction
  (``kernels.multigrid.coarse_nodes`` says why; keeping nodes for the finer unknowns around them made the coarsest
  operator singular on thin parts at some resolutions, and CG diverged); a coarse lattice may sit one finer step
  off along some axes (:func:`warp_stokes.solver.hierarchy.lattice_shift`) where that keeps a thin sheet coarsening;
- prolongation: cubic Hermite, using the stored gradients (value at an edge midpoint (q0+q1)/2 + (G0-G1)/8),
  applied axis by axis; its blocks form a table of 64 entries (the fine node's parities, which parent);
- coarse operators: Galerkin products P^T A P, so they stay symmetric positive definite. On a lattice they are
  27-point block stencils: formed by one kernel per level straight from the finer stencil (the fine operator is
  never assembled) and stored as (nodes, 27) 4x4 blocks;
- smoother: Chebyshev polynomial in D^-1 A (D the 4x4 diagonal blocks) on [lmax/30, lmax], of degree 3 on the
  two finest levels and 8 below (4, 4 and 12 in hierarchies of 8 levels or more): cheap there, and the deep levels'
  corrections limited convergence (the higher degrees below cut a deep hierarchy's CG iterations by nearly a third
  and its time by a fifth), lmax 1.2 times the estimate of 40 power iterations (12 underestimated it by a fifth on
  a deep hierarchy, and higher degrees then diverged); it is a fixed polynomial, so the V-cycle is a symmetric
  preconditioner;
- coarsest level: its inverse in float64, checked (:func:`coarsest_inverse`: scaled to a unit diagonal, a Cholesky
  factorisation and a bound of the condition number, else an eigendecomposition that leaves out eigenvalues below
  COARSEST_CUTOFF of the largest: a mode the float32 cycle cannot resolve is dropped, not amplified), its
  conditioning recorded
  (:attr:`Multigrid.coarsest`); for a GPU computed on a host thread
  while the device estimates the smoother's eigenvalues and the bind forms its boundary data (it is first needed by
  the first V-cycle).

When a solve finds the cycle misbehaving (:mod:`warp_stokes.solver.solve`), :meth:`Multigrid.bound_eigenvalues`
replaces the estimated upper ends of the smoothers by guaranteed ones (the largest absolute row sum of D^-1 A).

Harmonic coordinates (``equation="laplace"``, the 7-point operator of ``warp_stokes.kernels.laplace``) use the same
cycle with a trilinear prolongation of each of (q, G): their gradient rows are identity rows, decoupled.

No general sparse matrix is involved: warp.sparse addresses block values with 32-bit offsets
(`block * block_size` in int), which overflowed once the fine operator's 19 blocks of 16 per interior node passed
2^31 scalars (8.5 M interior nodes, a bulky cage at n = 256). Every index here is a row of a level (< 2^31).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import threading
import time
from concurrent.futures import Future

import numpy as np
import warp as wp

from ..device import Backend
from ..geometry.grid import Grid
from ..kernels import cg
from ..kernels import multigrid as mg_kernels
from ..kernels import multigrid_cpu
from .coarsest import COARSEST_CUTOFF, coarsest_inverse
from .coarsest import HOST as _HOST
from .coarsest import inverts_beside as _inverts_beside
from .hierarchy import (COARSE_NODE_BYTES, COARSEST_NODES, COARSEST_NODES_CPU, Level, coarsen, coarsest_nodes_for,
                        hierarchy_bytes)
from .equation import equation_of
from .operator import apply_operator, chebyshev_step

# the levels' sizes are planned before the hierarchy is formed (solver.hierarchy); offered here too
__all__ = ["Multigrid", "coarsen", "coarsest_inverse", "hierarchy_bytes", "Level", "SMOOTHER_DEGREES",
           "DEEP_SMOOTHER_DEGREES", "DEEP_LEVELS", "COARSEST_NODES", "COARSEST_NODES_CPU", "coarsest_nodes_for",
           "COARSE_NODE_BYTES", "COARSEST_CUTOFF"]

#: Chebyshev degree on the fine level, the first coarse level, ...; the last entry holds for every deeper level
#: (measured with benchmarks/bench_smoother.py: benchmarks/RESULTS.md)
SMOOTHER_DEGREES = (3, 3, 8)
#: hierarchies of at least DEEP_LEVELS levels smooth with DEEP_SMOOTHER_DEGREES: the CG iterations grew with the
#: depth, and on a hierarchy of 8 levels the higher degrees brought a chunk back within 20 CG iterations, for about
#: a tenth more time. Measured with the earlier coarsening, whose levels shrank by 5-7; the present one's shrink by
#: about 8, so hierarchies of 8 levels come only beyond n = 512 (not measured since)
DEEP_LEVELS = 8
DEEP_SMOOTHER_DEGREES = (4, 4, 12)
#: replay each V-cycle as a recorded CUDA graph on a GPU (Multigrid.apply); False launches every kernel each time
GRAPHS = True
#: held while a graph is recorded and while a solve announces itself (solving): Warp records every launch on the
#: device's stream and refuses every wait on the device while it records, so no other solve of this process may
#: run meanwhile
_RECORDING = threading.Lock()
_SOLVES = [0]  # solves in progress in this process


@contextlib.contextmanager
def solving():
    """Around a solve that may launch on a GPU: while more than one runs in this process (threads), no V-cycle is
    recorded as a graph (they are launched as they are), and none starts while one is being recorded."""
    with _RECORDING:
        _SOLVES[0] += 1
    try:
        yield
    finally:
        with _RECORDING:
            _SOLVES[0] -= 1
#: the Chebyshev interval is [lmax / SMOOTHING_RANGE, lmax]: the upper part of the spectrum is smoothed
SMOOTHING_RANGE = 30.0
POWER_ITERATIONS = 40
#: the power iteration's estimate approaches lmax from below: the smoother's upper end is this much above it
LMAX_SAFETY = 1.2

class Multigrid:
    """A V-cycle preconditioner for the interior block A_II of a grid, shared by all handles (a
    :class:`warp_stokes.solver.preconditioner.Preconditioner`).

    Parameters
    ----------
    grid : Grid
    device : None | str | Backend
    coarsest_nodes : int, optional, size at which coarsening stops (default by the device: :func:`coarsest_nodes_for`)
    levels : list of Level, optional
        The output of :func:`coarsen` for this grid and device, when it was computed already (e.g. to plan
        memory); computed here otherwise.
    equation : "biharmonic" | "laplace"
        The fine operator: the compact 19-point scheme (Hermite prolongation) or the 7-point Laplace equation of
        harmonic coordinates (trilinear prolongation).
    threads : int, optional
        On a CPU, threads that form the coarse operators (default: every core).

    Examples
    --------
    >>> mg = Multigrid(grid, device="cpu")          # doctest: +SKIP
    >>> mg.apply(residual, correction)                      # doctest: +SKIP
    """

    name = "multigrid"

    def __init__(self, grid: Grid, device=None, coarsest_nodes: int | None = None, levels=None,
                 equation: str = "biharmonic", threads: int | None = None):
        self.grid = grid
        self.backend = Backend.of(device, threads)
        self.device = self.backend.device
        self.equation = equation_of(equation)
        #: setup time by phase: Galerkin product per coarse level, the coarsest inverse, eigenvalue estimates
        self.seconds = {"galerkin": [], "coarsest": 0.0, "eigenvalues": 0.0}
        #: where the smoothers' upper ends come from: "power iteration" estimates, or guaranteed "row sums"
        self.smoother_bounds = "power iteration"
        self._coarsest = None
        #: on a GPU, each V-cycle's launches recorded once as a CUDA graph per (r, z) pair and replayed (see apply)
        self._graphs: dict = {}
        with wp.ScopedDevice(self.device):
            self.table = wp.empty(64, dtype=wp.mat44d)
            wp.launch(self.equation.prolongation_table, dim=64, outputs=[self.table])
            # the transfers read it in float32 (exact: halves, quarters, eighths): half the bytes, no conversions
            self.table32 = wp.array(self.table.numpy().astype(np.float32), dtype=wp.mat44f)
            self.levels = levels if levels is not None else coarsen(grid, self.backend, coarsest_nodes)
            self._form_operators()
            self._estimate_eigenvalues()

    # -- setup ----------------------------------------------------------------------------------------------------

    def _form_operators(self) -> None:
        fine = self.levels[0]
        # the stencil's constant diagonal
        inv = np.diag(list(self.equation.inverse_diagonal)).astype(np.float32)
        fine_operator = self.equation.multigrid_operator
        fine.inv_diag = wp.array(inv[None], dtype=wp.mat44f)
        empty = wp.empty((0, 27), dtype=wp.mat44f)
        for finer, coarse in zip(self.levels, self.levels[1:]):
            start = time.perf_counter()
            # each symmetric pair of blocks is formed once: the 14 slots from the centre on, and their transposes
            coarse.blocks = wp.zeros((coarse.n, 27), dtype=wp.mat44f)
            operands = [coarse.ijk_device, coarse.index, coarse.n, finer.index, finer.n,
                        empty if finer.blocks is None else finer.blocks,
                        int(fine_operator) if finer.blocks is None else int(mg_kernels.BLOCKS),
                        wp.vec3i(*coarse.shift), self.table]
            # on a CPU the rows are shared out between the threads (on one, a fine grid takes a good part of a second)
            self.backend.in_threads(coarse.n, lambda a, b, coarse=coarse, operands=operands: wp.launch(
                mg_kernels.galerkin_blocks, dim=(b - a, 14), inputs=[*operands, a], outputs=[coarse.blocks]),
                modules=("multigrid",))
            coarse.rows = wp.empty((coarse.n, 27), dtype=wp.int32)
            wp.launch(mg_kernels.neighbour_rows, dim=coarse.rows.shape, inputs=[coarse.ijk_device, coarse.index,
                                                                               coarse.n], outputs=[coarse.rows])
            coarse.inv_diag = wp.empty(coarse.n, dtype=wp.mat44f)
            wp.launch(mg_kernels.diagonal_inverse, dim=coarse.n, inputs=[coarse.blocks], outputs=[coarse.inv_diag])
            wp.synchronize_device()
            self.seconds["galerkin"].append(time.perf_counter() - start)
        self._coarse_inverse = None
        dense = self._dense(len(self.levels) - 1)
        if _inverts_beside(self.device):
            self._coarse_future = _HOST.submit(coarsest_inverse, dense)
        else:
            self._coarse_future = Future()
            self._coarse_future.set_result(coarsest_inverse(dense))

    @property
    def coarse_inverse(self) -> wp.array:
        """The coarsest operator's inverse, (4 n, 4 n) float32 on the device. For a GPU it is computed on a host
        thread: the first read waits for it. ``seconds["coarsest"]`` is the inversion's time (0 until read),
        ``seconds["coarsest_wait"]`` how long that first read waited (part of the first solve's time)."""
        if self._coarse_inverse is None:
            start = time.perf_counter()
            inverse, self.seconds["coarsest"], self._coarsest = self._coarse_future.result()
            self.seconds["coarsest_wait"] = time.perf_counter() - start
            self._coarse_inverse = wp.array(inverse, dtype=wp.float32, device=self.device)
            self._coarse_future = None
        return self._coarse_inverse

    @property
    def coarsest(self) -> dict:
        """The coarsest operator's figures (:func:`coarsest_inverse`'s report: ``unknowns``, ``smallest_eigenvalue``,
        ``condition``, ``dropped``); waits for its inverse where that is computed on a host thread."""
        self.coarse_inverse
        return dict(self._coarsest)

    def bound_eigenvalues(self) -> None:
        """Replace the smoothers' estimated upper ends (power iteration, times LMAX_SAFETY) by guaranteed bounds of
        the largest eigenvalue of D^-1 A: its largest absolute row sum on each level. A Chebyshev smoother whose
        interval ends below the spectrum amplifies the modes above it; with these bounds none is left above, at the
        cost of a somewhat weaker smoother. ``smoother_bounds`` says which are in use."""
        with wp.ScopedDevice(self.device):
            bounds = wp.zeros(len(self.levels), dtype=wp.float32)
            for depth, lev in enumerate(self.levels[1:-1], start=1):
                wp.launch(mg_kernels.row_sum_bound, dim=lev.n, inputs=[lev.blocks, lev.inv_diag, depth],
                          outputs=[bounds])
            bounds = bounds.numpy()
        for depth, lev in enumerate(self.levels[:-1]):
            lev.lmax = self.equation.row_sum_bound if depth == 0 else float(bounds[depth])
        self.smoother_bounds = "row sums"
        self._graphs = {}  # they hold the smoothers' old coefficients

    def _dense(self, depth: int) -> np.ndarray:
        rows, cols, blocks = self.operator_triplets(depth)
        n = self.levels[depth].n
        dense = np.zeros((n, 4, n, 4))
        np.add.at(dense, (rows, slice(None), cols, slice(None)), blocks.astype(np.float64))
        return dense.reshape(4 * n, 4 * n)

    def _estimate_eigenvalues(self) -> None:
        """lmax of D^-1 A per level (all but the coarsest) by power iteration on one random column, on the
        device: v <- D^-1 A v / |v|, and lmax = |D^-1 A v| for the last unit v."""
        start = time.perf_counter()
        # each level's |D^-1 A v|^2 in one array, read once all levels are launched: one wait and one copy
        norms = wp.zeros(max(len(self.levels) - 1, 1), dtype=wp.float64)
        for depth, lev in enumerate(self.levels[:-1]):
            v = wp.empty((lev.n, 1), dtype=wp.vec4f)
            wp.launch(mg_kernels.random_column, dim=lev.n, inputs=[depth], outputs=[v])
            av = wp.empty_like(v)
            z = wp.empty_like(v)
            squared = wp.zeros(1, dtype=wp.float64)
            threads = self.backend.reduction_threads(lev.n, 1)
            # an iteration's launches recorded once for each order of (v, z) and replayed: on one column, launching
            # is most of the cost (a replay skips packing the arguments: on a CPU about a fifth of a launch's time)
            iterations = [self._power_iteration(depth, a, b, av, squared, threads) for a, b in ((v, z), (z, v))]
            for k in range(POWER_ITERATIONS):
                squared.zero_()
                for launch in iterations[k % 2]:
                    if launch is not None:  # wp.launch records nothing for an empty launch
                        launch.launch()
            if POWER_ITERATIONS % 2:
                v = z
            wp.launch(cg.column_dots, dim=(threads, 1), inputs=[v, v, threads], outputs=[norms[depth : depth + 1]])
        for lev, squared in zip(self.levels[:-1], norms.numpy()):
            lev.lmax = LMAX_SAFETY * float(np.sqrt(squared))
        self._graphs = {}
        self.seconds["eigenvalues"] = time.perf_counter() - start

    # -- inspection -----------------------------------------------------------------------------------------------

    def operator_triplets(self, depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The operator of level ``depth`` as (rows, cols, (nnz, 4, 4) blocks) on the host, zero blocks dropped
        (level 0: the fine stencil of the interior nodes, A_II).

        Examples
        --------
        >>> rows, cols, blocks = mg.operator_triplets(1)            # doctest: +SKIP
        """
        lev = self.levels[depth]
        if lev.blocks is None:  # the fine level: its stencil, formed as blocks on demand
            blocks = wp.empty((lev.n, 27), dtype=wp.mat44f, device=self.device)
            wp.launch(mg_kernels.stencil_blocks, dim=blocks.shape, inputs=[lev.ijk_device, lev.index, lev.n,
                                                                              self.equation.multigrid_operator],
                      outputs=[blocks], device=self.device)
            blocks = blocks.numpy()
        else:
            blocks = lev.blocks.numpy()
        index = lev.index.numpy()
        offsets = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij"), -1).reshape(27, 3)
        nb = lev.ijk[:, None, :] + offsets[None]
        inside = np.all((nb >= 0) & (nb < np.array(index.shape)), axis=2)
        cols = np.full((lev.n, 27), -1)
        cols[inside] = index[tuple(nb[inside].T)]
        keep = (cols >= 0) & (cols < lev.n) & np.any(blocks != 0, axis=(2, 3))
        rows = np.repeat(np.arange(lev.n)[:, None], 27, axis=1)
        return rows[keep], cols[keep], blocks[keep]

    def prolongation_triplets(self, depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The prolongation from level ``depth + 1`` to level ``depth`` as (rows, cols, (nnz, 4, 4) blocks)."""
        fine, coarse = self.levels[depth], self.levels[depth + 1]
        with wp.ScopedDevice(self.device):
            rows = wp.empty(8 * fine.n, dtype=int)
            cols = wp.empty(8 * fine.n, dtype=int)
            blocks = wp.empty(8 * fine.n, dtype=wp.mat44f)
            wp.launch(mg_kernels.prolongation_triplets, dim=fine.n,
                      inputs=[fine.ijk_device, coarse.index, coarse.n, wp.vec3i(*coarse.shift), self.table],
                      outputs=[rows, cols, blocks])
        rows, cols, blocks = rows.numpy(), cols.numpy(), blocks.numpy()
        keep = rows >= 0
        return rows[keep], cols[keep], blocks[keep]

    # -- application ----------------------------------------------------------------------------------------------

    def _power_iteration(self, depth: int, v: wp.array, z: wp.array, av: wp.array, squared: wp.array,
                         threads: int) -> list:
        """The launches of one power iteration on level ``depth``, recorded: squared = |v|^2 (on a zeroed
        ``squared``), v /= |v|, av = A v, z = D^-1 av."""
        lev = self.levels[depth]
        return [
            wp.launch(cg.column_dots, dim=(threads, 1), inputs=[v, v, threads], outputs=[squared], record_cmd=True),
            wp.launch(mg_kernels.divide_column, dim=lev.n, inputs=[v, squared], record_cmd=True),
            self._apply_A(depth, v, av, record_cmd=True),
            wp.launch(mg_kernels.chebyshev_first, dim=(lev.n, 1), inputs=[av, lev.inv_diag, 1.0], outputs=[z, av],
                      record_cmd=True),
        ]

    def _apply_A(self, depth: int, x: wp.array, out: wp.array, record_cmd: bool = False) -> "wp.Launch | None":
        lev = self.levels[depth]
        if depth == 0:
            return apply_operator(self.grid, x, out, n_rows=lev.n, device=self.backend, precise=False,
                                  equation=self.equation, record_cmd=record_cmd)
        return wp.launch(mg_kernels.stencil_apply, dim=x.shape, inputs=[lev.blocks, lev.rows, x], outputs=[out],
                         device=self.device, record_cmd=record_cmd)  # a recorded launch keeps its device

    def _work(self, depth: int, n_cols: int) -> dict:
        """The level's work vectors for ``n_cols`` columns: kept from one solve to the next (chunks), and only
        reallocated for more columns, after the old ones are released (a smaller chunk uses their first columns),
        so that the memory planner's figure holds."""
        lev = self.levels[depth]
        if lev.work.get("n_cols", 0) < n_cols:
            self._graphs = {}  # recorded with the vectors about to be released
            lev.work = {}
            shape = (lev.n, n_cols)
            names = ("r", "d") if depth == 0 else ("r", "d", "x", "b")
            lev.work = {"n_cols": n_cols, **{name: wp.empty(shape, dtype=wp.vec4f) for name in names}}
        if lev.work["n_cols"] == n_cols:
            return lev.work
        return {name: a[:, :n_cols] for name, a in lev.work.items() if name != "n_cols"}

    def lane(self) -> "Multigrid":
        """A view of this multigrid for one of the threads that solve chunks at once on a CPU: the same operators,
        coarsest inverse and eigenvalue estimates, its own work vectors and smoother bounds (a lane whose solve
        recovers from a fault by guaranteed bounds changes them for itself, not in the middle of another lane's
        cycles)."""
        self.coarse_inverse  # formed (or waited for) once, here: every view shares it
        view = copy.copy(self)
        view.levels = [dataclasses.replace(lev, work={}) for lev in self.levels]
        view.seconds = dict(self.seconds)
        view._graphs = {}
        return view

    def _smooth(self, depth: int, b: wp.array, x: wp.array, r: wp.array, d: wp.array, x_is_zero: bool,
                residual: bool) -> None:
        """Chebyshev smoothing of A x = b; with `residual`, leaves b - A x in r."""
        lev = self.levels[depth]
        shape = x.shape
        upper = lev.lmax
        lower = upper / SMOOTHING_RANGE
        theta = 0.5 * (upper + lower)
        delta = 0.5 * (upper - lower)
        sigma = theta / delta
        rho = 1.0 / sigma
        if x_is_zero:  # x's old values are never read: the first step writes it
            wp.launch(mg_kernels.chebyshev_first, dim=shape, inputs=[b, lev.inv_diag, 1.0 / theta], outputs=[x, d],
                      device=self.device)
        else:
            self._residual(depth, b, x, r)
            wp.launch(mg_kernels.chebyshev_start, dim=shape, inputs=[r, lev.inv_diag, 1.0 / theta], outputs=[x, d],
                      device=self.device)
        degrees = DEEP_SMOOTHER_DEGREES if len(self.levels) >= DEEP_LEVELS else SMOOTHER_DEGREES
        # the steps take the residual where they form it (one pass each), writing the next iterate to the other
        # of x and r (r is free: the residual is never stored), so the iterate alternates between them
        current, spare = x, r
        for _ in range(degrees[min(depth, len(degrees) - 1)] - 1):
            rho_next = 1.0 / (2.0 * sigma - rho)
            if self._chebyshev_step(depth, b, current, d, rho_next * rho, 2.0 * rho_next / delta, spare):
                current, spare = spare, current
            rho = rho_next
        if current is not x:
            wp.copy(x, current)
        if residual:
            self._residual(depth, b, x, r)

    def _chebyshev_step(self, depth, b, x, d, ca, cb, spare) -> bool:
        """d = ca d + cb D^-1 (b - A x) and x + d, in one pass into ``spare`` (True), or, for the fine Laplace
        level, through a stored residual (in ``spare``) with x updated in place (False)."""
        lev = self.levels[depth]
        if depth > 0:
            on_cpu = self.backend.on_cpu  # a thread per row looping over the handles (see _cycle)
            wp.launch(multigrid_cpu.stencil_chebyshev_step_rows if on_cpu else mg_kernels.stencil_chebyshev_step,
                      dim=lev.n if on_cpu else x.shape,
                      inputs=[lev.blocks, lev.rows, b, x, lev.inv_diag, ca, cb, d], outputs=[spare], device=self.device)
            return True
        if self.equation.compact:  # the residual and the step in one pass
            chebyshev_step(self.grid, x, b, d, ca, cb, spare, n_rows=lev.n, device=self.backend)
            return True
        self._residual(depth, b, x, spare)
        wp.launch(mg_kernels.chebyshev_step, dim=x.shape, inputs=[spare, lev.inv_diag, ca, cb], outputs=[x, d],
                  device=self.device)
        return False

    def _residual(self, depth, b, x, r):
        """r = b - A x, in one pass (the fused kernels: a separate subtraction was 13% of a bind's GPU time)."""
        lev = self.levels[depth]
        if depth == 0:
            apply_operator(self.grid, x, r, n_rows=lev.n, device=self.backend, precise=False, equation=self.equation,
                           rhs=b)
        elif self.backend.on_cpu:  # a thread per row looping over the handles (see _cycle)
            wp.launch(multigrid_cpu.stencil_residual_rows, dim=lev.n, inputs=[lev.blocks, lev.rows, b, x], outputs=[r],
                      device=self.device)
        else:
            wp.launch(mg_kernels.stencil_residual, dim=x.shape, inputs=[lev.blocks, lev.rows, b, x], outputs=[r],
                      device=self.device)

    def _cycle(self, depth: int, b: wp.array, x: wp.array) -> None:
        n_cols = b.shape[1]
        if depth == len(self.levels) - 1:
            wp.launch(mg_kernels.dense_apply, dim=b.shape, inputs=[self.coarse_inverse, b], outputs=[x],
                      device=self.device)
            return
        lev, coarse_level = self.levels[depth], self.levels[depth + 1]
        work = self._work(depth, n_cols)
        r, d = work["r"], work["d"]
        self._smooth(depth, b, x, r, d, x_is_zero=True, residual=True)
        coarse = self._work(depth + 1, n_cols)
        shift = wp.vec3i(*coarse_level.shift)
        # a CPU runs a thread per node looping over the handles (a kernel's threads run there one after another):
        # the transfers' look-ups are made once per node instead of once per node and handle
        on_cpu = self.backend.on_cpu
        wp.launch(multigrid_cpu.restrict_rows if on_cpu else mg_kernels.restrict,
                  dim=coarse_level.n if on_cpu else coarse["b"].shape,
                  inputs=[self.table32, coarse_level.ijk_device, lev.index, lev.n, shift, r], outputs=[coarse["b"]],
                  device=self.device)
        self._cycle(depth + 1, coarse["b"], coarse["x"])
        wp.launch(multigrid_cpu.prolong_add_rows if on_cpu else mg_kernels.prolong_add, dim=lev.n if on_cpu else x.shape,
                  inputs=[self.table32, lev.ijk_device, coarse_level.index, shift, coarse["x"]], outputs=[x],
                  device=self.device)
        self._smooth(depth, b, x, r, d, x_is_zero=False, residual=False)

    def apply(self, r: wp.array, z: wp.array) -> None:
        """z = one V-cycle applied to r (both (n_interior, handles) vec4 arrays on this device).

        On a GPU the cycle's launches (about fifty, each costing the host more than the GPU at these sizes) are
        recorded once per pair of arrays as a CUDA graph and replayed: the same kernels with the same arguments in
        the same order, so the same numbers. A CG solve applies it to the same two arrays every iteration."""
        with wp.ScopedDevice(self.device):
            if self.backend.on_cpu or not GRAPHS:
                self._cycle(0, r, z)
                return
            key = (r.ptr, z.ptr, r.shape, r.strides, z.strides)
            graph = self._graphs.get(key)
            if graph is None:  # the first cycle on these arrays: launched as it is (its modules load, its vectors
                self._cycle(0, r, z)  # are made); recorded at the second, when a solve is using them again
                self._graphs[key] = "seen"
            elif graph == "seen":
                self._graphs[key] = self._record_cycle(r, z)
            elif graph is False:  # this device cannot record (see _record_cycle)
                self._cycle(0, r, z)
            else:
                wp.capture_launch(graph)

    def _record_cycle(self, r: wp.array, z: wp.array):
        """A CUDA graph of one V-cycle from r into z, the cycle run once by replaying it; False where recording
        fails (then the cycle is launched as it is, every time: this one too)."""
        with _RECORDING:
            if _SOLVES[0] > 1:  # another solve of this process runs (a thread): not now, maybe at a later apply
                self._cycle(0, r, z)
                return "seen"
            try:  # the modules are loaded and the work vectors made by the first, plain cycle on these arrays
                with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                    self._cycle(0, r, z)
            except Exception:  # a driver or stream that cannot capture: the plain launches always work
                self._cycle(0, r, z)
                return False
        wp.capture_launch(capture.graph)
        return capture.graph

    # -- reporting ------------------------------------------------------------------------------------------------

    @property
    def level_sizes(self) -> list[int]:
        return [lev.n for lev in self.levels]

    def operator_bytes(self) -> int:
        """Device bytes held by the hierarchy, counted from its arrays (coarse operators, diagonals, node
        coordinates, lattice indices, the coarsest inverse); the fine level's index and coordinates are the
        grid's, and its diagonal is one block."""
        # the coarsest inverse counted from its size: reading it would wait for the thread that computes it
        total = (4 * (4 * self.levels[-1].n) ** 2 + self.table.capacity + self.table32.capacity
                 + self.levels[0].inv_diag.capacity)
        for lev in self.levels[1:]:
            total += (lev.blocks.capacity + lev.rows.capacity + lev.inv_diag.capacity + lev.ijk_device.capacity
                      + lev.index.capacity)
        return int(total)
