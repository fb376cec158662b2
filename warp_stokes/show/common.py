"""What the pictures share: matplotlib, headless (Agg) and deterministic; a picture saved whole; the slice's axis; a
mesh's cross-section by a plane; the method a binding's weights were computed by."""

from __future__ import annotations

import numpy as np

from ..errors import WarpStokesError
from ..io.outputs import atomic_output

__all__ = ["AXES", "RC", "binding_method", "pyplot", "axis_index", "cross_section", "save_picture"]

AXES = "xyz"
RC = {"svg.hashsalt": "warp-stokes", "figure.dpi": 100}


def binding_method(binding) -> str:
    """How the binding's weights were computed: ``settings["method"]``, "stokes" for bindings that do not say."""
    return str(binding.settings.get("method") or "stokes")


def pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise WarpStokesError('the pictures need matplotlib: pip install "warp-stokes[plot]"') from None
    return plt


def axis_index(axis) -> int:
    if axis in (0, 1, 2):
        return int(axis)
    if isinstance(axis, str) and axis.lower() in AXES:
        return AXES.index(axis.lower())
    raise WarpStokesError(f"the slice's axis must be x, y or z, got {axis!r}")


def cross_section(vertices, faces, axis: int, position: float) -> np.ndarray:
    """The cage's outline on the plane ``x[axis] == position``: one segment per triangle that crosses it.

    Parameters
    ----------
    vertices : (L, 3) array
    faces : (T, 3) int array
    axis : 0, 1 or 2
    position : float

    Returns
    -------
    (S, 2, 2) float64, segments in the plane's coordinates (the two other axes, in order). A vertex on the plane
    counts as above it, so a surface through a vertex gives connected segments.

    Examples
    --------
    >>> v = np.array([[0, 0, -1], [1, 0, 1], [0, 1, 1]], float)
    >>> cross_section(v, np.array([[0, 1, 2]]), 2, 0.0).tolist()
    [[[0.5, 0.0], [0.0, 0.5]]]
    """
    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    d = vertices[:, axis] - position
    above = d >= 0
    starts, ends = faces, np.roll(faces, -1, axis=1)  # edges (0, 1), (1, 2), (2, 0) of every triangle
    crossing = above[starts] != above[ends]
    t = d[starts] / np.where(crossing, d[starts] - d[ends], 1.0)
    points = vertices[starts] + t[..., None] * (vertices[ends] - vertices[starts])
    cut = crossing.sum(axis=1) == 2
    first_two = np.argsort(~crossing[cut], axis=1, kind="stable")[:, :2]
    segments = np.take_along_axis(points[cut], first_two[..., None], axis=1)
    return segments[..., [a for a in range(3) if a != axis]]


def save_picture(figure, path) -> None:
    import matplotlib.pyplot as plt

    try:
        with atomic_output(path, ".png") as tmp:
            figure.savefig(tmp, format="png")
    finally:
        plt.close(figure)


