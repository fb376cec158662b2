"""All the quality measures of a set of weights for a cage pose, by region: :func:`deformation_quality`, and the
same for mean value coordinates on the same pair (:func:`mean_value_quality`)."""

from __future__ import annotations

import numpy as np

from ..geometry.cage import Cage, interior_edges
from ..io.load import load_surface
from ..io.poses import pose_vertices
from .compare import vertex_weight_difference
from .coupling import DISTANT_FRACTION, distant_handle_weight, distant_handles
from .measures import (NEGATIVE_TOLERANCE, conformal_distortion, dihedral_change, percentile_summary, region_edges,
                       region_triangles, row_chunks, vertex_mask)

__all__ = ["deformation_quality", "mean_value_quality"]


def _pose(pose, cage: Cage) -> np.ndarray:
    is_mesh = type(pose).__name__ in ("Trimesh", "Surface") or (isinstance(pose, tuple) and len(pose) == 2)
    if isinstance(pose, (str, bytes)) or hasattr(pose, "__fspath__") or is_mesh:
        surface = load_surface(pose)
        return pose_vertices(surface.vertices, surface.faces, cage.faces, cage.source_index, surface.name)
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != cage.vertices.shape:
        raise ValueError(f"a cage pose of shape {pose.shape} does not fit a cage of {cage.n_handles} handles")
    return pose


def deformation_quality(weights, mesh_vertices=None, mesh_faces=None, cage=None, pose=None, reference=None,
                        regions: dict | None = None, device=None, finer=None,
                        fraction: float = DISTANT_FRACTION) -> dict:
    """Every measure of the module for one set of weights and one cage pose, per region.

    Parameters
    ----------
    weights : (V, L) array, e.g. ``binding.weights`` or ``mean_value_coordinates(cage, mesh_vertices)``; or a
        Binding, which supplies the mesh and the cage when they are not given
    mesh_vertices, mesh_faces : the rest mesh
    cage : Cage (or a path / ``(vertices, faces)``, checked with ``check_cage``), the rest cage
    pose : None | (L, 3) deformed cage vertices | a deformed cage with the cage's topology (path or mesh). Without
        a pose only the weight measures are computed.
    reference : None | (V, 3) array | path or mesh: the real mesh in the pose, same vertex order (for the dihedral
        change)
    regions : dict name -> (V,) bool mask or vertex indices, optional; a triangle (edge) belongs to a region when
        all its vertices do. Default: the whole mesh as "all".
    device : None | str, for the nearest-face query
    finer : None | (V, L) array | Binding, weights to compare with (e.g. a finer resolution)
    fraction : float, the distant-handle threshold as a fraction of the cage's graph diameter

    Returns
    -------
    dict: ``vertices``, ``handles``, ``distant_threshold`` (cage units), ``min_weight``, ``negative_fraction``
    (below -:data:`NEGATIVE_TOLERANCE`) and ``regions``: name -> ``vertices``, ``min_weight``,
    ``negative_fraction``, ``distant_weight`` (p50 / p95 / max / mean over its vertices), with a pose
    ``conformal`` (p50 / p95 / max / count over its triangles), with a reference ``dihedral_change`` (unsigned
    angles, degrees, over its interior edges) and ``dihedral_change_signed``, with ``finer`` ``change`` (``max``
    over its vertices and the handles, ``rms`` over its vertices of each one's largest change).

    Examples
    --------
    >>> q = deformation_quality(b.weights, b.mesh_vertices, b.mesh_faces, cage, pose)    # doctest: +SKIP
    >>> q["regions"]["all"]["conformal"]["p95"]                                          # doctest: +SKIP
    1.83
    >>> q = deformation_quality(b, pose="cage_tpose.obj", reference="model_tpose.obj",
    ...                         finer=b_finer)                                            # doctest: +SKIP
    """
    binding = weights if hasattr(weights, "weights") else None
    w = np.asarray(binding.weights if binding is not None else weights)
    if binding is not None:
        mesh_vertices = binding.mesh_vertices if mesh_vertices is None else mesh_vertices
        mesh_faces = binding.mesh_faces if mesh_faces is None else mesh_faces
        if cage is None:
            cage = Cage(binding.cage_vertices, binding.cage_faces, "<binding>",
                        source_index=getattr(binding, "cage_source_index", None))
    if mesh_vertices is None or mesh_faces is None or cage is None:
        raise ValueError("deformation_quality needs the mesh and the cage (or a Binding)")
    if not isinstance(cage, Cage):
        from ..geometry.cage import check_cage

        cage = check_cage(cage)
    vertices = np.asarray(mesh_vertices, dtype=np.float64)
    faces = np.asarray(mesh_faces, dtype=np.int64)
    if w.shape != (len(vertices), cage.n_handles):
        raise ValueError(f"weights of shape {w.shape} do not fit {len(vertices)} vertices and {cage.n_handles} handles")
    n_vertices, n_handles = w.shape
    masks = {name: vertex_mask(region, n_vertices)
             for name, region in (regions or {"all": np.ones(n_vertices, dtype=bool)}).items()}

    conformal = dihedral = signed = edges = None
    if pose is not None:
        conformal, dihedral, signed, edges = _pose_measures(w, vertices, faces, _pose(pose, cage), reference)

    # per-vertex weight statistics, one pass over the weights
    smallest = np.empty(n_vertices)
    negatives = np.empty(n_vertices, dtype=np.int64)
    for rows in row_chunks(n_vertices, n_handles):
        smallest[rows] = w[rows].min(axis=1, initial=np.inf)
        negatives[rows] = np.count_nonzero(w[rows] < -NEGATIVE_TOLERANCE, axis=1)
    distant = distant_handle_weight(w, cage, vertices, fraction, device)
    change = None if finer is None else vertex_weight_difference(w, finer)[0]

    out = {"vertices": n_vertices, "handles": n_handles, "distant_threshold": distant_handles(cage, fraction)[1],
           "min_weight": float(smallest.min(initial=np.inf)),
           "negative_fraction": float(negatives.sum() / max(1, w.size)), "regions": {}}
    for name, mask in masks.items():
        out["regions"][name] = _region_row(mask, smallest, negatives, distant, change, conformal, dihedral, signed,
                                           edges, faces, n_handles)
    return out


