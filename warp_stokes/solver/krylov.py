"""Batched preconditioned conjugate gradients: every handle a column of one (interior node, handle) array, each step
a few launches over all of them (the kernels are in ``warp_stokes.kernels.cg``), one round of the solve's stopping
rule (:func:`warp_stokes.solver.solve.solve_biharmonic` explains it), and the watchdog that ends a round when the
iteration misbehaves."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..device import Backend
from ..geometry.grid import Grid
from ..kernels import cg, cg_cpu
from .equation import equation_of
from .operator import apply_operator

__all__ = ["BatchedCG", "Watchdog", "cg_round"]

#: a residual this many times above the round's best is growing: the preconditioner is broken (a healthy CG's
#: M-norm residual is not monotone, but does not swing by orders of magnitude)
GROWTH = 1e3
#: a multigrid round that has not reduced its largest residual this many times over STAGNATION_WINDOW iterations is
#: stagnating (a healthy cycle takes it from about 1 below 1e-7 in a dozen iterations or fewer on every bind of
#: benchmarks/bench_convergence.py: benchmarks/RESULTS.md)
STAGNATION_FACTOR = 10.0
STAGNATION_WINDOW = 10
#: ... judged only above this relative residual: below it, slow progress is the float32 floor, not a fault
STAGNATION_FLOOR = 1e-4
#: r^T M r below -(this * ||b||_M)^2 is negative beyond rounding: the preconditioner is not positive definite
NEGATIVE_TOLERANCE = 1e-6


class BatchedCG:
    """The vectors of one batched preconditioned CG over all handles (columns) and its steps, each a few launches
    over (interior node, handle). ``x`` is a view of the field's interior rows: the solve updates the field in
    place."""

    def __init__(self, grid: Grid, field: wp.array, source, precondition, backend: Backend,
                 equation: str = "biharmonic"):
        n, n_cols = grid.n_interior, field.shape[1]
        self.grid, self.field, self.precondition, self.backend = grid, field, precondition, backend
        self.equation = equation
        self.shape = (n, n_cols)
        self.threads = backend.reduction_threads(n, n_cols)
        self.rhs = None  # zero: Stokes coordinates have no source
        if source is not None:
            src = np.zeros((n, n_cols, 4), dtype=np.float32)
            # the value equation's right-hand side: (h^4 / 2) f for the compact scheme, h^2 f for -Laplace(q) = f
            scale = equation_of(equation).source_scale(grid.spacing)
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
        #: whether some r^T M r (or b^T M b) met so far was negative beyond rounding: M is not positive definite
        self.indefinite = False

    def dots(self, a, b):
        out = wp.zeros(self.shape[1], dtype=wp.float64)
        if self.backend.on_cpu:  # a thread per block of rows, reading them in order (kernels/cg_cpu.py)
            wp.launch(cg_cpu.column_dots_rows, dim=self.threads, inputs=[a, b, self.threads], outputs=[out])
        else:
            wp.launch(cg.column_dots, dim=(self.threads, self.shape[1]), inputs=[a, b, self.threads], outputs=[out])
        return out

    def preconditioned_norms(self, v):
        """v^T M v per handle, leaving M v in z."""
        self.precondition(v, self.z)
        return self.dots(v, self.z)

    def true_residual(self):
        apply_operator(self.grid, self.field, self.r, device=self.backend, equation=self.equation)
        if self.rhs is None:
            wp.launch(cg.negate, dim=self.shape, inputs=[self.r], outputs=[self.r])
        else:
            wp.launch(cg.residual, dim=self.shape, inputs=[self.rhs, self.r], outputs=[self.r])

    def clear(self, columns: np.ndarray) -> None:
        """Set the iterate of the handles in the boolean mask ``columns`` to zero (a restart after a fault); call
        :meth:`start` after it."""
        wp.launch(cg.clear_columns, dim=self.shape, inputs=[self.x, wp.array(columns.astype(np.int32))])

    def start(self) -> np.ndarray:
        """The scale ||b_h||_M per handle (b = rhs - A_IK x_K = r0 + A_II x0) and the starting relative residuals."""
        apply_operator(self.grid, self.field, self.p, n_rows=self.shape[0], device=self.backend, equation=self.equation)
        self.true_residual()
        wp.launch(cg.add_columns, dim=self.shape, inputs=[self.r, self.p], outputs=[self.p])
        squared = self.preconditioned_norms(self.p).numpy()
        scale = np.sqrt(np.maximum(squared, 0.0))
        # a handle with (almost) no forcing is measured against the others, not against zero; a column that is not
        # finite (a fault's) keeps its NaN and leaves the others' scales alone
        top = np.max(scale, where=np.isfinite(scale), initial=0.0)
        self.scale = np.maximum(scale, 1e-12 * top + 1e-300)
        self.indefinite = bool((squared < -(NEGATIVE_TOLERANCE * self.scale) ** 2).any())
        self.rz = self.preconditioned_norms(self.r)
        return self._relative(self.rz.numpy())

    def _relative(self, rz: np.ndarray) -> np.ndarray:
        """||r_h||_M / ||b_h||_M from r^T M r; notes whether some r^T M r is negative beyond rounding (then M is not
        positive definite, and a residual measured in it says nothing: its clamped zero would pass any test)."""
        self.indefinite = self.indefinite or bool((rz < -(NEGATIVE_TOLERANCE * self.scale) ** 2).any())
        return np.sqrt(np.maximum(rz, 0.0)) / self.scale

    def restart_directions(self):
        wp.copy(self.p, self.z)  # z = M r from the last norm

    def step(self, running: wp.array) -> np.ndarray:
        """One CG iteration of the running handles; their relative residuals by the recurrence."""
        # float64 sums here too: with float32 ones the CG recurrence drifts further from the true residual on
        # fine grids (several times the identity error after the first round); one application per iteration,
        # against ten in the V-cycle
        apply_operator(self.grid, self.p, self.ap, n_rows=self.shape[0], device=self.backend, equation=self.equation)
        pap = self.dots(self.p, self.ap)
        wp.launch(cg.step, dim=self.shape, inputs=[self.x, self.r, self.p, self.ap, self.rz, pap, running])
        rz_next = self.preconditioned_norms(self.r)
        rel = self._relative(rz_next.numpy())
        # every handle that stepped gets its next direction, also one that stops here: it can resume exactly
        # where it left off
        wp.launch(cg.new_directions, dim=self.shape, inputs=[self.z, self.p, self.rz, rz_next, running])
        self.rz = rz_next
        return rel

    def recompute(self) -> np.ndarray:
        """The relative residuals recomputed from scratch (r = b - A x), which restarts the recurrence."""
        self.true_residual()
        self.rz = self.preconditioned_norms(self.r)
        return self._relative(self.rz.numpy())


class Watchdog:
    """Signs that a CG round's preconditioner is broken, from the residuals of its iterations: a residual that is not
    finite, r^T M r < 0, a residual GROWTH times above the round's best, or (with ``stagnation``, for multigrid) a
    largest residual above STAGNATION_FLOOR that fell less than STAGNATION_FACTOR times over STAGNATION_WINDOW
    iterations.

    Examples
    --------
    >>> dog = Watchdog(stagnation=True)
    >>> [dog.check(np.array([r]), indefinite=False) for r in (1.0, 0.1, 1e3)]
    [None, None, 'the residual grew 1e+04-fold (to 1e+03)']
    >>> dog = Watchdog(stagnation=False)  # a residual of zero (converged) is no base to grow from
    >>> [dog.check(np.array([r]), indefinite=False) for r in (0.0, 1e-9)]
    [None, None]
    """

    def __init__(self, stagnation: bool):
        self.stagnation = stagnation
        self.best = np.inf
        self.history = []  # the best largest residual after each iteration

    def check(self, rel: np.ndarray, indefinite: bool, watch_stagnation: bool = True) -> str | None:
        """The fault seen in the relative residuals ``rel`` of the handles still iterating, or None."""
        if indefinite:
            return "the preconditioner is not positive definite (r^T M r < 0)"
        if not np.isfinite(rel).all():
            return "the residual is not finite"
        worst = float(rel.max()) if len(rel) else 0.0
        if 0.0 < self.best < np.inf and worst > GROWTH * self.best:
            return f"the residual grew {worst / self.best:.0e}-fold (to {worst:.0e})"
        self.best = min(self.best, worst)
        self.history.append(self.best)
        if self.stagnation and watch_stagnation and len(self.history) > STAGNATION_WINDOW:
            before = self.history[-1 - STAGNATION_WINDOW]
            if self.best > STAGNATION_FLOOR and self.best > before / STAGNATION_FACTOR:
                return (f"the residual stagnates ({before:.1e} to {self.best:.1e} over {STAGNATION_WINDOW} "
                        "iterations)")
        return None


def cg_round(solver: BatchedCG, rel: np.ndarray, tol_cg: float, deviation, identity_tol: float, iterations: int,
              max_iterations: int, callback, field, watchdog: Watchdog | None = None,
              progress=None) -> tuple[int, str | None]:
    """One round of CG from the current residual: the handles above ``tol_cg`` iterate until the recurrence puts
    them below it; then, while partition of unity and linear precision (``deviation()``) exceed ``identity_tol``,
    every handle goes on, the check running after each iteration, until it passes or stalls (the float32 floor).
    A ``watchdog`` ends the round at the first sign of a broken preconditioner; ``progress(iteration, residual)``
    is told the largest residual of the running handles after each iteration.
    Returns (the iteration count so far, the watchdog's fault or None)."""
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
        if progress is not None:
            progress(iterations, float(rel_cg[running_np == 1].max(initial=0.0)))
        if watchdog is not None:
            # every handle's residual counts while the identity check drives them all (stagnation excepted: there
            # slow progress is the float32 floor)
            fault = watchdog.check(rel_cg[running_np == 1], solver.indefinite, watch_stagnation=not by_identity)
            if fault is not None:
                return iterations, fault
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
    return iterations, None
