"""Solving the compact coupled biharmonic scheme for all handles at once.

The interior block A_II of the scheme is symmetric positive definite, so conjugate gradients apply directly,
preconditioned by the multigrid V-cycle (``warp_stokes.solver.multigrid``) or by the inverse diagonal. Every handle is
a column of one (node, handle) array: each operator application is one launch over all interior nodes and all
handles (``warp_stokes.solver.operator``); the CG kernels are in ``warp_stokes.kernels.cg``.

Stopping rule. For handle h let b_h = f_h - A_IK x_K be the right-hand side (boundary forcing) and
r_h = b_h - A_II x_I the residual, with ``||v||_M^2 = v^T M v`` (M the preconditioner). A handle iterates until
``||r_h||_M / ||b_h||_M`` is below tol / 10. The preconditioned residual does not bound the weight error tightly
(with the diagonal preconditioner the error-to-residual ratio grows like n^2; with multigrid it is a few, more
at n >= 192), so when the columns are cage coordinates the deviation from partition of unity and linear
precision at the nodes, an exact property of the discrete solution, is measured once every handle is there;
while it exceeds tol, CG goes on for every handle (each keeping its Krylov space) and the check runs after each
iteration. At the end the residual is recomputed from scratch in float64 sums (the CG recurrence drifts in
float32): the solve ends when it is <= tol and the identity check passes (it allows twice its float32 rounding
floor, measured on the starting field, when that is larger). Otherwise, or when the identity check stalls at the
float32 floor, CG restarts from the recomputed residual with a tighter tolerance. Checked against a direct
float64 solve in tests/test_solve.py.

Harmonic coordinates. ``equation="laplace"`` solves the 7-point Laplace equation instead, with the same data,
stopping rule, multigrid cycle (trilinear prolongation) and identity check (the 7-point operator reproduces linear
functions exactly, too); its gradient rows are identity rows, and the interior G are set to the central
differences of the solved values at the end (``warp_stokes.kernels.laplace``).

Chunks. When the handles are solved a chunk at a time (memory), the chunk's field carries one more column that
stands for the rest of the cage (``boundary_field(..., complement=True)``): the sum over the other handles of
w_l, biharmonic too. Chunk and complement sum to 1 exactly, so the same stopping rule applies to each chunk, with
partition of unity as its identity check (linear precision is measured on the sampled weights of all chunks).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..geometry.boundary import COMPLEMENT_COLUMNS
from ..device import resolve_device
from ..geometry.grid import Grid
from ..geometry.topology import bounding_diagonal
from ..kernels import cg, checks, laplace
from .krylov import BatchedCG, cg_round
from .multigrid import Multigrid
from .operator import apply_operator, check_equation

__all__ = ["SolveReport", "solve_biharmonic", "apply_operator"]

#: true-residual checks (restarts) before giving up on reaching `tol`
MAX_RESTARTS = 8


@dataclass
class SolveReport:
    """What the solver did.

    Attributes
    ----------
    iterations : int, CG iterations (summed over restarts)
    residual : float, the largest relative residual ||r_h||_M / ||b_h||_M over handles, recomputed at the end
    identity_error : float, the largest deviation from partition of unity and linear precision (relative to
        the cage's diagonal) at interior nodes; 0 when the solve was not told the handles' positions
    converged : bool, residual <= tol and identity_error <= max(tol, twice the float32 rounding floor of the
        starting field's identity check)
    restarts : int, restarts of CG from a recomputed residual (after float32 drift or a stalled identity check)
    seconds : float, wall time of the solve (synchronised), multigrid setup included
    setup_seconds : float, of which building the multigrid hierarchy
    rounds : list of [iterations so far, residual, identity deviation] after each CG round (restart)
    """

    iterations: int
    residual: float
    identity_error: float
    converged: bool
    restarts: int
    seconds: float
    setup_seconds: float = 0.0
    rounds: list = None


def solve_biharmonic(
    grid: Grid,
    field: wp.array,
    tol: float = 1e-6,
    max_iterations: int | None = None,
    source: np.ndarray | None = None,
    handles: np.ndarray | None = None,
    preconditioner: str | Multigrid = "multigrid",
    device=None,
    callback=None,
    chunk: slice | None = None,
    equation: str = "biharmonic",
) -> SolveReport:
    """Solve the compact 19-point coupled scheme (or the 7-point Laplace equation) in place, for all handles in one
    batched CG.

    Parameters
    ----------
    grid : Grid
    field : wp.array2d(vec4f), (grid.n_active, handles)
        Known (q, G) at ring and band rows; the starting guess at interior rows, overwritten by the solution.
    tol : float
        Relative preconditioned residual per handle, and (with ``handles``) the largest deviation from partition
        of unity and linear precision at the interior nodes, relative to the cage's diagonal.
    max_iterations : int, optional
        Default: 200 with multigrid, 40 * (resolution + 8)**2 with Jacobi.
    source : (n_interior, handles) array, optional
        ``f`` at interior nodes; the value equation's right-hand side is ``h**4 / 2 * f`` (``h**2 * f`` for the
        Laplace equation, ``-Laplace(q) = f``). Zero by default
        (Stokes coordinates); used by manufactured-solution tests.
    handles : (handles, 3) array, optional
        Cage vertices (absolute positions) when the columns are the cage coordinates: enables the identity
        check.
    preconditioner : "multigrid" | "jacobi" | Multigrid
        The V-cycle of :class:`warp_stokes.solver.multigrid.Multigrid` (built here unless given), or the inverse
        diagonal.
    device : None | str
    callback : callable, optional
        ``callback(iteration, field)`` is called with the starting field (iteration 0) and after every CG
        iteration, with ``field`` holding the current iterate: to record convergence histories. It must not
        modify the field.
    chunk : slice, optional
        With ``handles``, when the columns are a chunk of the cage coordinates, ``handles[chunk]``, followed by
        the column of the rest of the cage (``boundary_field(..., handles=chunk, complement=True)``): the
        identity check then checks the chunk's partition of unity.
    equation : "biharmonic" | "laplace"
        Stokes coordinates (the compact scheme) or harmonic coordinates (7-point Laplace; the interior gradients
        are then the central differences of the solved values). A given Multigrid must be for the same equation.

    Returns
    -------
    SolveReport

    Examples
    --------
    >>> field = boundary_field(grid, cage)                               # doctest: +SKIP
    >>> report = solve_biharmonic(grid, field, handles=cage.vertices)    # doctest: +SKIP
    >>> report.converged                                                 # doctest: +SKIP
    True
    """
    # about 70 lines: the stopping rule (rounds, recomputed residual, identity check, restarts) reads in one place
    device = resolve_device(device)
    check_equation(equation)
    start = time.perf_counter()
    with wp.ScopedDevice(device):
        deviation = _identity_check(grid, field, handles, device, chunk)  # first: it checks the columns
        precondition, default_iterations, setup_seconds = _preconditioner(grid, preconditioner, device, equation)
        if max_iterations is None:
            max_iterations = default_iterations
        solver = BatchedCG(grid, field, source, precondition, device, equation)
        rel = solver.start()

        # The preconditioned residual is a few times smaller than the weight error it stands for: aim ten times
        # below tol before the first identity check.
        iterations, restarts, tol_cg = 0, 0, 0.1 * tol
        rounds = []
        # The starting MVC field reproduces constants and linear functions exactly in float64; its deviation
        # once stored in float32 is the rounding floor of the identity check (it grows with the handles and
        # the nodes: 1e-6 is within reach of 100+ handles on 10^6 nodes). Ask for the tolerance or twice it.
        identity = deviation()
        identity_tol = max(tol, 2.0 * identity)
        if callback is not None:
            callback(0, field)
        while True:
            iterations = cg_round(solver, rel, tol_cg, deviation, identity_tol, iterations, max_iterations,
                                   callback, field)
            # the CG recurrence drifts from the true residual in float32: check it from scratch
            rel = solver.recompute()
            identity = deviation()
            rounds.append([iterations, float(rel.max()), identity])
            if ((rel <= tol).all() and identity <= identity_tol) or iterations >= max_iterations:
                break
            if restarts >= MAX_RESTARTS:
                break
            # CG starts again from the recomputed residual; when the weights were what fell short, asking
            # for more
            restarts += 1
            if identity > identity_tol:
                tol_cg = min(tol_cg, float(rel.max())) / 10.0
        if equation == "laplace":
            _gradients_from_values(grid, field, device)
        wp.synchronize_device(device)

    residual = float(rel.max()) if len(rel) else 0.0
    converged = bool((rel <= tol).all() and identity <= identity_tol)
    if not converged:
        warnings.warn(
            f"the solver stopped after {iterations} iterations with relative residual {residual:.3g} and identity "
            f"deviation {identity:.3g} (tol {tol:g}, identity tol {identity_tol:.3g})"
            + (": iteration limit reached" if iterations >= max_iterations else ": float32 accuracy limit"),
            stacklevel=2,
        )
    return SolveReport(
        iterations=iterations,
        residual=residual,
        identity_error=identity,
        converged=converged,
        restarts=restarts,
        seconds=time.perf_counter() - start,
        setup_seconds=setup_seconds,
        rounds=rounds,
    )


def _gradients_from_values(grid: Grid, field: wp.array, device) -> None:
    """The interior rows' G of a Laplace solution: central differences of its values (its G rows solved to 0)."""
    arrays = grid.device_arrays(device)
    wp.launch(laplace.gradient_from_values, dim=(grid.n_interior, field.shape[1]),
              inputs=[field, arrays["index"], arrays["active_ijk"]], device=device)


def _preconditioner(grid: Grid, preconditioner, device, equation: str = "biharmonic"):
    """(apply(r, z), default iteration limit, setup seconds) of the V-cycle (built here for "multigrid", or given
    as a Multigrid) or of the inverse diagonal ("jacobi")."""
    setup_seconds = 0.0
    if preconditioner == "multigrid":
        start = time.perf_counter()
        preconditioner = Multigrid(grid, device=device, equation=equation)
        wp.synchronize_device(device)
        setup_seconds = time.perf_counter() - start
    if isinstance(preconditioner, Multigrid):
        if preconditioner.equation != equation:
            raise ValueError(f"the multigrid was built for the {preconditioner.equation} equation, the solve is for "
                             f"the {equation} one")
        return preconditioner.apply, 200, setup_seconds
    if preconditioner == "jacobi":
        def precondition(r, z):
            if equation == "laplace":
                wp.launch(laplace.jacobi, dim=r.shape, inputs=[r], outputs=[z], device=device)
            else:
                wp.launch(cg.jacobi, dim=r.shape, inputs=[r], outputs=[z], device=device)
        return precondition, 40 * (grid.resolution + 8) ** 2, setup_seconds
    raise ValueError(f"unknown preconditioner {preconditioner!r}: use 'multigrid' or 'jacobi'")


def _identity_check(grid: Grid, field: wp.array, handles, device, chunk: slice | None = None):
    """A function returning the largest deviation from partition of unity and linear precision at the
    interior nodes (0 when ``handles`` is None), over the columns of ``field``: the cage coordinates of all
    ``handles``; or of ``handles[chunk]`` followed by the complement column, and then partition of unity only."""
    if handles is None:
        return lambda: 0.0
    handles = np.asarray(handles, dtype=np.float64)
    scale = bounding_diagonal(handles)
    first, stop, _ = (chunk or slice(None)).indices(len(handles))
    columns = np.zeros((stop - first, 4))
    columns[:, 0] = 1.0
    columns[:, 1:] = handles[first:stop] - grid.centre
    if chunk is not None:
        # the rest of the cage: the sum of its w_l counts towards 1
        columns = np.concatenate([columns, np.eye(4)[:COMPLEMENT_COLUMNS]])
    if field.shape[1] != len(columns):
        raise ValueError(
            f"the field has {field.shape[1]} columns; the identity check expects {len(columns)} "
            + (f"({stop - first} handles of the chunk and {COMPLEMENT_COLUMNS} for the rest of the cage)"
               if chunk is not None else "(one per handle)")
        )
    ijk = grid.device_arrays(device)["active_ijk"]
    columns = wp.array(columns, dtype=wp.vec4d, device=device)
    out = wp.zeros(1, dtype=float, device=device)

    def deviation() -> float:
        out.zero_()
        wp.launch(
            checks.identity_deviation,
            dim=grid.n_interior,
            inputs=[field, ijk, wp.vec3d(*grid.origin), wp.float64(grid.spacing), columns, wp.float64(scale),
                    int(chunk is None)],
            outputs=[out],
            device=device,
        )
        return float(out.numpy()[0])

    return deviation
