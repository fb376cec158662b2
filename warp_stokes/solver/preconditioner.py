"""The preconditioners of the batched CG: what a solve needs of one (:class:`Preconditioner`), and the inverse
diagonal (:class:`Jacobi`); the multigrid V-cycle (:class:`warp_stokes.solver.multigrid.Multigrid`) is the other."""

from __future__ import annotations

from typing import Protocol

import warp as wp

from ..device import Backend
from ..geometry.grid import Grid
from .equation import equation_of

__all__ = ["Preconditioner", "Jacobi", "jacobi_step"]


class Preconditioner(Protocol):
    """What a solve and a bind's report need of a preconditioner (:class:`Multigrid` and :class:`Jacobi`): its
    name; ``apply(r, z)``, z = M^-1 r for every column; its levels' sizes, setup seconds by phase and coarsest
    operator (None without one); and ``lane()``, its view for one of the threads that solve chunks at once."""

    name: str
    level_sizes: list
    seconds: dict
    coarsest: "dict | None"

    def apply(self, r: wp.array, z: wp.array) -> None: ...

    def lane(self) -> "Preconditioner": ...


class Jacobi:
    """The inverse diagonal of the fine operator: the preconditioner for comparisons (and the last one a solve takes
    after faults of the multigrid's). Nothing to set up, nothing per thread.

    Examples
    --------
    >>> import numpy as np
    >>> mask = np.zeros((12, 12, 12), bool); mask[5:7, 5:7, 5:7] = True
    >>> from warp_stokes.geometry.grid import grid_from_mask
    >>> jacobi = Jacobi(grid_from_mask(mask, device="cpu"), device="cpu")
    >>> jacobi.name, jacobi.level_sizes, jacobi.lane() is jacobi
    ('jacobi', [8], True)
    """

    name = "jacobi"
    coarsest = None

    def __init__(self, grid: Grid, equation: str = "biharmonic", device=None):
        self.backend, self.equation = Backend.of(device), equation_of(equation)
        self.level_sizes, self.seconds = [grid.n_interior], {}
        self._step = jacobi_step(self.equation, self.backend)

    def apply(self, r: wp.array, z: wp.array) -> None:
        self._step(r, z)

    def lane(self) -> "Jacobi":
        return self


def jacobi_step(equation, backend: Backend):
    """apply(r, z): z = D^-1 r, the inverse diagonal of the fine operator."""
    kernel = equation_of(equation).jacobi

    def precondition(r, z):
        wp.launch(kernel, dim=r.shape, inputs=[r], outputs=[z], device=backend.device)

    return precondition
