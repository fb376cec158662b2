"""Exceptions raised for bad input, and for a solve that could not give exact weights. All derive from ValueError so
callers can catch either."""


class WarpStokesError(ValueError):
    """Base class: input that warp-stokes cannot work with."""


class MeshError(WarpStokesError):
    """A mesh (or point set) could not be read or is unusable."""


class CageError(WarpStokesError):
    """A cage is unusable: not closed, badly oriented, degenerate, too small, ..."""


class BindingError(WarpStokesError):
    """A saved binding is unreadable, or does not match the cage or poses given with it."""


class ResolutionError(WarpStokesError):
    """The requested grid is too coarse for the cage or too large for the device. ``suggested`` (a finer resolution
    the cage needs) or ``fits`` (a coarser one the memory holds), where the error knows one: resolution "auto"
    tries that one instead."""

    suggested: int | None = None
    fits: int | None = None


class ConvergenceError(WarpStokesError):
    """The solver could not bring partition of unity and linear precision within tolerance: no weights. ``report``
    holds the solver's report (``warp_stokes.SolveReport``) where one was made."""

    report = None
