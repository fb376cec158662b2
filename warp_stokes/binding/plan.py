"""A bind's plan: every option checked and resolved once, where the bind starts, and carried down whole.

:func:`warp_stokes.bind` (and a spread bind's workers) make a :class:`GridPlan`; the stages below it read typed fields
(``plan.multigrid``, ``plan.local_data``, ``plan.backend``) and never test an option string or resolve a device."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..arguments import integer, number
from ..device import Backend
from ..errors import WarpStokesError
from ..geometry.local_data import LocalData, MeanValueData, boundary_settings
from ..solver.equation import Equation, equation_of
from .sample import SAMPLINGS

__all__ = ["GridPlan", "METHODS", "PRECONDITIONERS", "SAMPLINGS"]

#: the coordinates ``bind`` computes: the equation each grid method solves, and None for MVC (no grid)
METHODS = {"stokes": "biharmonic", "harmonic": "laplace", "mvc": None}
#: the CG preconditioners: the multigrid V-cycle, or the inverse diagonal (for comparisons)
PRECONDITIONERS = ("multigrid", "jacobi")


@dataclass(frozen=True)
class GridPlan:
    """How the grid part of a bind is computed.

    Attributes
    ----------
    backend : Backend, the device (and a CPU's threads) the grid, solve and sampling run on
    method : "stokes" | "harmonic" | "mvc"
    boundary : LocalData | MeanValueData, the data at ring and band nodes
    preconditioner : "multigrid" | "jacobi"
    tol : float
    max_iterations : int or None
    sampling : "hermite" | "trilinear"
    memory_budget : int or None, bytes the bind may allocate (None: what the device has free)

    Examples
    --------
    >>> plan = GridPlan.of("cpu", boundary="local", threads=1)
    >>> plan.equation.name, plan.multigrid, plan.local_data, plan.backend.threads
    ('biharmonic', True, True, 1)
    """

    backend: Backend
    method: str = "stokes"
    boundary: "LocalData | MeanValueData" = LocalData()
    preconditioner: str = "multigrid"
    tol: float = 1e-6
    max_iterations: int | None = None
    sampling: str = "hermite"
    memory_budget: int | None = None

    @classmethod
    def of(cls, device=None, method: str = "stokes", boundary="local", solver: str = "multigrid", tol: float = 1e-6,
           max_iterations: int | None = None, sampling: str = "hermite", memory_budget: int | None = None,
           threads: int | None = None) -> "GridPlan":
        """The plan for ``bind``'s arguments (see :func:`warp_stokes.bind`), each checked here: a bad one is one
        WarpStokesError before any work."""
        if method not in METHODS:
            raise WarpStokesError(f"method must be 'stokes', 'harmonic' or 'mvc', got {method!r}")
        number(tol, "tol", 0, 0.1, low_open=True)
        if memory_budget is not None:
            number(memory_budget, "memory_budget (bytes)", 0, low_open=True)
            memory_budget = int(memory_budget)
        if max_iterations is not None:
            integer(max_iterations, "max_iterations", 1)
        if solver not in PRECONDITIONERS:
            raise WarpStokesError(f"solver must be 'multigrid' or 'jacobi', got {solver!r}")
        if sampling not in SAMPLINGS:
            raise WarpStokesError(f"sampling must be 'hermite' or 'trilinear', got {sampling!r}")
        return cls(Backend.of(device, threads), method, boundary_settings(boundary), solver, float(tol),
                   max_iterations, sampling, memory_budget)

    @property
    def equation(self) -> Equation | None:
        """The biharmonic equation (Stokes), Laplace's (harmonic), or None (MVC: no grid)."""
        return None if METHODS[self.method] is None else equation_of(METHODS[self.method])

    @property
    def multigrid(self) -> bool:
        return self.preconditioner == "multigrid"

    @property
    def local_data(self) -> bool:
        """Whether the ring and band take the local data (else mean value coordinates)."""
        return self.boundary.local

    def budget(self) -> int:
        """Bytes the bind may allocate on its device."""
        return self.backend.available_memory() if self.memory_budget is None else self.memory_budget

    def on(self, backend: Backend) -> "GridPlan":
        """The same plan on another backend (a spread bind's share, a CPU lane's threads)."""
        return dataclasses.replace(self, backend=backend)

    def __getstate__(self):
        # a Warp device stays in its process: a plan sent to another (a spread bind's Ray task) names its device
        return {**{f.name: getattr(self, f.name) for f in dataclasses.fields(self)},
                "backend": (self.backend.alias, self.backend.threads)}

    def __setstate__(self, state):
        alias, threads = state.pop("backend")
        for name, value in state.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "backend", Backend.of(alias, threads))
