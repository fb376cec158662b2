"""Sampling the solved weight field at mesh vertices: tricubic Hermite of (q, G) by default (C1), or trilinear
of q (C0, as in the source paper)."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..device import Backend
from ..geometry.grid import Grid
from ..kernels import sample

__all__ = ["sample_weights", "SAMPLINGS"]

#: the sampling methods: "hermite" (default) and "trilinear"
SAMPLINGS = ("hermite", "trilinear")


def sample_weights(grid: Grid, field: wp.array, points: np.ndarray, device=None,
                   method: str = "hermite") -> tuple[np.ndarray, np.ndarray]:
    """Interpolation of every handle's weight at the given points.

    ``"hermite"`` interpolates (q, G = h grad q) over the point's cell with tricubic Hermite polynomials (mixed
    derivatives zero): C1 across cell faces, exact for linear functions. ``"trilinear"`` interpolates q: C0.

    A point is sampled when all 8 corners of its grid cell are active nodes (interior, ring or band): every
    point inside the cage, and points outside it within the band.

    Parameters
    ----------
    grid : Grid
    field : wp.array2d(vec4f), (grid.n_active, handles), the solved field
    points : (V, 3) array of absolute positions
    device : None | str | Backend
    method : "hermite" | "trilinear"

    Returns
    -------
    weights : (V, handles) float32; rows of points that were not sampled are zero
    corners : (V, 8) int32, rows of each point's cell corners in the field (-1: not an active node); a point
        is sampled when all are >= 0, and its cell has a node inside the cage when one is < ``grid.n_inside``

    Examples
    --------
    >>> weights, corners = sample_weights(grid, field, mesh_vertices)  # doctest: +SKIP
    """
    if method not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {SAMPLINGS}, got {method!r}")
    backend = Backend.of(device)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n_points, n_handles = len(points), field.shape[1]
    arrays = grid.device_arrays(backend)
    with backend.scope():
        pts = wp.array(points - grid.centre, dtype=wp.vec3d)
        corners = wp.empty((n_points, 8), dtype=wp.int32)
        fractions = wp.empty(n_points, dtype=wp.vec3d)
        wp.launch(
            sample.locate_cells,
            dim=n_points,
            inputs=[pts, wp.vec3d(*grid.origin), wp.float64(grid.spacing), arrays["index"]],
            outputs=[corners, fractions],
        )
        weights = wp.empty((n_points, n_handles), dtype=wp.float32)
        kernel = {"hermite": sample.sample_hermite, "trilinear": sample.sample_trilinear}[method]
        wp.launch(kernel, dim=(n_points, n_handles), inputs=[corners, fractions, field], outputs=[weights])
        rows = corners.numpy()
        out = weights.numpy()
    out[~(rows >= 0).all(axis=1)] = 0.0
    return out, rows
