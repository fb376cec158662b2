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

Faults and recovery. A watchdog (:class:`warp_stokes.solver.krylov.Watchdog`) ends a round at the first sign of a
broken preconditioner: a residual that is not finite or grows by orders of magnitude, r^T M r < 0, or a multigrid
round that stagnates. The solve then goes on with the next preconditioner of a ladder, each built only when needed:
the multigrid cycle; the same cycle with guaranteed upper ends of its smoothers (:meth:`Multigrid.bound_eigenvalues`:
an underestimated largest eigenvalue is what can still break a cycle whose coarse levels are positive definite);
the inverse diagonal (slow, O(n^2) iterations, but it converges on any positive definite system; at most
:func:`jacobi_recovery_iterations`). It restarts from
the current iterate, a handle whose residual is worse than that of a zero iterate from zero. Each switch is recorded
(``SolveReport.recoveries``) and warned of once. A solve of cage coordinates whose partition of unity or linear
precision at the nodes ends above ACCEPTABLE times its tolerance, or whose every preconditioner failed, raises
:class:`ConvergenceError` (no weights that break them, and no unsolved ones, are returned); within it, a solve that
did not reach ``tol`` returns with ``converged`` False and a warning.

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
from typing import NamedTuple

import numpy as np
import warp as wp

from ..device import Backend
from ..errors import ConvergenceError
from ..geometry.boundary import COMPLEMENT_COLUMNS
from ..geometry.grid import Grid
from ..geometry.topology import bounding_diagonal
from ..kernels import checks, laplace
from .krylov import GROWTH, BatchedCG, Watchdog, cg_round
from .multigrid import Multigrid
from .equation import equation_of
from .operator import apply_operator
from .preconditioner import Jacobi, jacobi_step

__all__ = ["SolveReport", "solve_biharmonic", "apply_operator", "jacobi_recovery_iterations", "ACCEPTABLE"]

