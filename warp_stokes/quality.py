"""Deformation quality of a binding: what a deformed mesh looks like, not only whether the weights are exact.

Partition of unity and linear precision say nothing about folds or stretched fingers. These measures judge the
deformation a set of weights gives for a cage pose, beside a reference method (mean value coordinates evaluated at
the vertices, ``warp_stokes.mean_value_coordinates``) on the same pair:

- conformal distortion per triangle: sigma1 / sigma2 of the linear map of the rest triangle onto the deformed one
  (1 for a similarity; the angles a texture keeps);
- dihedral-angle change per interior edge against a reference mesh in the deformed pose, where there is one;
- negative weights and the smallest weight;
- the weight held by distant handles: per vertex, the sum of |w_l| over the handles farther along the cage's edges
  from the vertex's nearest cage face than a fraction of the cage's graph diameter (coupling across narrow gaps);
- the change of the weights against another binding (e.g. a finer resolution).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .cage import Cage
from .device import resolve_device
from .kernels import voxel

__all__ = ["conformal_distortion", "interior_edges", "dihedral_angles", "dihedral_change", "nearest_faces",
           "distant_handle_weight", "weight_difference", "deformation_quality", "DISTANT_FRACTION"]

#: handles farther along the cage than this fraction of its graph diameter from a vertex's nearest face are distant
DISTANT_FRACTION = 0.25


def conformal_distortion(faces: np.ndarray, rest: np.ndarray, deformed: np.ndarray) -> np.ndarray:
    """Per triangle sigma1 / sigma2 of the linear map rest -> deformed (NaN for a degenerate rest triangle).

    Examples
    --------
    >>> f = np.array([[0, 1, 2]]); p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    >>> conformal_distortion(f, p, 3 * p).tolist(), conformal_distortion(f, p, p * [2, 1, 1]).tolist()
    ([1.0], [2.0])
    """
    faces = np.asarray(faces)
    e1, e2 = rest[faces[:, 1]] - rest[faces[:, 0]], rest[faces[:, 2]] - rest[faces[:, 0]]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
        n = np.cross(e1, e2)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        v = np.cross(n, u)
        a = np.stack([np.stack([(e1 * u).sum(1), (e2 * u).sum(1)], 1), np.stack([(e1 * v).sum(1), (e2 * v).sum(1)], 1)],
                     1)  # the rest triangle's edges in its own plane
        b = np.stack([deformed[faces[:, 1]] - deformed[faces[:, 0]], deformed[faces[:, 2]] - deformed[faces[:, 0]]], 2)
        ok = np.isfinite(a).all(axis=(1, 2)) & (np.abs(np.linalg.det(np.nan_to_num(a))) > 0)
        s = np.full((len(faces), 2), np.nan)
        s[ok] = np.linalg.svd(b[ok] @ np.linalg.inv(a[ok]), compute_uv=False)
        return s[:, 0] / s[:, 1]


def interior_edges(faces: np.ndarray):
    """(face a, face b, (E, 2) vertex pairs) for every edge shared by two faces.

    Examples
    --------
    >>> interior_edges(np.array([[0, 1, 2], [2, 1, 3]]))[2].tolist()
    [[1, 2]]
    """
    faces = np.asarray(faces)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    face = np.tile(np.arange(len(faces)), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort(key.T[::-1])
    key, face = key[order], face[order]
    same = (key[1:] == key[:-1]).all(axis=1)
    return face[:-1][same], face[1:][same], key[:-1][same]


def dihedral_angles(faces: np.ndarray, points: np.ndarray, edges=None) -> np.ndarray:
    """Angle between the two faces' normals at every interior edge (degrees; 0 where the surface is flat)."""
    fa, fb, _ = interior_edges(faces) if edges is None else edges
    n = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    with np.errstate(invalid="ignore", divide="ignore"):
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    # atan2 of the sine and cosine: accurate near 0 and 180 degrees, unlike arccos of the cosine
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(n[fa], n[fb]), axis=1), (n[fa] * n[fb]).sum(axis=1)))


def dihedral_change(faces: np.ndarray, deformed: np.ndarray, reference: np.ndarray, edges=None) -> np.ndarray:
    """|dihedral angle of the deformed mesh - that of the reference mesh| at every interior edge, in degrees.

    Examples
    --------
    >>> f = np.array([[0, 1, 2], [2, 1, 3]]); p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    >>> q = p.copy(); q[3, 2] = 1.0
    >>> bool(dihedral_change(f, q, p)[0] > 40)
    True
    """
    edges = interior_edges(faces) if edges is None else edges
    return np.abs(dihedral_angles(faces, deformed, edges) - dihedral_angles(faces, reference, edges))


