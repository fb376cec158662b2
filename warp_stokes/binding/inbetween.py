"""In-betweening: frames between key cage poses, per handle, piecewise linear or a natural cubic spline in the
frame number (the source paper's cage in-betweening, Fig. 3: the binding deforms every in-between cage)."""

from __future__ import annotations

import math
import numbers

import numpy as np

from ..errors import WarpStokesError
from ..io.poses import Poses

__all__ = ["inbetween", "INTERPOLATIONS", "MAX_FRAMES"]

INTERPOLATIONS = ("linear", "spline")
MAX_FRAMES = 100_000  # more is a typo in the key frames or the step count, not an animation


def inbetween(poses: Poses, key_frames=None, steps: int | None = None, interpolation: str = "linear") -> Poses:
    """Frames between key cage poses.

    Parameters
    ----------
    poses : Poses, the keys (at least 2)
    key_frames : sequence of float, optional, the keys' frame numbers, strictly increasing, one per key
        (default: ``poses.frames``)
    steps : int, optional, the number of evenly spaced frames between each two consecutive keys (time codes may be
        fractional; 0 gives the keys alone). Default: every integer frame from the first key to the last, with the
        keys at non-integer frames kept too.
    interpolation : "linear" | "spline", per handle: piecewise linear in the frame number, or the natural cubic
        spline through the keys (twice continuously differentiable, zero second derivative at the first and last
        key; with 2 keys it is the linear motion)

    Returns
    -------
    Poses, the keys (reproduced exactly) and the frames between them, in frame order, with the keys'
    ``time_codes_per_second``

    Raises
    ------
    WarpStokesError
        Fewer than 2 keys, key frames that are not one finite, strictly increasing number per key, a step count that
        is not an integer >= 0, an unknown interpolation, or more than :data:`MAX_FRAMES` frames to write.

    Examples
    --------
    Two keys of 2 handles at frames 0 and 10, 4 frames between them:

    >>> keys = Poses(np.array([[[0.0, 0, 0], [1, 0, 0]], [[0, 10, 0], [1, 0, 10]]]), np.array([0.0, 10.0]), "keys")
    >>> out = inbetween(keys, steps=4)
    >>> out.frames
    array([ 0.,  2.,  4.,  6.,  8., 10.])
    >>> out.positions[1]
    array([[0., 2., 0.],
           [1., 0., 2.]])
    >>> len(inbetween(keys, key_frames=[0, 30], interpolation="spline").frames)  # every frame 0..30
    31
    """
    positions = np.asarray(poses.positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise WarpStokesError(f"{poses.name}: key poses must have shape (keys, handles, 3), got {positions.shape}")
    n_keys = len(positions)
    if n_keys < 2:
        raise WarpStokesError(f"{poses.name}: in-betweening needs at least 2 key poses, got {n_keys}")
    try:
        keys = np.asarray(poses.frames if key_frames is None else key_frames, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise WarpStokesError(f"key frames must be numbers, got {key_frames!r}") from None
    if len(keys) != n_keys:
        raise WarpStokesError(f"{poses.name}: {len(keys)} key frame numbers for {n_keys} key poses")
    if not np.all(np.isfinite(keys)):
        raise WarpStokesError(f"{poses.name}: key frames must be finite, got {keys.tolist()[:10]}")
    if not np.all(np.diff(keys) > 0):
        raise WarpStokesError(f"{poses.name}: key frames must be strictly increasing, got {keys.tolist()[:10]}")
    if not np.all(np.isfinite(positions)):
        raise WarpStokesError(f"{poses.name}: the key poses contain NaN or infinite coordinates")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, numbers.Integral) or steps < 0):
        raise WarpStokesError(f"steps (frames between two keys) must be an integer >= 0, got {steps!r}")
    if interpolation not in INTERPOLATIONS:
        raise WarpStokesError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {interpolation!r}")

    frames = _output_frames(keys, steps)
    interval = np.clip(np.searchsorted(keys, frames, side="right") - 1, 0, n_keys - 2)
    h = (keys[interval + 1] - keys[interval])[:, None, None]
    b = (frames - keys[interval])[:, None, None] / h  # 0 at the interval's first key, 1 at its last
    a = 1.0 - b
    out = a * positions[interval] + b * positions[interval + 1]
    if interpolation == "spline":
        m = _natural_second_derivatives(keys, positions)
        out += ((a**3 - a) * m[interval] + (b**3 - b) * m[interval + 1]) * h**2 / 6.0
    out[np.searchsorted(frames, keys)] = positions  # the keys as given, bit for bit, whatever the rounding above
    return Poses(out, frames, f"{poses.name}, in-between ({interpolation})", poses.time_codes_per_second)


def _output_frames(keys: np.ndarray, steps: int | None) -> np.ndarray:
    """The frame numbers to write: ``steps`` evenly between each two keys, else every integer frame and the keys.
    Counted before anything is allocated, so that a huge request is one error, not an out-of-memory."""
    if steps is not None:
        count = (len(keys) - 1) * (steps + 1) + 1
    else:
        first, last = math.ceil(keys[0]), math.floor(keys[-1])
        count = max(last - first + 1, 0) + len(keys)  # at most: keys on integer frames are counted twice
    if count > MAX_FRAMES:
        raise WarpStokesError(f"in-betweening would write {count:,} frames (keys {keys[0]:g} to {keys[-1]:g}), more "
                              f"than {MAX_FRAMES:,}; check the key frames and the step count")
    if steps is not None:
        fractions = np.arange(steps + 1) / (steps + 1)
        inner = (keys[:-1, None] + np.diff(keys)[:, None] * fractions).reshape(-1)  # each key, then its steps
        frames = np.append(inner, keys[-1])
        if not np.all(np.diff(frames) > 0):  # keys so close, for their size, that the steps round together
            raise WarpStokesError(f"{steps} steps between keys {keys.tolist()[:10]} round to repeated frame numbers")
        return frames
    return np.union1d(np.arange(first, last + 1, dtype=np.float64), keys)


def _natural_second_derivatives(keys: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """The natural cubic spline's second derivatives at the keys, (K, L, 3): zero at both ends, and at each
    interior key the C2 condition h[i-1] M[i-1] + 2 (h[i-1] + h[i]) M[i] + h[i] M[i+1] = 6 (slope[i] - slope[i-1]),
    a tridiagonal system solved by forward elimination and back substitution (strictly diagonally dominant, so no
    pivoting), for all handles and axes at once."""
    m = np.zeros_like(positions)
    n_inner = len(keys) - 2
    if n_inner == 0:
        return m
    h = np.diff(keys)
    slopes = np.diff(positions, axis=0) / h[:, None, None]
    diagonal = 2.0 * (h[:-1] + h[1:])
    rhs = 6.0 * np.diff(slopes, axis=0)
    for i in range(1, n_inner):  # eliminate the sub-diagonal h[i]
        factor = h[i] / diagonal[i - 1]
        diagonal[i] -= factor * h[i]
        rhs[i] -= factor * rhs[i - 1]
    m[n_inner] = rhs[-1] / diagonal[-1]
    for i in range(n_inner - 2, -1, -1):
        m[i + 1] = (rhs[i] - h[i + 1] * m[i + 2]) / diagonal[i]
    return m
