"""Coupling across narrow gaps: the weight a vertex takes from handles far away along the cage's edges."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..kernels import voxel
from ..device import Backend
from ..geometry.cage import Cage
from .measures import row_chunks

__all__ = ["DISTANT_FRACTION", "nearest_faces", "distant_handles", "distant_handle_weight"]

#: a handle is distant from a point when it is farther along the cage's edges from the nearest corner of the point's
#: nearest cage face than this fraction of the cage's graph diameter (the longest shortest path between two handles)
DISTANT_FRACTION = 0.25


def nearest_faces(cage: Cage, points: np.ndarray, device=None) -> np.ndarray:
    """(N,) index of the cage face nearest to each point (Warp's BVH query, float32)."""
    from ..geometry.inside import cage_mesh

    backend = Backend.of(device)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (cage.vertices.min(axis=0) + cage.vertices.max(axis=0))
    with backend.scope():
        mesh = cage_mesh(cage, centre, backend.device)
        out = wp.empty(len(points), dtype=wp.int32)
        wp.launch(voxel.nearest_faces, dim=len(points),
                  inputs=[mesh.id, wp.array((points - centre).astype(np.float32), dtype=wp.vec3)], outputs=[out])
        return out.numpy().astype(np.int64)


def distant_handles(cage: Cage, fraction: float = DISTANT_FRACTION) -> tuple[np.ndarray, float]:
    """Which handles are distant from each cage face along the cage.

    Handle l's distance from face f is the shortest path along the cage's edges (weighted by their lengths) from the
    nearest of f's three corners; l is distant from f when that exceeds ``fraction`` of the cage's graph diameter
    (the longest of these paths between two handles).

    Parameters
    ----------
    cage : Cage
    fraction : float in [0, 1]

    Returns
    -------
    distant : (T, L) bool
    threshold : float, the distance beyond which a handle is distant, in the cage's units

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> tetrahedron = Cage(v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]), "tetrahedron")
    >>> distant, threshold = distant_handles(tetrahedron, 0.5)    # diameter sqrt(2); each face misses one handle,
    >>> distant.astype(int).tolist(), round(threshold, 4)       # 1 or sqrt(2) from the face's nearest corner
    ([[0, 0, 0, 1], [0, 0, 1, 0], [0, 1, 0, 0], [1, 0, 0, 0]], 0.7071)
    """
    from ..geometry.local_data import cage_graph_distances

    graph = cage_graph_distances(cage)
    threshold = float(fraction * graph.max())
    return graph[cage.faces].min(axis=1) > threshold, threshold


def distant_handle_weight(weights: np.ndarray, cage: Cage, points: np.ndarray, fraction: float = DISTANT_FRACTION,
                          device=None) -> np.ndarray:
    """Per point, the sum of |w_l| over the handles distant along the cage from the point's nearest cage face.

    Smooth local weights put little on handles far away along the cage; where two parts are close in space but far
    apart along it (a hand beside a thigh), a method that couples them gives one part's vertices weight on the other
    part's handles. See :func:`distant_handles` for the threshold.

    Parameters
    ----------
    weights : (N, L)
    cage : Cage, the rest cage
    points : (N, 3), where the weights were evaluated (the rest mesh's vertices)
    fraction : float, of the cage's graph diameter
    device : None | str, for the nearest-face query

    Returns
    -------
    (N,) float64, >= 0

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> tetrahedron = Cage(v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]), "tetrahedron")
    >>> w = np.full((1, 4), 0.25)               # the point's nearest face is 0 (z = 0), handle 3 distant from it
    >>> distant_handle_weight(w, tetrahedron, [[0.1, 0.1, 0.05]], 0.5, device="cpu").tolist()
    [0.25]
    >>> distant_handle_weight(w, tetrahedron, [[0.1, 0.1, 0.05]], 0.75, device="cpu").tolist()
    [0.0]
    """
    weights = np.asarray(weights)
    distant, _ = distant_handles(cage, fraction)
    face = nearest_faces(cage, points, device)
    out = np.empty(len(weights))
    for rows in row_chunks(*weights.shape):
        out[rows] = (np.abs(weights[rows].astype(np.float64)) * distant[face[rows]]).sum(axis=1)
    return out
