"""Batched preconditioned conjugate gradients: every handle a column of one (interior node, handle) array, each step
a few launches over all of them (the kernels are in ``warp_stokes.kernels.cg``), and one round of the solve's
stopping rule (:func:`warp_stokes.solver.solve.solve_biharmonic` explains it)."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..device import reduction_threads
from ..geometry.grid import Grid
from ..kernels import cg
from .operator import apply_operator

__all__ = ["BatchedCG", "cg_round"]


class BatchedCG:
    """The vectors of one batched preconditioned CG over all handles (columns) and its steps, each a few launches
    over (interior node, handle). ``x`` is a view of the field's interior rows: the solve updates the field in
    place."""

    def __init__(self, grid: Grid, field: wp.array, source, precondition, device, equation: str = "biharmonic"):
        n, n_cols = grid.n_interior, field.shape[1]
        self.grid, self.field, self.precondition, self.device = grid, field, precondition, device
        self.equation = equation
        self.shape = (n, n_cols)
        self.threads = reduction_threads(n, n_cols, device)
        self.rhs = None  # zero: Stokes coordinates have no source
        if source is not None:
            src = np.zeros((n, n_cols, 4), dtype=np.float32)
            # the value equation's right-hand side: (h^4 / 2) f for the compact scheme, h^2 f for -Laplace(q) = f
            scale = grid.spacing**2 if equation == "laplace" else 0.5 * grid.spacing**4
            src[..., 0] = scale * np.asarray(source, dtype=np.float64).reshape(n, n_cols)
            self.rhs = wp.array(src, dtype=wp.vec4f)
        self.x = field[0:n]  # interior rows come first
        self.r = wp.empty(self.shape, dtype=wp.vec4f)
        self.p = wp.empty(self.shape, dtype=wp.vec4f)
        # A p is needed until x and r are updated, M r only after: they share storage (three vectors per column
        # instead of four, see warp_stokes.solver.budget)
        self.ap = wp.empty(self.shape, dtype=wp.vec4f)
        self.z = self.ap
        self.scale = self.rz = None

    def dots(self, a, b):
        out = wp.zeros(self.shape[1], dtype=wp.float64)
        wp.launch(cg.column_dots, dim=(self.threads, self.shape[1]), inputs=[a, b, self.threads], outputs=[out])
        return out

    def preconditioned_norms(self, v):
        """v^T M v per handle, leaving M v in z."""
        self.precondition(v, self.z)
        return self.dots(v, self.z)

    def true_residual(self):
        apply_operator(self.grid, self.field, self.r, device=self.device, equation=self.equation)
        if self.rhs is None:
            wp.launch(cg.negate, dim=self.shape, inputs=[self.r], outputs=[self.r])
        else:
            wp.launch(cg.residual, dim=self.shape, inputs=[self.rhs, self.r], outputs=[self.r])

    def start(self) -> np.ndarray:
        """The scale ||b_h||_M per handle (b = rhs - A_IK x_K = r0 + A_II x0) and the starting relative residuals."""
        apply_operator(self.grid, self.field, self.p, n_rows=self.shape[0], device=self.device, equation=self.equation)
        self.true_residual()
        wp.launch(cg.add_columns, dim=self.shape, inputs=[self.r, self.p], outputs=[self.p])
        scale = np.sqrt(np.maximum(self.preconditioned_norms(self.p).numpy(), 0.0))
        # a handle with (almost) no forcing is measured against the others, not against zero
        self.scale = np.maximum(scale, 1e-12 * scale.max() + 1e-300)
        self.rz = self.preconditioned_norms(self.r)
        return np.sqrt(np.maximum(self.rz.numpy(), 0.0)) / self.scale

    def restart_directions(self):
        wp.copy(self.p, self.z)  # z = M r from the last norm

    def step(self, running: wp.array) -> np.ndarray:
        """One CG iteration of the running handles; their relative residuals by the recurrence."""
        # float64 sums here too: with float32 ones the CG recurrence drifts further from the true residual on
        # fine grids (measured on an H100 at n = 256: 4e-5 instead of 1e-5 identity error after the first
        # round); one application per iteration, against ten in the V-cycle
        apply_operator(self.grid, self.p, self.ap, n_rows=self.shape[0], device=self.device, equation=self.equation)
        pap = self.dots(self.p, self.ap)
        wp.launch(cg.step, dim=self.shape, inputs=[self.x, self.r, self.p, self.ap, self.rz, pap, running])
        rz_next = self.preconditioned_norms(self.r)
        rel = np.sqrt(np.maximum(rz_next.numpy(), 0.0)) / self.scale
        # every handle that stepped gets its next direction, also one that stops here: it can resume exactly
        # where it left off
        wp.launch(cg.new_directions, dim=self.shape, inputs=[self.z, self.p, self.rz, rz_next, running])
        self.rz = rz_next
        return rel

    def recompute(self) -> np.ndarray:
        """The relative residuals recomputed from scratch (r = b - A x), which restarts the recurrence."""
        self.true_residual()
        self.rz = self.preconditioned_norms(self.r)
        return np.sqrt(np.maximum(self.rz.numpy(), 0.0)) / self.scale


def cg_round(solver: BatchedCG, rel: np.ndarray, tol_cg: float, deviation, identity_tol: float, iterations: int,
              max_iterations: int, callback, field) -> int:
    """One round of CG from the current residual: the handles above ``tol_cg`` iterate until the recurrence puts
    them below it; then, while partition of unity and linear precision (``deviation()``) exceed ``identity_tol``,
    every handle goes on, the check running after each iteration, until it passes or stalls (the float32 floor).
    Returns the iteration count so far."""
    running_np = (rel > tol_cg).astype(np.int32)
    if running_np.any():
        running = wp.array(running_np, dtype=wp.int32)
        solver.restart_directions()
    by_identity, best_identity, stalled = False, np.inf, 0
    while running_np.any() and iterations < max_iterations:
        rel_cg = solver.step(running)
        iterations += 1
        if callback is not None:
            callback(iterations, field)
        if not by_identity:
            still = ((running_np == 1) & (rel_cg > tol_cg)).astype(np.int32)
            if still.any():
                if not np.array_equal(still, running_np):
                    running_np = still
                    running = wp.array(running_np, dtype=wp.int32)
                continue
        identity = deviation()
        if identity <= identity_tol:
            break
        # Every residual is small but the weights are not there yet (the preconditioned residual understates the
        # error of smooth components): every handle goes on with its own CG, keeping its Krylov space. Stop when
        # the check no longer improves: the float32 floor.
        if not by_identity:
            by_identity = True
            running_np = np.ones(len(running_np), dtype=np.int32)
            running = wp.array(running_np, dtype=wp.int32)
        stalled = stalled + 1 if identity > 0.7 * best_identity else 0
        best_identity = min(best_identity, identity)
        if stalled >= 3:
            break
    return iterations
