"""Boundary data: mean value coordinates of the cage at grid nodes, packed with their gradients.

Ring and band nodes keep these values as known data; interior nodes start from them (the MVC field already
has exact partition of unity and linear precision, so the solver only corrects it). Gradients G = h grad q
are the central differences of nodal MVC values with step h: a rule exact for linear functions, so the
discrete solution reproduces constants and linear functions exactly. (The analytic MVC gradient is the
other exact choice; it imposes slightly different Neumann data. We keep the central difference.)
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .cage import Cage
from .device import resolve_device
from .grid import Grid
from .kernels import mvc, stencil

__all__ = ["mean_value_coordinates", "boundary_field"]

#: tolerance of the degenerate cases (point on a triangle, or in its plane outside it), on unit-vector
#: quantities: angles and the volume spanned by the three unit vectors to the corners
EPS_ANGLE = 1e-10


def _mvc_on_device(cage: Cage, centre: np.ndarray, points_rel: np.ndarray, handles: slice, device) -> wp.array:
    cage_rel = cage.vertices - centre
    first, stop, _ = handles.indices(cage.n_handles)
    with wp.ScopedDevice(device):
        pts = wp.array(points_rel, dtype=wp.vec3d)
        verts = wp.array(cage_rel, dtype=wp.vec3d)
        tris = wp.array(cage.faces.astype(np.int32), dtype=wp.vec3i)
        out = wp.empty((len(points_rel), stop - first), dtype=wp.float64)
        wp.launch(
            mvc.mean_value_coordinates,
            dim=len(points_rel),
            inputs=[pts, verts, tris, wp.float64(1e-12 * cage.diagonal), wp.float64(EPS_ANGLE), first],
            outputs=[out],
        )
    return out


def mean_value_coordinates(cage: Cage, points: np.ndarray, device=None) -> np.ndarray:
    """Mean value coordinates (Ju, Schaefer, Warren 2005) of a triangle cage at arbitrary points.

    Parameters
    ----------
    cage : Cage
    points : (N, 3) array, anywhere off the cage (on it, the coordinates are the hat functions)
    device : None | str

    Returns
    -------
    (N, L) float64, rows sum to one and reproduce the points: ``W @ cage.vertices == points``

    Examples
    --------
    >>> w = mean_value_coordinates(cage, cage.vertices.mean(axis=0)[None])  # doctest: +SKIP
    >>> np.allclose(w @ cage.vertices, cage.vertices.mean(axis=0))  # doctest: +SKIP
    True
    """
    device = resolve_device(device)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros((0, len(cage.vertices)))
    centre = 0.5 * (cage.vertices.min(axis=0) + cage.vertices.max(axis=0))
    return _mvc_on_device(cage, centre, points - centre, slice(None), device).numpy()


def boundary_field(grid: Grid, cage: Cage, device=None, handles: slice = slice(None)) -> wp.array:
    """The packed (q, G) field of every handle at every active node, from mean value coordinates.

    Parameters
    ----------
    grid : Grid
    cage : Cage
    device : None | str
    handles : slice, the handles (columns) to compute, e.g. ``slice(0, 32)`` for a chunk; all by default

    Returns
    -------
    wp.array2d of vec4f, shape (grid.n_active, handles): known data at ring and band rows, the starting
    guess at interior rows. Band rows carry G = 0 (never read).
    """
    device = resolve_device(device)
    values = _mvc_on_device(cage, grid.centre, grid.node_positions(), handles, device)
    arrays = grid.device_arrays(device)
    field = wp.empty(values.shape, dtype=wp.vec4f, device=device)
    wp.launch(
        stencil.pack_nodal_field,
        dim=field.shape,
        inputs=[values, arrays["active_ijk"], arrays["index"], grid.n_interior + grid.n_ring],
        outputs=[field],
        device=device,
    )
    return field