def nearest_faces(cage: Cage, points: np.ndarray, device=None) -> np.ndarray:
    """(N,) index of the cage face nearest to each point (Warp's BVH query, float32)."""
    from .grid import _cage_mesh

    device = resolve_device(device)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (cage.vertices.min(axis=0) + cage.vertices.max(axis=0))
    with wp.ScopedDevice(device):
        mesh = _cage_mesh(cage, centre, device)
        out = wp.empty(len(points), dtype=wp.int32)
        wp.launch(voxel.nearest_faces, dim=len(points),
                  inputs=[mesh.id, wp.array((points - centre).astype(np.float32), dtype=wp.vec3)], outputs=[out])
        return out.numpy().astype(np.int64)


def distant_handle_weight(weights: np.ndarray, cage: Cage, points: np.ndarray, fraction: float = DISTANT_FRACTION,
                          device=None) -> np.ndarray:
    """Per point, the sum of |w_l| over the handles farther along the cage than ``fraction`` of its graph diameter
    from the point's nearest cage face (the distance from the face's nearest corner, along the cage's edges).

    Parameters
    ----------
    weights : (N, L)
    cage : Cage
    points : (N, 3), where the weights were evaluated (the rest mesh's vertices)
    fraction : float
    device : None | str

    Returns
    -------
    (N,) float64

    Examples
    --------
    >>> share = distant_handle_weight(b.weights, cage, b.mesh_vertices)   # doctest: +SKIP
    """
    from .local_boundary import cage_graph_distances

    graph = cage_graph_distances(cage)
    far = graph[cage.faces].min(axis=1) > fraction * graph.max()  # (F, L)
    return (np.abs(weights) * far[nearest_faces(cage, points, device)]).sum(axis=1)


def weight_difference(a: np.ndarray, b: np.ndarray) -> dict:
    """Max and RMS over vertices of the largest per-vertex weight change between two weight sets (V, L).

    Examples
    --------
    >>> weight_difference(np.eye(2), np.eye(2))
    {'max': 0.0, 'rms': 0.0}
    """
    per_vertex = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).max(axis=1)
    return {"max": float(per_vertex.max()), "rms": float(np.sqrt(np.mean(per_vertex**2)))}


def _summary(values: np.ndarray) -> dict:
    values = values[np.isfinite(values)]
    return {"p50": float(np.percentile(values, 50)), "p95": float(np.percentile(values, 95)), "max": float(values.max())}


def deformation_quality(weights: np.ndarray, mesh_vertices: np.ndarray, mesh_faces: np.ndarray, cage: Cage,
                        pose: np.ndarray, reference: np.ndarray | None = None, regions: dict | None = None,
                        device=None) -> dict:
    """Every measure of the module for one set of weights and one cage pose, per region.

    Parameters
    ----------
    weights : (V, L), e.g. ``binding.weights`` or ``mean_value_coordinates(cage, mesh_vertices)``
    mesh_vertices, mesh_faces : the rest mesh
    cage : Cage, the rest cage
    pose : (L, 3) deformed cage vertices
    reference : (V, 3), optional, the mesh as it should look in the pose (for the dihedral change)
    regions : dict name -> (V,) bool, optional; a triangle (edge) belongs to a region when all its vertices do.
        Default: the whole mesh as "all".
    device : None | str

    Returns
    -------
    dict: ``min_weight``, ``negative_fraction`` and per region ``conformal`` (p50/p95/max over triangles),
    ``distant_weight`` (p50/p95/max over vertices) and, with a reference, ``dihedral_change`` (p50/p95/max,
    degrees).

    Examples
    --------
    >>> q = deformation_quality(b.weights, b.mesh_vertices, b.mesh_faces, cage, pose)    # doctest: +SKIP
    >>> q["regions"]["all"]["conformal"]["p95"]                                          # doctest: +SKIP
    1.83
    """
    weights = np.asarray(weights, dtype=np.float64)
    mesh_faces = np.asarray(mesh_faces)
    deformed = weights @ np.asarray(pose, dtype=np.float64)
    conformal = conformal_distortion(mesh_faces, mesh_vertices, deformed)
    edges = interior_edges(mesh_faces)
    dihedral = None if reference is None else dihedral_change(mesh_faces, deformed, reference, edges)
    regions = regions or {"all": np.ones(len(mesh_vertices), dtype=bool)}
    distant = distant_handle_weight(weights, cage, mesh_vertices, device=device)
    out = {"min_weight": float(weights.min()), "negative_fraction": float((weights < 0).mean()), "regions": {}}
    for name, mask in regions.items():
        mask = np.asarray(mask, dtype=bool)
        row = {"conformal": _summary(conformal[mask[mesh_faces].all(axis=1)]), "distant_weight": _summary(distant[mask])}
        if dihedral is not None:
            row["dihedral_change"] = _summary(dihedral[mask[edges[2]].all(axis=1)])
        out["regions"][name] = row
    return out
