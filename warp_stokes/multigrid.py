"""Geometric multigrid for the compact coupled scheme, used as the preconditioner of the batched CG.

One V-cycle for all handles at once (every handle a column of the level arrays):

- levels: interior nodes of the grid, then nodes of lattices of spacing 2h, 4h, ...; a coarse node is kept only
  where it covers at least 1/8 of the 27 finer nodes around it (otherwise thin features make coarse matrices
  singular);
- prolongation: cubic Hermite, using the stored gradients (value at an edge midpoint (q0+q1)/2 + (G0-G1)/8),
  applied axis by axis;
- coarse operators: Galerkin products P^T A P (warp.sparse), so they stay symmetric positive definite;
- smoother: Chebyshev polynomial of degree 3 in D^-1 A (D the 4x4 diagonal blocks) on [lmax/30, 1.1 lmax], lmax
  from power iterations; it is a fixed polynomial, so the V-cycle is a symmetric preconditioner;
- coarsest level: a dense inverse computed once in float64.

The fine level is applied matrix-free (the 19-point stencil); its assembled blocks exist only while the first
Galerkin product is formed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp
import warp.sparse as wps

from .device import resolve_device
from .grid import Grid
from .kernels import cg, multigrid as mg
from .operator import apply_operator

__all__ = ["Multigrid", "SMOOTHER_DEGREE", "COARSEST_NODES"]

SMOOTHER_DEGREE = 3
#: the Chebyshev interval is [lmax / SMOOTHING_RANGE, 1.1 lmax]: the upper part of the spectrum is smoothed
SMOOTHING_RANGE = 30.0
#: coarsen until a level has at most this many nodes; it is then inverted densely
COARSEST_NODES = 400
POWER_ITERATIONS = 12


@dataclass
class Level:
    n: int  # unknown nodes
    ijk: np.ndarray  # (n, 3) lattice coordinates at this level
    index: wp.array  # lattice -> row or -1
    A: wps.BsrMatrix | None = None  # None on the fine level (matrix-free)
    inv_diag: wp.array | None = None  # (n,) mat44 inverses of the diagonal blocks
    P: wps.BsrMatrix | None = None  # prolongation from the next level (n x n_next)
    R: wps.BsrMatrix | None = None  # its transpose
    lmax: float = 0.0
    work: dict = field(default_factory=dict)


def _compact(A: wps.BsrMatrix) -> wps.BsrMatrix:
    """Compact rows without zero blocks: warp.sparse products can carry explicit zero blocks far outside the
    Galerkin stencil (seen with Warp 1.19 on the CPU: 72% of a coarse operator's blocks), which would cost
    bandwidth and memory in every coarse-level application."""
    return wps.bsr_compress(A, prune_numerical_zeros=True)


class Multigrid:
    """A V-cycle preconditioner for the interior block A_II of a grid, shared by all handles.

    Parameters
    ----------
    grid : Grid
    device : None | str
    coarsest_nodes : int, size at which coarsening stops

    Examples
    --------
    >>> mg = Multigrid(grid, device="cpu")          # doctest: +SKIP
    >>> mg.apply(residual, correction)              # doctest: +SKIP
    """

    def __init__(self, grid: Grid, device=None, coarsest_nodes: int = COARSEST_NODES):
        self.grid = grid
        self.device = resolve_device(device)
        with wp.ScopedDevice(self.device):
            self.levels = self._build(coarsest_nodes)
            self._estimate_eigenvalues()

    # -- setup ----------------------------------------------------------------------------------------------------

    def _build(self, coarsest_nodes: int) -> list[Level]:
        grid = self.grid
        n0 = grid.n_interior
        index0 = np.where(grid.index < n0, grid.index, -1).astype(np.int32)
        ijk0 = grid.active_ijk[:n0]
        fine = Level(n=n0, ijk=ijk0, index=wp.array(index0, dtype=wp.int32))
        rows = wp.empty(19 * n0, dtype=int)
        cols = wp.empty(19 * n0, dtype=int)
        blocks = wp.empty(19 * n0, dtype=wp.mat44f)
        wp.launch(mg.fine_operator_triplets, dim=n0, inputs=[wp.array(ijk0, dtype=wp.vec3i), fine.index, n0],
                  outputs=[rows, cols, blocks])
        A = wps.bsr_from_triplets(n0, n0, rows, cols, blocks)
        del rows, cols, blocks
        fine.inv_diag = self._inverse_diagonal(A, n0)
        levels = [fine]
        shape = np.array(index0.shape)
        while levels[-1].n > coarsest_nodes:
            lev = levels[-1]
            coarse_shape = tuple(int(s) for s in shape // 2 + 1)
            counts = wp.empty(coarse_shape, dtype=wp.int32)
            wp.launch(mg.coarse_coverage, dim=coarse_shape, inputs=[lev.index], outputs=[counts])
            keep = counts.numpy().ravel() * 8 >= 27
            order = np.flatnonzero(keep)
            if len(order) == 0 or len(order) >= lev.n:
                break
            ijk = np.stack(np.unravel_index(order, coarse_shape), axis=1).astype(np.int32)
            index = np.full(int(np.prod(coarse_shape)), -1, dtype=np.int32)
            index[order] = np.arange(len(order), dtype=np.int32)
            coarse = Level(n=len(order), ijk=ijk, index=wp.array(index.reshape(coarse_shape), dtype=wp.int32))
            rows = wp.empty(8 * lev.n, dtype=int)
            cols = wp.empty(8 * lev.n, dtype=int)
            blocks = wp.empty(8 * lev.n, dtype=wp.mat44f)
            wp.launch(mg.prolongation_triplets, dim=lev.n, inputs=[wp.array(lev.ijk, dtype=wp.vec3i), coarse.index],
                      outputs=[rows, cols, blocks])
            lev.P = wps.bsr_from_triplets(lev.n, coarse.n, rows, cols, blocks)
            del rows, cols, blocks
            lev.R = _compact(wps.bsr_transposed(lev.P))
            coarse.A = _compact(wps.bsr_mm(lev.R, _compact(wps.bsr_mm(A, lev.P))))
            A = coarse.A
            coarse.inv_diag = self._inverse_diagonal(A, coarse.n)
            levels.append(coarse)
            shape = np.array(coarse_shape)
        last = levels[-1]
        dense = self._to_dense(A, last.n)
        try:
            inverse = np.linalg.inv(dense)
        except np.linalg.LinAlgError:
            inverse = np.linalg.pinv(dense)
        self.coarse_inverse = wp.array(inverse.astype(np.float32), dtype=wp.float32)
        return levels

    @staticmethod
    def _inverse_diagonal(A: wps.BsrMatrix, n: int) -> wp.array:
        diag = wps.bsr_get_diag(A)
        inv = wp.empty(n, dtype=wp.mat44f)
        wp.launch(mg.invert_blocks, dim=n, inputs=[diag], outputs=[inv])
        return inv

    @staticmethod
    def _to_dense(A: wps.BsrMatrix, n: int) -> np.ndarray:
        offsets = A.offsets.numpy()[: n + 1]
        cols = A.columns.numpy()[: offsets[-1]]
        vals = A.values.numpy()[: offsets[-1]].astype(np.float64)
        dense = np.zeros((n, 4, n, 4))
        rows = np.repeat(np.arange(n), np.diff(offsets))
        np.add.at(dense, (rows, slice(None), cols, slice(None)), vals)
        return dense.reshape(4 * n, 4 * n)

    def _estimate_eigenvalues(self) -> None:
        """lmax of D^-1 A per level (all but the coarsest) by power iteration on one random column."""
        rng = np.random.default_rng(0)
        for depth, lev in enumerate(self.levels[:-1]):
            v = wp.array(rng.standard_normal((lev.n, 1, 4)).astype(np.float32), dtype=wp.vec4f)
            av = wp.empty_like(v)
            z = wp.empty_like(v)
            lam = 1.0
            for _ in range(POWER_ITERATIONS):
                norm = float(np.linalg.norm(v.numpy()))
                v = wp.array(v.numpy() / norm, dtype=wp.vec4f)
                self._apply_A(depth, v, av)
                zeros = wp.zeros_like(z)
                wp.launch(mg.chebyshev_start, dim=(lev.n, 1), inputs=[av, lev.inv_diag, 1.0], outputs=[zeros, z])
                lam = float(np.linalg.norm(z.numpy()))
                v, z = z, v
            lev.lmax = 1.1 * lam

    # -- application ----------------------------------------------------------------------------------------------

    def _apply_A(self, depth: int, x: wp.array, out: wp.array) -> None:
        lev = self.levels[depth]
        if depth == 0:
            apply_operator(self.grid, x, out, n_rows=lev.n, device=self.device, precise=False)
        else:
            wp.launch(mg.bsr_apply, dim=x.shape,
                      inputs=[lev.A.offsets, lev.A.columns, lev.A.values, x, 1.0, 0.0], outputs=[out])

    def _work(self, depth: int, n_cols: int) -> dict:
        lev = self.levels[depth]
        if lev.work.get("n_cols") != n_cols:
            shape = (lev.n, n_cols)
            lev.work = {"n_cols": n_cols, "r": wp.empty(shape, dtype=wp.vec4f), "d": wp.empty(shape, dtype=wp.vec4f)}
            if depth > 0:
                lev.work["x"] = wp.empty(shape, dtype=wp.vec4f)
                lev.work["b"] = wp.empty(shape, dtype=wp.vec4f)
        return lev.work

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
        if x_is_zero:
            wp.launch(mg.chebyshev_start, dim=shape, inputs=[b, lev.inv_diag, 1.0 / theta], outputs=[x, d])
        else:
            self._residual(depth, b, x, r)
            wp.launch(mg.chebyshev_start, dim=shape, inputs=[r, lev.inv_diag, 1.0 / theta], outputs=[x, d])
        for _ in range(SMOOTHER_DEGREE - 1):
            self._residual(depth, b, x, r)
            rho_next = 1.0 / (2.0 * sigma - rho)
            wp.launch(mg.chebyshev_step, dim=shape, inputs=[r, lev.inv_diag, rho_next * rho, 2.0 * rho_next / delta],
                      outputs=[x, d])
            rho = rho_next
        if residual:
            self._residual(depth, b, x, r)

    def _residual(self, depth, b, x, r):
        self._apply_A(depth, x, r)
        wp.launch(cg.residual, dim=x.shape, inputs=[b, r], outputs=[r])

    def _cycle(self, depth: int, b: wp.array, x: wp.array) -> None:
        n_cols = b.shape[1]
        if depth == len(self.levels) - 1:
            wp.launch(mg.dense_apply, dim=b.shape, inputs=[self.coarse_inverse, b], outputs=[x])
            return
        lev = self.levels[depth]
        work = self._work(depth, n_cols)
        r, d = work["r"], work["d"]
        x.zero_()
        self._smooth(depth, b, x, r, d, x_is_zero=True, residual=True)
        coarse = self._work(depth + 1, n_cols)
        R = lev.R
        wp.launch(mg.bsr_apply, dim=coarse["b"].shape, inputs=[R.offsets, R.columns, R.values, r, 1.0, 0.0],
                  outputs=[coarse["b"]])
        self._cycle(depth + 1, coarse["b"], coarse["x"])
        P = lev.P
        wp.launch(mg.bsr_apply, dim=x.shape, inputs=[P.offsets, P.columns, P.values, coarse["x"], 1.0, 1.0],
                  outputs=[x])
        self._smooth(depth, b, x, r, d, x_is_zero=False, residual=False)

    def apply(self, r: wp.array, z: wp.array) -> None:
        """z = one V-cycle applied to r (both (n_interior, handles) vec4 arrays on this device)."""
        with wp.ScopedDevice(self.device):
            self._cycle(0, r, z)

    # -- reporting ------------------------------------------------------------------------------------------------

    @property
    def level_sizes(self) -> list[int]:
        return [lev.n for lev in self.levels]

    def operator_bytes(self) -> int:
        """Bytes held by the hierarchy (coarse operators, transfer operators, diagonals, coarsest inverse)."""
        total = self.coarse_inverse.capacity
        for lev in self.levels:
            for m in (lev.A, lev.P, lev.R):
                if m is not None:
                    total += m.values.capacity + m.columns.capacity + m.offsets.capacity
            total += lev.inv_diag.capacity + lev.index.capacity
        return int(total)
