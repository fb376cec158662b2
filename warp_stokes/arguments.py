"""The one place where option values are checked, for the command line and the library alike: numbers (real,
finite, within float32's range, within bounds), integers, choices and flags. A bad value is one
:class:`~warp_stokes.errors.WarpStokesError` that names the option and what it takes."""

from __future__ import annotations

import math
import numbers

from .errors import WarpStokesError

__all__ = ["FLOAT32_MAX", "FLOAT32_TINY", "INT32_MAX", "number", "integer", "choice", "flag", "shown"]

#: the largest finite float32, and the smallest normal one: the kernels compute in float32, so every number the
#: package takes as a float lies in between (or is zero)
FLOAT32_MAX = 3.4028234663852886e38
FLOAT32_TINY = 1.1754943508222875e-38
#: counts (iterations, handles, influences) are int32 in the kernels
INT32_MAX = 2**31 - 1


def shown(value) -> str:
    """A value as a message shows it: numbers compactly (``1e-40``, ``inf``), anything else by its repr."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return repr(value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def _bounds(low, high, low_open: bool, integer: bool) -> str:
    parts = []
    if low is not None:
        parts.append(f"> {low:g}" if low_open else f">= {low:g}")
    if high is not None:
        parts.append(f"<= {high:g}")
    if integer:
        return "an integer " + " and ".join(parts) if parts else "an integer"
    return " and ".join(parts) if parts else "a finite number"


def number(value, name: str, low=None, high=None, low_open: bool = False, integer: bool = False):
    """``value`` checked as a number: real (not a bool or a string), finite, within float32's range (zero, or a
    magnitude from :data:`FLOAT32_TINY` to :data:`FLOAT32_MAX`; with ``integer``, an int within int32), and within
    ``[low, high]``
    (``low`` excluded with ``low_open``).

    Parameters
    ----------
    value : the value given
    name : str, the option's name for the message (empty: the message starts with "must")
    low, high : bounds, optional
    low_open : bool
    integer : bool, an integer is required (a float with an integral value is not one)

    Returns
    -------
    int or float

    Raises
    ------
    WarpStokesError

    Examples
    --------
    >>> number(24, "fps", 0, low_open=True)
    24.0
    >>> number(1e-40, "fps", 0, low_open=True)
    Traceback (most recent call last):
    ...
    warp_stokes.errors.WarpStokesError: fps must be > 0 within float32's range (1.18e-38 to 3.4e+38), got 1e-40
    >>> number(2.5, "influences", 1, integer=True)
    Traceback (most recent call last):
    ...
    warp_stokes.errors.WarpStokesError: influences must be an integer >= 1, got 2.5
    """
    expected = _bounds(low, high, low_open, integer)
    prefix = f"{name} " if name else ""
    is_integer = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or (integer and not is_integer):
        raise WarpStokesError(f"{prefix}must be {expected}, got {shown(value)}")
    if is_integer and integer:
        value = int(value)
        if abs(value) > INT32_MAX:
            raise WarpStokesError(f"{prefix}must be {expected} of at most {INT32_MAX}, got {value}")
    else:
        value = float(value)
        if not math.isfinite(value):
            raise WarpStokesError(f"{prefix}must be {expected}, got {shown(value)}")
        if value != 0 and not FLOAT32_TINY <= abs(value) <= FLOAT32_MAX:
            raise WarpStokesError(f"{prefix}must be {expected} within float32's range ({FLOAT32_TINY:.3g} to "
                                  f"{FLOAT32_MAX:.3g}), got {shown(value)}")
    if (low is not None and (value <= low if low_open else value < low)) or (high is not None and value > high):
        raise WarpStokesError(f"{prefix}must be {expected}, got {shown(value)}")
    return value


def integer(value, name: str, low=None, high=None) -> int:
    """:func:`number` for an integer (``True``, ``2.5`` and ``"8"`` are not ones).

    Examples
    --------
    >>> integer(8, "influences", 1)
    8
    """
    return number(value, name, low, high, integer=True)


def choice(value, name: str, choices) -> str:
    """``value`` when it is one of ``choices`` (strings), else one error listing them.

    Examples
    --------
    >>> choice("linear", "interpolation", ("linear", "spline"))
    'linear'
    """
    if not isinstance(value, str) or value not in choices:
        listed = ", ".join(repr(c) for c in choices)
        raise WarpStokesError(f"{name} must be one of {listed}, got {shown(value)}")
    return value


def flag(value, name: str) -> bool:
    """``value`` when it is a bool (numpy's too), else one error: ``"no"`` is not False.

    Examples
    --------
    >>> flag(False, "with_cage")
    False
    """
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        return bool(value)
    raise WarpStokesError(f"{name} must be True or False, got {shown(value)}")