#: true-residual checks (restarts) before giving up on reaching `tol`
MAX_RESTARTS = 8
#: a solve of cage coordinates whose identity deviation ends above this many times its tolerance raises
#: ConvergenceError: with the default tol 1e-6, partition of unity and linear precision within 1e-5
ACCEPTABLE = 10.0
#: the multigrid's iteration limit (it needs 6-20)
MULTIGRID_ITERATIONS = 200


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
    identity_tolerance : float, the identity check's tolerance: tol, or twice the float32 floor of the starting
        field's deviation where that is larger
    preconditioner : str, the preconditioner that ended the solve ("multigrid", "multigrid with guaranteed smoother
        bounds", "jacobi")
    recoveries : list of dict, each switch to the next preconditioner after a fault: ``iteration``, ``fault``,
        ``preconditioner`` (the one that failed), ``next``
    """

    iterations: int
    residual: float
    identity_error: float
    converged: bool
    restarts: int
    seconds: float
    setup_seconds: float = 0.0
    rounds: list = None
    identity_tolerance: float = 0.0
    preconditioner: str = ""
    recoveries: list = None


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
    progress=None,
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
        For the preconditioner asked for. Default: 200 with multigrid, 40 * (resolution + 8)**2 with Jacobi; a
        preconditioner taken after a fault has its default.
    source : (n_interior, handles) array, optional
        ``f`` at interior nodes; the value equation's right-hand side is ``h**4 / 2 * f`` (``h**2 * f`` for the
        Laplace equation, ``-Laplace(q) = f``). Zero by default
        (Stokes coordinates); used by manufactured-solution tests.
    handles : (handles, 3) array, optional
        Cage vertices (absolute positions) when the columns are the cage coordinates: enables the identity
        check.
    preconditioner : "multigrid" | "jacobi" | Multigrid | Jacobi
        The V-cycle of :class:`warp_stokes.solver.multigrid.Multigrid` (built here unless given), or the inverse
        diagonal (:class:`Jacobi`).
    device : None | str | Backend
    callback : callable, optional
        ``callback(iteration, field)`` is called with the starting field (iteration 0) and after every CG
        iteration, with ``field`` holding the current iterate: to record convergence histories. It must not
        modify the field.
    progress : callable, optional
        ``progress(iteration, residual)`` after every CG iteration, with the largest relative residual of the handles
        still iterating (cheap: for a progress display).
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

    Raises
    ------
    ConvergenceError
        When every preconditioner failed, or (with ``handles``) partition of unity or linear precision at the nodes
        ends above ACCEPTABLE times its tolerance (or not finite); its ``report`` is the SolveReport, the field holds
        the last iterate.

    Examples
    --------
    >>> field = boundary_field(grid, cage)                               # doctest: +SKIP
    >>> report = solve_biharmonic(grid, field, handles=cage.vertices)    # doctest: +SKIP
    >>> report.converged                                                 # doctest: +SKIP
    True
    """
    # the stopping rule (rounds, recomputed residual, identity check, restarts) in _attempt; the ladder of
    # preconditioners after faults in _climb_ladder
    backend = Backend.of(device)
    equation = equation_of(equation)
    start = time.perf_counter()
    with backend.scope():
        deviation = _identity_check(grid, field, handles, backend, chunk)  # first: it checks the columns
        # The starting field reproduces constants and linear functions exactly in float64; its deviation once
        # stored in float32 is the rounding floor of the identity check (it grows with the handles and the nodes:
        # 1e-6 is within reach of 100+ handles on 10^6 nodes). Ask for the tolerance or twice it.
        identity_tol = max(tol, 2.0 * deviation())
        if callback is not None:
            callback(0, field)
        climb = _climb_ladder(grid, field, source, preconditioner, backend, equation, tol, identity_tol, deviation,
                              max_iterations, callback, progress)
        if not equation.compact:
            _gradients_from_values(grid, field, backend)
        backend.synchronize()

    return _reported(climb, tol, identity_tol, deviation, backend, handles is not None, time.perf_counter() - start)


class _Climb(NamedTuple):
    """Where the ladder of preconditioners ended: the last one's name and iteration limit, the handles' relative
    residuals and identity deviation, the fault that stopped it (None: none), the totals and the recoveries."""

    name: str
    limit: int
    rel: np.ndarray
    identity: float
    fault: str | None
    totals: dict
    recoveries: list


def _climb_ladder(grid: Grid, field: wp.array, source, preconditioner, backend: Backend, equation: str, tol: float,
                  identity_tol: float, deviation, max_iterations, callback, progress) -> _Climb:
    """CG with each preconditioner of the ladder in turn (:func:`_ladder`), the next only after a fault of the one
    before it, from the iterate the fault left."""
    totals = {"iterations": 0, "restarts": 0, "rounds": [], "setup": 0.0}
    recoveries = []
    solver = None
    for k, (name, precondition, limit, build_seconds) in enumerate(_ladder(grid, preconditioner, backend, equation)):
        totals["setup"] += build_seconds
        if k == 0 and max_iterations is not None:
            limit = max_iterations
        del solver  # its vectors go before the next ones are allocated (the memory plan counts one set)
        solver = BatchedCG(grid, field, source, precondition, backend, equation)
        rel = solver.start()
        if recoveries:
            recoveries[-1]["next"] = name
            # from the iterate the fault left; a handle worse off than from zero (or not finite) from zero
            worse = ~np.isfinite(rel) | (rel > 1.0)
            if worse.any():
                solver.clear(worse)
                rel = solver.start()
        rel, identity, fault = _attempt(solver, rel, tol, identity_tol, deviation, totals, limit, callback, field,
                                        stagnation=name != "jacobi", progress=progress)
        if fault is None:
            break
        recoveries.append({"iteration": totals["iterations"], "fault": fault, "preconditioner": name})
    return _Climb(name, limit, rel, identity, fault, totals, recoveries)


def _reported(climb: _Climb, tol: float, identity_tol: float, deviation, backend: Backend, checked: bool,
              seconds: float) -> SolveReport:
    """The solve's report, after its warnings (each recovery; a stop short of the tolerance); a ConvergenceError
    when every preconditioner failed or (``checked``: the columns are cage coordinates) the identity deviation ends
    beyond what is acceptable."""
    rel, identity, fault, totals, recoveries = climb.rel, climb.identity, climb.fault, climb.totals, climb.recoveries
    residual = float(rel.max()) if len(rel) else 0.0
    converged = bool(fault is None and (rel <= tol).all() and identity <= identity_tol)
    for event in recoveries:
        warnings.warn(
            f"the solver's {event['preconditioner']} preconditioner failed after {event['iteration']} iterations "
            f"({event['fault']}); " + (f"it went on with {event['next']}" if "next" in event else
                                       "nothing else was left to try"), stacklevel=3)
    report = SolveReport(iterations=totals["iterations"], residual=residual, identity_error=identity,
                         converged=converged, restarts=totals["restarts"], seconds=seconds,
                         setup_seconds=totals["setup"], rounds=totals["rounds"], identity_tolerance=identity_tol,
                         preconditioner=climb.name, recoveries=recoveries)
    # a fault on every preconditioner leaves an iterate that is no solution, whatever its identity deviation (the
    # starting field already reproduces constants and linear functions)
    if fault is not None or (checked and not identity <= ACCEPTABLE * identity_tol):
        with backend.scope():
            data = deviation(known=True)
        error = ConvergenceError(_failure_message(totals, residual, identity, ACCEPTABLE * identity_tol, recoveries,
                                                  fault, climb.limit, data))
        error.report = report
        raise error
    if not converged:
        warnings.warn(
            f"the solver stopped after {totals['iterations']} iterations with relative residual {residual:.3g} and "
            f"identity deviation {identity:.3g} (tol {tol:g}, identity tol {identity_tol:.3g})"
            + (": iteration limit reached" if totals["limit_reached"] else ": float32 accuracy limit"),
            stacklevel=3,
        )
    return report


def _attempt(solver: BatchedCG, rel: np.ndarray, tol: float, identity_tol: float, deviation, totals: dict,
             max_iterations: int, callback, field, stagnation: bool, progress=None):
    """Rounds of CG with one preconditioner until the stopping rule is met, the iteration limit is reached, restarts
    run out, or a watchdog sees a fault. Adds to ``totals`` (iterations, restarts, rounds, whether the limit was
    reached, and ``progress``: the residual's fall over the last rounds). Returns (relative residuals, identity
    deviation, the fault or None)."""
    # The preconditioned residual is a few times smaller than the weight error it stands for: aim ten times below
    # tol before the first identity check.
    tol_cg, restarts, used = 0.1 * tol, 0, 0
    first = float(rel.max()) if len(rel) else 0.0
    totals["progress"], totals["limit_reached"] = (first, first), False
    if solver.indefinite:  # found by start(): the residuals measured in M are meaningless
        return rel, deviation(), "the preconditioner is not positive definite (b^T M b < 0)"
    before = totals["iterations"]  # the callback counts the iterations of the whole solve
    numbered = None if callback is None else (lambda iteration, current: callback(before + iteration, current))
    shown = None if progress is None else (lambda iteration, residual: progress(before + iteration, residual))
    while True:
        iterations, fault = cg_round(solver, rel, tol_cg, deviation, identity_tol, used, max_iterations, numbered,
                                     field, Watchdog(stagnation), shown)
        totals["iterations"] += iterations - used
        used = iterations
        # the CG recurrence drifts from the true residual in float32: check it from scratch
        rel = solver.recompute()
        identity = deviation()
        totals["rounds"].append([totals["iterations"], float(rel.max()) if len(rel) else 0.0, identity])
        if fault is None and not (np.isfinite(rel).all() and np.isfinite(identity)):
            fault = "the residual is not finite"
        if fault is None and solver.indefinite:
            fault = "the preconditioner is not positive definite (r^T M r < 0)"
        if fault is None and len(rel) and rel.max() > GROWTH * max(first, 1.0):
            fault = f"the residual grew {rel.max() / max(first, 1.0):.0e}-fold"
        totals["limit_reached"] = used >= max_iterations
        totals["progress"] = (first, float(rel.max()) if len(rel) else 0.0)
        done = bool((rel <= tol).all() and identity <= identity_tol)
        if fault is not None and not (done and np.isfinite(rel).all() and not solver.indefinite):
            return rel, identity, fault
        # (a growth or stagnation seen within a round whose recomputed residual meets the rule is no fault)
        if done or used >= max_iterations or restarts >= MAX_RESTARTS:
            return rel, identity, None
        # CG starts again from the recomputed residual; when the weights were what fell short, asking for more
        restarts += 1
        totals["restarts"] += 1
        if identity > identity_tol:
            tol_cg = min(tol_cg, float(rel.max())) / 10.0


def _failure_message(totals: dict, residual: float, identity: float, acceptable: float, recoveries: list, fault,
                     limit: int, data: float) -> str:
    """One line: what the solve reached, what it tried, and the cause as far as it is known (``data``: the boundary
    data's own deviation at the ring and band nodes); advice only where it holds for this case."""
    tried = [e["preconditioner"] for e in recoveries] + ([recoveries[-1]["next"]] if recoveries and fault is None
                                                         else [])
    message = (f"the solver could not bring partition of unity and linear precision within {acceptable:.1g} "
               f"(reached {identity:.2g}, relative residual {residual:.2g}, after {totals['iterations']} iterations"
               + (f" with {', then '.join(tried)}" if tried else "") + "); no weights were returned: ")
    if not data <= acceptable:
        return message + (f"the boundary data does not reproduce constant and linear functions (deviation {data:.2g} "
                          "at the ring and band nodes)")
    if fault is not None:
        return message + (f"{fault}, a fault of the solver on this cage at this resolution; please report it with "
                          "the cage")
    first, last = totals["progress"]
    if totals["limit_reached"]:
        if last < first and recoveries:  # the limit of a preconditioner taken after a fault: not the user's
            return message + (f"its last preconditioner reached its iteration limit ({limit}) while still converging "
                              f"(residual {first:.2g} to {last:.2g}); bind with solver='jacobi' (--solver jacobi) and "
                              f"a higher iteration limit to let it finish, and please report the cage")
        if last < first:
            return message + (f"it reached its iteration limit ({limit}) while still converging (residual {first:.2g}"
                              f" to {last:.2g}); raise the limit")
        return message + (f"it reached its iteration limit ({limit}) without converging (residual {first:.2g} to "
                          f"{last:.2g}); please report it with the cage")
    return message + (f"it stopped improving after {MAX_RESTARTS} restarts; please report it with the cage")


def _gradients_from_values(grid: Grid, field: wp.array, backend: Backend) -> None:
    """The interior rows' G of a Laplace solution: central differences of its values (its G rows solved to 0)."""
    arrays = grid.device_arrays(backend)
    wp.launch(laplace.gradient_from_values, dim=(grid.n_interior, field.shape[1]),
              inputs=[field, arrays["index"], arrays["active_ijk"]], device=backend.device)


def _ladder(grid: Grid, preconditioner, backend: Backend, equation: str = "biharmonic"):
    """The preconditioners a solve takes in turn, each only after a fault of the one before it, built when reached:
    (name, apply(r, z), default iteration limit, seconds to build it). The multigrid cycle (built here for
    "multigrid"), then the same cycle with guaranteed smoother bounds, then the inverse diagonal; "jacobi" alone
    when asked for."""
    if preconditioner == "jacobi" or isinstance(preconditioner, Jacobi):
        yield "jacobi", jacobi_step(equation, backend), 40 * (grid.resolution + 8) ** 2, 0.0
        return
    start = time.perf_counter()
    if preconditioner == "multigrid":
        preconditioner = Multigrid(grid, device=backend, equation=equation)
        backend.synchronize()
    if not isinstance(preconditioner, Multigrid):
        raise ValueError(f"unknown preconditioner {preconditioner!r}: use 'multigrid' or 'jacobi'")
    if preconditioner.equation != equation:
        raise ValueError(f"the multigrid was built for the {preconditioner.equation} equation, the solve is for the "
                         f"{equation} one")
    setup = time.perf_counter() - start
    if preconditioner.smoother_bounds == "power iteration":
        yield "multigrid", preconditioner.apply, MULTIGRID_ITERATIONS, setup
        start = time.perf_counter()
        preconditioner.bound_eigenvalues()  # kept: the later chunks of a bind use the cycle that worked
        setup = time.perf_counter() - start
    yield "multigrid with guaranteed smoother bounds", preconditioner.apply, MULTIGRID_ITERATIONS, setup
    yield "jacobi", jacobi_step(equation, backend), jacobi_recovery_iterations(grid.resolution), 0.0


def jacobi_recovery_iterations(resolution: int) -> int:
    """The iteration limit of the inverse diagonal taken after the multigrid failed: (n + 8)^2, about three times what
    Jacobi-preconditioned CG needs to a 1e-6 weight error on a smooth cage (its iterations grow like n^2). Beyond it
    the solve ends in a ConvergenceError rather than in hours of iterations: 5,184 at n = 64, 69,696 at n = 256
    (minutes of a GPU for a cage of a hundred handles).

    Examples
    --------
    >>> jacobi_recovery_iterations(64)
    5184
    """
    return (int(resolution) + 8) ** 2


def _identity_check(grid: Grid, field: wp.array, handles, backend: Backend, chunk: slice | None = None):
    """A function returning the largest deviation from partition of unity and linear precision at the
    interior nodes (0 when ``handles`` is None), over the columns of ``field``: the cage coordinates of all
    ``handles``; or of ``handles[chunk]`` followed by the complement column, and then partition of unity only."""
    if handles is None:
        return lambda known=False: 0.0
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
    device = backend.device
    ijk = grid.device_arrays(backend)["active_ijk"]
    columns = wp.array(columns, dtype=wp.vec4d, device=device)
    out = wp.zeros(1, dtype=float, device=device)

    def deviation(known: bool = False) -> float:
        """At the interior nodes; with ``known``, of the boundary data at the ring and band nodes."""
        rows = slice(grid.n_interior, field.shape[0]) if known else slice(0, grid.n_interior)
        out.zero_()
        wp.launch(
            checks.identity_deviation,
            dim=rows.stop - rows.start,
            inputs=[field[rows], ijk[rows], wp.vec3d(*grid.origin), wp.float64(grid.spacing), columns,
                    wp.float64(scale), int(chunk is None)],
            outputs=[out],
            device=device,
        )
        return float(out.numpy()[0])

    return deviation
