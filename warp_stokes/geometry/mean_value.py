"""Mean value coordinates (Ju, Schaefer, Warren 2005) of a triangle cage at any points, in a Warp kernel: the boundary
data of "mvc" (:mod:`.boundary`), the start of the interior's solve, and the normal derivatives the local data
starts from (:mod:`.local_data`)."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..device import Backend
from ..kernels import mvc as mvc_kernels
from .cage import Cage

__all__ = ["mean_value_coordinates", "mvc_on_device", "EPS_PLANE", "ON_CAGE"]

#: a point whose unit vectors to a triangle's corners span a volume below this lies in the triangle's plane (outside
#: it, once the on-cage test has failed): the triangle contributes nothing
EPS_PLANE = 1e-10
#: a point within this fraction of the cage's diagonal from a cage triangle is on the cage: its coordinates are the
#: hat functions at its projection (exact for points on faces, edges and vertices; an error of at most about this
#: much, relative, in linear precision for points that near)
ON_CAGE = 1e-9


def mvc_on_device(cage: Cage, centre: np.ndarray, pts: wp.array, handles: slice, device,
                   out: wp.array | None = None) -> wp.array:
    """MVC of the handles in `handles` at the points `pts` (vec3d on `device`, relative to `centre`), into
    `out` (points, handles) or a new float64 array."""
    cage_rel = cage.vertices - centre
    first, stop, _ = handles.indices(cage.n_handles)
    with wp.ScopedDevice(device):
        verts = wp.array(cage_rel, dtype=wp.vec3d)
        tris = wp.array(cage.faces.astype(np.int32), dtype=wp.vec3i)
        if out is None:
            out = wp.empty((pts.shape[0], stop - first), dtype=wp.float64)
        wp.launch(
            mvc_kernels.mean_value_coordinates,
            dim=pts.shape[0],
            inputs=[pts, verts, tris, wp.float64(ON_CAGE * cage.diagonal), wp.float64(EPS_PLANE), first],
            outputs=[out],
        )
    return out


def mean_value_coordinates(cage: Cage, points: np.ndarray, device=None) -> np.ndarray:
    """Mean value coordinates (Ju, Schaefer, Warren 2005) of a triangle cage at arbitrary points.

    Parameters
    ----------
    cage : Cage
    points : (N, 3) array, anywhere off the cage (on it, the coordinates are the hat functions)
    device : None | str | Backend

    Returns
    -------
    (N, L) float64, rows sum to one and reproduce the points: ``W @ cage.vertices == points``

    Examples
    --------
    >>> w = mean_value_coordinates(cage, cage.vertices.mean(axis=0)[None])  # doctest: +SKIP
    >>> np.allclose(w @ cage.vertices, cage.vertices.mean(axis=0))  # doctest: +SKIP
    True
    """
    device = Backend.of(device).device
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros((0, len(cage.vertices)))
    centre = 0.5 * (cage.vertices.min(axis=0) + cage.vertices.max(axis=0))
    pts = wp.array(points - centre, dtype=wp.vec3d, device=device)
    return mvc_on_device(cage, centre, pts, slice(None), device).numpy()