def mean_value_quality(mesh_vertices, mesh_faces, cage, pose=None, reference=None, regions: dict | None = None,
                       device=None, finer=None, fraction: float = DISTANT_FRACTION) -> dict:
    """:func:`deformation_quality` of mean value coordinates evaluated at the mesh's vertices: the reference method.

    Parameters
    ----------
    mesh_vertices, mesh_faces, cage, pose, reference, regions, device, finer, fraction
        As for :func:`deformation_quality`; ``device`` also evaluates the coordinates.

    Returns
    -------
    dict, as :func:`deformation_quality`, with ``weights``: the (V, L) float64 coordinates

    Examples
    --------
    >>> s = ws.load_surface("model_rpose.obj")                                                     # doctest: +SKIP
    >>> q = mean_value_quality(s.vertices, s.faces, ws.check_cage("cage_rpose.obj"), "cage_tpose.obj",
    ...                        "model_tpose.obj")                                                  # doctest: +SKIP
    >>> q["regions"]["all"]["conformal"]["p95"], q["regions"]["all"]["dihedral_change"]["p95"]  # doctest: +SKIP
    (1.647, 10.0)
    """
    from ..geometry.boundary import mean_value_coordinates

    if not isinstance(cage, Cage):
        from ..geometry.cage import check_cage

        cage = check_cage(cage)
    weights = mean_value_coordinates(cage, mesh_vertices, device=device)
    out = deformation_quality(weights, mesh_vertices, mesh_faces, cage, pose, reference, regions, device, finer,
                              fraction)
    out["weights"] = weights
    return out


def _pose_measures(w, vertices, faces, pose: np.ndarray, reference):
    """(conformal distortion per triangle, dihedral change per interior edge, its signed form, the interior edges)
    of the mesh deformed by ``w @ pose``; the last three None without a reference mesh."""
    n_vertices, n_handles = w.shape
    deformed = np.empty((n_vertices, 3))
    for rows in row_chunks(n_vertices, n_handles):
        deformed[rows] = w[rows].astype(np.float64) @ pose
    conformal = conformal_distortion(faces, vertices, deformed)
    if reference is None:
        return conformal, None, None, None
    reference = np.asarray(reference, dtype=np.float64) if isinstance(reference, np.ndarray) else \
        load_surface(reference).vertices
    if reference.shape != vertices.shape:
        raise ValueError(f"the reference mesh has {len(reference)} vertices, the mesh {n_vertices}")
    edges = interior_edges(faces)
    return (conformal, dihedral_change(faces, deformed, reference, edges),
            dihedral_change(faces, deformed, reference, edges, signed=True), edges)


def _region_row(mask, smallest, negatives, distant, change, conformal, dihedral, signed, edges, faces,
                n_handles: int) -> dict:
    """The measures of one region (a vertex mask; its triangles and edges are those with every vertex in it)."""
    n_vertices, count = len(mask), int(mask.sum())
    row = {"vertices": count,
           "min_weight": float(smallest[mask].min(initial=np.inf)) if count else float("nan"),
           "negative_fraction": float(negatives[mask].sum() / (count * n_handles)) if count else float("nan"),
           "distant_weight": {**{k: v for k, v in percentile_summary(distant[mask]).items() if k != "count"},
                              "mean": float(distant[mask].mean()) if count else float("nan")}}
    if conformal is not None:
        row["conformal"] = percentile_summary(conformal, region_triangles(faces, mask, n_vertices))
    if dihedral is not None:
        in_region = region_edges(edges[2], mask, n_vertices)
        row["dihedral_change"] = percentile_summary(dihedral, in_region)
        row["dihedral_change_signed"] = percentile_summary(signed, in_region)
    if change is not None:
        row["change"] = {"max": float(change[mask].max(initial=0.0)),
                         "rms": float(np.sqrt(np.mean(change[mask] ** 2))) if count else float("nan")}
    return row
