"""Topology and extent of triangle meshes: directed and interior edges, closedness, merging a triangle soup, and
the bounding-box diagonal that tolerances are relative to."""

from __future__ import annotations

import numpy as np

__all__ = ["face_edges", "interior_edges", "is_closed", "merge_coincident", "bounding_diagonal", "MERGE_TOLERANCE"]

#: vertices of a triangle soup closer than this fraction of the cage's diagonal are one handle
MERGE_TOLERANCE = 1e-6


def bounding_diagonal(points) -> float:
    """The length of the bounding box's diagonal: the scale that the package's tolerances and errors are relative to.

    Examples
    --------
    >>> bounding_diagonal([[0, 0, 0], [3, 4, 0]])
    5.0
    """
    points = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def is_closed(faces: np.ndarray) -> bool:
    """Whether every undirected edge is shared by exactly two faces."""
    key = np.sort(face_edges(faces), axis=1)
    return bool((np.unique(key, axis=0, return_counts=True)[1] == 2).all())


def merge_coincident(vertices: np.ndarray, faces: np.ndarray, tolerance: float):
    """Merge vertices closer than ``tolerance``: each becomes the first vertex (in source order) near it.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int
    tolerance : float, absolute

    Returns
    -------
    merged_vertices : (L, 3), the distinct vertices in order of first appearance
    merged_faces : (F, 3) int64
    source_index : (V,) int64, the merged vertex of each source vertex

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    >>> merge_coincident(v, np.array([[0, 1, 2], [3, 5, 4]]), 1e-9)[2].tolist()
    [0, 1, 2, 1, 2, 3]
    """
    v = np.asarray(vertices, dtype=np.float64)
    if len(v) <= 20000:
        # every pair (a cage's soup has a few thousand vertices): the first vertex near each one represents it
        first = np.empty(len(v), dtype=np.int64)
        for start in range(0, len(v), 2048):
            block = v[start : start + 2048]
            near = np.linalg.norm(block[:, None, :] - v[None, :, :], axis=2) <= tolerance
            first[start : start + len(block)] = np.argmax(near, axis=1)
        first = first[first]  # a representative that is itself represented by an earlier one
    else:  # too many for all pairs: bit-identical positions only
        _, first_of, inverse = np.unique(v, axis=0, return_index=True, return_inverse=True)
        first = first_of[inverse.ravel()]
    representatives, source_index = np.unique(first, return_inverse=True)  # sorted: order of first appearance
    return v[representatives], source_index.ravel()[np.asarray(faces, dtype=np.int64)], source_index.ravel()


def face_edges(faces: np.ndarray) -> np.ndarray:
    """(3F, 2) the triangles' directed edges: every face's (0, 1), then every face's (1, 2), then (2, 0).

    Examples
    --------
    >>> face_edges(np.array([[0, 1, 2]])).tolist()
    [[0, 1], [1, 2], [2, 0]]
    """
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def interior_edges(faces: np.ndarray):
    """The edges shared by exactly two triangles (edges of one face, or of three or more, are left out).

    Parameters
    ----------
    faces : (F, 3) int array

    Returns
    -------
    face_a, face_b : (E,) int64, the two triangles
    edges : (E, 2) int64, the edge's vertices in the order ``face_a`` traverses them

    Examples
    --------
    >>> a, b, e = interior_edges(np.array([[0, 1, 2], [2, 1, 3]]))
    >>> a.tolist(), b.tolist(), e.tolist()
    ([0], [1], [[1, 2]])
    """
    faces = np.asarray(faces, dtype=np.int64)
    directed = face_edges(faces)
    owner = np.tile(np.arange(len(faces), dtype=np.int64), 3)
    key = np.sort(directed, axis=1)
    order = np.lexsort((owner, key[:, 1], key[:, 0]))
    key, directed, owner = key[order], directed[order], owner[order]
    start = np.flatnonzero(np.r_[True, (key[1:] != key[:-1]).any(axis=1)])
    two = start[np.diff(np.r_[start, len(key)]) == 2]
    return owner[two], owner[two + 1], directed[two]
