"""The times an animation is read at: its keys, or a rate's samples from its first key to its last, and times in
seconds as frame numbers (:func:`warp_stokes.io.skinned.load_frames`, glTF and USD alike)."""

from __future__ import annotations

import numpy as np

from ..errors import BindingError

__all__ = ["MAX_FRAMES", "sample_times", "frame_numbers"]

#: the most frames a rate may ask for (a rate far beyond the animation's would fill the memory)
MAX_FRAMES = 100_000


def sample_times(keys: np.ndarray, step: float | None, name: str = "the animation") -> np.ndarray:
    """``keys`` themselves (no ``step``), or every ``step`` from the first key through the last.

    Examples
    --------
    >>> sample_times(np.array([0.0, 0.3, 1.0]), 0.25).tolist()
    [0.0, 0.25, 0.5, 0.75, 1.0]
    """
    if step is None:
        return np.asarray(keys, dtype=np.float64)
    # the last key included when within 1e-4 of a step of one (glTF keeps times as float32: 17/24 s at 48 fps is
    # 33.99999 steps)
    count = np.floor((keys[-1] - keys[0]) / step + 1e-4) + 1
    if count > MAX_FRAMES:
        raise BindingError(f"{name}: sampling it every {step:g} from {keys[0]:g} to {keys[-1]:g} makes {count:.3g} "
                           f"frames, more than {MAX_FRAMES}; choose a lower rate")
    return keys[0] + step * np.arange(int(count))


def frame_numbers(seconds: np.ndarray, rate: float) -> np.ndarray:
    """Times in seconds as frame numbers at ``rate``; within 1e-4 of a whole frame, that frame (glTF keeps times as
    float32: a 24 fps animation's key 17/24 s is 16.9999995 frames).

    Examples
    --------
    >>> frame_numbers(np.array([0.0, 0.7083333134651184, 0.71]), 24.0).tolist()
    [0.0, 17.0, 17.04]
    """
    frames = np.asarray(seconds, dtype=np.float64) * rate
    whole = np.round(frames)
    return np.where(np.abs(frames - whole) < 1e-4, whole, frames)
