"""Normals of a deforming polygon mesh, recomputed per frame with the interpolation its asset authors them with.

A stale rest normal on a moving mesh shades it wrongly; a smooth recomputation would round off the asset's hard
edges. So the rest normals decide which corners are smoothed together (corners of one vertex whose rest normals
agree), and every frame's normals are area-weighted sums of its polygons' normals over those groups.
"""

from __future__ import annotations

import numpy as np

__all__ = ["NormalsPlan", "INTERPOLATIONS"]

#: USD interpolations of normals that can be recomputed from the points
INTERPOLATIONS = ("vertex", "varying", "faceVarying", "uniform", "constant")


class NormalsPlan:
    """The fixed part of recomputing a mesh's normals (fan triangles, smoothing groups, gather order), built once
    per mesh; calling it with a frame's points gives that frame's normals.

    Parameters
    ----------
    face_counts, face_indices : int arrays, the polygons (USD ``faceVertexCounts`` / ``faceVertexIndices``)
    interpolation : one of :data:`INTERPOLATIONS`: one normal per point (``vertex``, ``varying``), per polygon
        corner (``faceVarying``), per polygon (``uniform``) or one for the mesh (``constant``)
    n_points : int
    rest_normals : array, optional, for ``faceVarying``: the rest normals per corner; corners of one vertex are
        smoothed together where these agree (hard edges stay hard). Without them, all corners of a vertex are.
    left_handed : bool, the mesh's ``orientation`` is ``leftHanded`` (its polygons wind clockwise)

    Examples
    --------
    >>> plan = NormalsPlan([4], [0, 1, 2, 3], "vertex", 4)
    >>> plan(np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]))[0].tolist()
    [0.0, 0.0, 1.0]
    """

    def __init__(self, face_counts, face_indices, interpolation: str, n_points: int, rest_normals=None,
                 left_handed: bool = False):
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"cannot recompute normals with interpolation {interpolation!r}")
        counts = np.asarray(face_counts, dtype=np.int64)
        corners = np.asarray(face_indices, dtype=np.int64)
        self.interpolation = interpolation
        self.sign = -1.0 if left_handed else 1.0
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        # fan triangles (first, k, k + 1) of every polygon: their cross products sum to the polygon's area normal
        n_fans = np.maximum(counts - 2, 0)
        self.fan_face = np.repeat(np.arange(len(counts)), n_fans)
        k = np.arange(int(n_fans.sum())) - np.repeat(np.cumsum(n_fans) - n_fans, n_fans)
        self.fan = np.stack([corners[first[self.fan_face]], corners[first[self.fan_face] + k + 1],
                             corners[first[self.fan_face] + k + 2]], axis=1)
        self.n_faces = len(counts)
        corner_face = np.repeat(np.arange(len(counts)), counts)
        if interpolation in ("vertex", "varying"):
            groups, n_groups = corners, n_points
        elif interpolation == "faceVarying":
            if rest_normals is not None and len(rest_normals) == len(corners):
                rounded = np.round(np.asarray(rest_normals, dtype=np.float64) * 1e4).astype(np.int64)
                _, groups = np.unique(np.column_stack([corners, rounded]), axis=0, return_inverse=True)
                groups = groups.ravel()
            else:
                _, groups = np.unique(corners, return_inverse=True)
            n_groups = int(groups.max()) + 1 if len(groups) else 0
            self.corner_group = groups
        else:
            groups = n_groups = None
        if groups is not None:
            # a gather then one reduceat per frame: no scattered atomic sums in numpy
            self.order = np.argsort(groups, kind="stable")
            self.order_face = corner_face[self.order]
            sorted_groups = groups[self.order]
            self.starts = np.flatnonzero(np.r_[True, sorted_groups[1:] != sorted_groups[:-1]]) if len(groups) else \
                np.zeros(0, dtype=np.int64)
            self.present = sorted_groups[self.starts]
            self.n_groups = n_groups

    def face_normals(self, points) -> np.ndarray:
        """(F, 3) area-weighted (unnormalised) normals of the polygons."""
        p = np.asarray(points, dtype=np.float64)
        cross = np.cross(p[self.fan[:, 1]] - p[self.fan[:, 0]], p[self.fan[:, 2]] - p[self.fan[:, 0]])
        out = np.zeros((self.n_faces, 3))
        for axis in range(3):
            out[:, axis] = np.bincount(self.fan_face, weights=cross[:, axis], minlength=self.n_faces)
        return self.sign * out

    def __call__(self, points) -> np.ndarray:
        """The normals of the mesh with these points: float32, one per point, corner, polygon, or one in all."""
        faces = self.face_normals(points)
        if self.interpolation == "uniform":
            out = faces
        elif self.interpolation == "constant":
            out = faces.sum(axis=0, keepdims=True)
        else:
            sums = np.zeros((self.n_groups, 3))
            if len(self.starts):
                sums[self.present] = np.add.reduceat(faces[self.order_face], self.starts, axis=0)
            out = sums[self.corner_group] if self.interpolation == "faceVarying" else sums
        length = np.linalg.norm(out, axis=1, keepdims=True)
        return (out / np.where(length > 0, length, 1.0)).astype(np.float32)
