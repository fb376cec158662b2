"""Where a cage can go wrong geometrically: faces that cross (found with a BVH on the device), and edges where it
folds back on itself."""

from __future__ import annotations

import numpy as np

from .topology import bounding_diagonal, interior_edges

__all__ = ["crossing_faces", "unit_normals", "folded_edges", "FOLD_DEGREES"]

#: an edge where the two faces' normals are more than this many degrees apart is folded: the cage folds back on
#: itself there, leaving a wedge of outside (or inside) space thinner than any grid cell near the edge
FOLD_DEGREES = 150.0


def crossing_faces(vertices: np.ndarray, faces: np.ndarray, device=None) -> np.ndarray:
    """Pairs of faces that cross each other (an edge of one passes through the other), found with a BVH.

    Faces that share an edge are not tested (they meet along it); faces that share a corner are, away from it.
    Coplanar overlaps are not detected.

    Parameters
    ----------
    vertices : (L, 3) array
    faces : (F, 3) int array
    device : None | str | Backend, where the test runs (default: CUDA when present, else the CPU)

    Returns
    -------
    (K, 2) int array of face pairs (i < j), ordered by i

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [3, 3, 0]], float)
    >>> crossing_faces(v, np.array([[0, 1, 2], [3, 4, 5]])).tolist()
    [[0, 1]]
    """
    import warp as wp

    from ..device import Backend
    from ..kernels import intersect

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int32)
    if len(faces) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    relative = vertices - centre
    diag = bounding_diagonal(vertices)
    with Backend.of(device).scope():
        mesh = wp.Mesh(points=wp.array(relative.astype(np.float32), dtype=wp.vec3),
                       indices=wp.array(faces.ravel(), dtype=wp.int32))
        first = wp.empty(len(faces), dtype=wp.int32)
        wp.launch(intersect.crossing_faces, dim=len(faces),
                  inputs=[mesh.id, wp.array(relative, dtype=wp.vec3d), wp.array(faces, dtype=wp.vec3i),
                          float(1e-6 * diag), wp.float64(1e-9)], outputs=[first])
        first = first.numpy()
    i = np.flatnonzero(first >= 0)
    return np.column_stack([i, first[i]]).astype(np.int64)


def unit_normals(cage) -> np.ndarray:
    """(F, 3) unit normals of the cage's faces (outward for a checked cage).

    Examples
    --------
    >>> from warp_stokes.geometry.cage import check_cage
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> unit_normals(check_cage((v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])))[0].tolist()
    [0.0, 0.0, -1.0]
    """
    v, f = cage.vertices, cage.faces
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def folded_edges(cage, degrees: float = FOLD_DEGREES, angles: bool = False):
    """The cage's edges where the two faces' normals are more than ``degrees`` apart (the cage folds back there).

    Parameters
    ----------
    cage : Cage
    degrees : float
    angles : bool, also return the angle between the normals at each folded edge

    Returns
    -------
    (E, 2) int64 handle pairs, sorted by handle; with ``angles``, also (E,) degrees

    Examples
    --------
    >>> folded_edges(check_cage("examples/arm/arm_cage.obj")).shape  # doctest: +SKIP
    (4, 2)
    """
    face_a, face_b, edges = interior_edges(cage.faces)
    n = unit_normals(cage)
    angle = np.degrees(np.arccos(np.clip((n[face_a] * n[face_b]).sum(axis=1), -1.0, 1.0)))
    folded = angle > degrees
    edges = np.sort(edges[folded], axis=1)
    return (edges, angle[folded]) if angles else edges


#: vertices of a triangle soup closer than this fraction of the cage's diagonal are one handle
