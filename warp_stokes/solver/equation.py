"""The equations the weights solve, each with what every solver stage takes for it: Stokes coordinates (the compact
19-point coupled biharmonic scheme) and harmonic coordinates (the 7-point Laplace equation in the same (q, G)
layout). Named once where a solve starts (:func:`equation_of`); below, the stages read the Equation's fields."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import WarpStokesError
from ..kernels import cg, laplace
from ..kernels import multigrid as mg_kernels

__all__ = ["Equation", "BIHARMONIC", "LAPLACE", "EQUATIONS", "equation_of"]


@dataclass(frozen=True)
class Equation:
    """A PDE the weights solve.

    Attributes
    ----------
    name : "biharmonic" | "laplace"
    compact : bool, the compact scheme: values and gradients are coupled unknowns (its operator fuses a residual
        with a smoothing step); else the values alone, the gradients their central differences after the solve
    source_power, source_factor : the value equation's right-hand side is ``source_factor * h**source_power * f``
    jacobi : the kernel of its inverse diagonal, z = D^-1 r
    inverse_diagonal : (4,) the fine operator's constant diagonal block's inverse, per unknown (q, G)
    multigrid_operator : the multigrid kernels' code of the fine operator
    prolongation_table : the kernel that tabulates its prolongation (Hermite for the compact scheme, trilinear)
    row_sum_bound : a guaranteed bound of the largest eigenvalue of D^-1 A on the fine level: its largest absolute row
        sum, the same on every row that has all its neighbours (the multigrid smoother's guaranteed upper end)
    kernel_modules : the kernel modules it needs beyond a bind's own

    Examples
    --------
    >>> equation_of("laplace").compact, equation_of(BIHARMONIC) is BIHARMONIC
    (False, True)
    """

    name: str
    compact: bool
    source_power: int
    source_factor: float
    jacobi: object
    inverse_diagonal: tuple
    multigrid_operator: int
    prolongation_table: object
    row_sum_bound: float
    kernel_modules: tuple

    def source_scale(self, spacing: float) -> float:
        """The factor of a source ``f`` in the value equation's right-hand side at node spacing ``spacing``."""
        return self.source_factor * spacing**self.source_power

    def __str__(self) -> str:
        return self.name


# the row sum bounds: (48 + 6 * 10 + 12 + 6 * 3) / 48 on the compact scheme's value rows, (4 + 2 + 2 * 3) / 4 on its
# gradient rows; (6 + 6) / 6 for Laplace
BIHARMONIC = Equation("biharmonic", True, 4, 0.5, cg.jacobi, (1.0 / 48.0, 0.25, 0.25, 0.25),
                      int(mg_kernels.BIHARMONIC), mg_kernels.hermite_table, 3.0, ())
LAPLACE = Equation("laplace", False, 2, 1.0, laplace.jacobi, (1.0 / 6.0, 1.0, 1.0, 1.0), int(mg_kernels.LAPLACE),
                   mg_kernels.trilinear_table, 2.0, ("laplace",))
#: the equations by name
EQUATIONS = {e.name: e for e in (BIHARMONIC, LAPLACE)}


def equation_of(equation) -> Equation:
    """The Equation for a name ("biharmonic" or "laplace") or an Equation.

    Raises
    ------
    WarpStokesError
        For anything else.
    """
    if isinstance(equation, Equation):
        return equation
    if isinstance(equation, str) and equation in EQUATIONS:
        return EQUATIONS[equation]
    raise WarpStokesError(f"equation must be 'biharmonic' or 'laplace', got {equation!r}")
