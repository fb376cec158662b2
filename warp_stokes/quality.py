"""Deformation quality of a binding: what a deformed mesh looks like, not only whether the weights are exact.

Partition of unity and linear precision say nothing about folds, stretched fingers or a hand that follows the
thigh. These measures judge the deformation a set of weights gives for a cage pose, beside a reference method (mean
value coordinates evaluated at the vertices, :func:`mean_value_quality`) on the same pair:

- **conformal distortion** per triangle of the map rest mesh -> deformed mesh: sigma1 / sigma2, the ratio of the
  singular values of the triangle's 2D deformation gradient (1 for a similarity, >= 1 always; the angles a
  texture keeps);
- **dihedral-angle change** per interior edge against a reference mesh in the deformed pose, where there is one:
  |dihedral(deformed) - dihedral(reference)| in degrees, of the unsigned angles between the faces' normals (issue
  19's figures) and of the signed ones (a bend from convex to concave counts whole);
- **negative weights**: the fraction of the (vertex, handle) weights below -1e-5 (:data:`NEGATIVE_TOLERANCE`: the
  float32 noise around zero of far handles does not count), and the smallest weight;
- **distant-handle weight** per vertex: the sum of |w_l| over the handles farther along the cage's edges from the
  vertex's nearest cage face than a quarter (:data:`DISTANT_FRACTION`) of the cage's graph diameter. Weight there is
  coupling across a narrow gap between parts that are close in space but far apart along the cage (a hand hanging
  beside a thigh);
- **weight difference** against another binding of the same mesh and cage (per vertex, the largest and the RMS
  change over handles), e.g. a finer resolution.

:func:`deformation_quality` computes all of them by region (vertex subsets: a region's triangles and edges are those
with every vertex in it). Weights are read in chunks of rows and all sums are float64, so meshes of 500k vertices
need no (V, L) float64 copy. Regions specific to a data set (SMPL's hands) belong to the caller, e.g.
``benchmarks/bench_quality.py``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .geometry.cage import Cage, interior_edges
from .io.poses import pose_vertices
from .device import resolve_device
from .kernels import voxel
from .io.load import load_surface

__all__ = ["conformal_distortion", "interior_edges", "dihedral_angles", "dihedral_change", "percentile_summary",
           "region_triangles", "region_edges", "negative_weight_fraction", "nearest_faces", "distant_handles",
           "distant_handle_weight", "vertex_weight_difference", "weight_difference", "deformation_quality",
           "mean_value_quality", "DISTANT_FRACTION", "NEGATIVE_TOLERANCE"]

#: a handle is distant from a point when it is farther along the cage's edges from the nearest corner of the point's
#: nearest cage face than this fraction of the cage's graph diameter (the longest shortest path between two handles)
DISTANT_FRACTION = 0.25

#: weights in [-NEGATIVE_TOLERANCE, 0) count as zero, not negative: a float32 solve (its partition-of-unity check is
#: 1e-5) leaves the weights of handles far away at +-1e-7..1e-5 (on SMPL at n = 32 with the local data, a third of
#: the weights are within 1e-6 of zero and half of those below it)
NEGATIVE_TOLERANCE = 1e-5

#: entries of a (V, L) weight matrix read at once (rows per chunk = this / L)
_CHUNK_ENTRIES = 1 << 20


def _row_chunks(n_rows: int, n_columns: int):
    step = max(1, _CHUNK_ENTRIES // max(1, n_columns))
    for start in range(0, n_rows, step):
        yield slice(start, min(n_rows, start + step))


def conformal_distortion(faces: np.ndarray, rest: np.ndarray, deformed: np.ndarray) -> np.ndarray:
    """Per triangle, sigma1 / sigma2 of the linear map of the rest triangle onto the deformed one.

    The map's 2D deformation gradient J (3 x 2, from the rest triangle's plane) has singular values
    sigma1 >= sigma2; their ratio K is 1 for a similarity and grows with anisotropic stretch. It is computed without
    a frame or an SVD from the edge vectors (e1, e2 at rest, f1, f2 deformed):
    ``q = (|e2|^2 |f1|^2 - 2 (e1.e2)(f1.f2) + |e1|^2 |f2|^2) / (|e1 x e2| |f1 x f2|)`` is the trace of J^T J (in the
    rest metric) over the square root of its determinant, K + 1/K, so ``K = q/2 + sqrt(q^2/4 - 1)``. (The symmetric
    measure (sigma1^2 + sigma2^2) / (2 sigma1 sigma2) would be q / 2; issue 19's figures are sigma1 / sigma2.)

    Parameters
    ----------
    faces : (F, 3) int array
    rest, deformed : (V, 3) arrays, the same vertices at rest and deformed

    Returns
    -------
    (F,) float64, >= 1; NaN for a triangle degenerate at rest, inf for one the deformation collapses

    Examples
    --------
    >>> f = np.array([[0, 1, 2]]); p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    >>> conformal_distortion(f, p, 3 * p).tolist(), conformal_distortion(f, p, p * [2, 1, 1]).tolist()
    ([1.0], [2.0])
    >>> shear = p + p[:, 1:2] * [1, 0, 0]      # (x, y) -> (x + y, y): the golden ratio squared
    >>> round(float(conformal_distortion(f, p, shear)[0]), 6)
    2.618034
    """
    faces = np.asarray(faces, dtype=np.int64)
    rest, deformed = np.asarray(rest, dtype=np.float64), np.asarray(deformed, dtype=np.float64)
    e1, e2 = rest[faces[:, 1]] - rest[faces[:, 0]], rest[faces[:, 2]] - rest[faces[:, 0]]
    f1, f2 = deformed[faces[:, 1]] - deformed[faces[:, 0]], deformed[faces[:, 2]] - deformed[faces[:, 0]]
    trace = ((e2 * e2).sum(1) * (f1 * f1).sum(1) - 2.0 * (e1 * e2).sum(1) * (f1 * f2).sum(1)
             + (e1 * e1).sum(1) * (f2 * f2).sum(1))
    area_rest = np.linalg.norm(np.cross(e1, e2), axis=1)
    area_deformed = np.linalg.norm(np.cross(f1, f2), axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        half = 0.5 * trace / (area_rest * area_deformed)
        ratio = half + np.sqrt(np.maximum(half * half - 1.0, 0.0))
    ratio[(area_rest > 0) & (area_deformed == 0)] = np.inf
    ratio[area_rest == 0] = np.nan
    return np.maximum(ratio, 1.0, where=np.isfinite(ratio), out=ratio)


def dihedral_angles(faces: np.ndarray, points: np.ndarray, edges=None, signed: bool = False) -> np.ndarray:
    """The angle between the two triangles' normals at every interior edge, in degrees (0 where it is flat).

    Parameters
    ----------
    faces : (F, 3) int array
    points : (V, 3) array
    edges : the output of :func:`interior_edges` for ``faces``, to reuse it
    signed : bool. Unsigned (default), the angle is in [0, 180] for convex and concave bends alike. Signed, it is
        positive where the surface bends away from the normals' side (convex, for outward faces) and negative
        where it bends towards it; a second face that traverses the edge the same way as the first (inconsistent
        orientation) is measured as if it were flipped.

    Returns
    -------
    (E,) float64, in the order of :func:`interior_edges`; NaN where a triangle is degenerate

    Examples
    --------
    >>> p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> tetrahedron = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])   # outward: convex everywhere
    >>> np.round(dihedral_angles(tetrahedron, p), 3).tolist()                  # 180 - the interior angle
    [90.0, 90.0, 90.0, 125.264, 125.264, 125.264]
    >>> np.round(dihedral_angles(tetrahedron[:, ::-1], p, signed=True), 3).tolist()
    [-90.0, -90.0, -90.0, -125.264, -125.264, -125.264]
    """
    faces = np.asarray(faces, dtype=np.int64)
    points = np.asarray(points, dtype=np.float64)
    fa, fb, edge = interior_edges(faces) if edges is None else edges
    n = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    with np.errstate(invalid="ignore", divide="ignore"):
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    na, nb = n[fa], n[fb]
    cross = np.cross(na, nb)
    if not signed:
        # atan2 of the sine and cosine: accurate near 0 and 180 degrees, unlike arccos of the cosine
        return np.degrees(np.arctan2(np.linalg.norm(cross, axis=1), (na * nb).sum(axis=1)))
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = points[edge[:, 1]] - points[edge[:, 0]]
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    second = faces[fb]
    same_way = np.zeros(len(fb), dtype=bool)  # face b traverses the edge as face a does: inconsistent orientation
    for k in range(3):
        same_way |= (second[:, k] == edge[:, 0]) & (second[:, (k + 1) % 3] == edge[:, 1])
    sine = np.where(same_way, -1.0, 1.0) * (cross * axis).sum(axis=1)
    cosine = np.where(same_way, -1.0, 1.0) * (na * nb).sum(axis=1)
    return np.degrees(np.arctan2(sine, cosine))


def dihedral_change(faces: np.ndarray, deformed: np.ndarray, reference: np.ndarray, edges=None,
                    signed: bool = False) -> np.ndarray:
    """|dihedral angle of the deformed mesh - that of the reference mesh| at every interior edge, in degrees.

    Parameters
    ----------
    faces : (F, 3) int array, shared by both meshes
    deformed, reference : (V, 3) arrays, the deformed mesh and the real mesh in the same pose
    edges : the output of :func:`interior_edges`, to reuse it
    signed : bool, compare signed angles (see :func:`dihedral_angles`; wrapped to the shorter way round) instead
        of the unsigned ones. The unsigned change misses the part of a change that passes through flat.

    Returns
    -------
    (E,) float64 in [0, 180]

    Examples
    --------
    >>> f = np.array([[0, 1, 2], [2, 1, 3]]); p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    >>> up, down = p.copy(), p.copy(); up[3, 2], down[3, 2] = 0.1, -0.1   # bent 8 degrees either way
    >>> np.round(dihedral_change(f, up, p), 2).tolist(), np.round(dihedral_change(f, up, down), 2).tolist()
    ([8.05], [0.0])
    >>> np.round(dihedral_change(f, up, down, signed=True), 2).tolist()    # convex to concave: the whole swing
    [16.1]
    """
    edges = interior_edges(faces) if edges is None else edges
    d = dihedral_angles(faces, deformed, edges, signed) - dihedral_angles(faces, reference, edges, signed)
    return np.abs((d + 180.0) % 360.0 - 180.0) if signed else np.abs(d)


def percentile_summary(values: np.ndarray, where=None) -> dict:
    """p50, p95 and max of per-element values (per triangle, edge or vertex), over a subset.

    NaN entries (undefined: triangles degenerate at rest) are left out; inf entries (collapsed triangles) are larger
    than any finite value, and a percentile that interpolates towards one is inf. Percentiles interpolate linearly
    (numpy's default).

    Parameters
    ----------
    values : (N,) array
    where : None | (N,) bool mask | index array, the subset (all by default)

    Returns
    -------
    dict: ``p50``, ``p95``, ``max`` (floats; NaN for an empty subset), ``count`` (the entries used)

    Examples
    --------
    >>> percentile_summary(np.arange(101.0))
    {'p50': 50.0, 'p95': 95.0, 'max': 100.0, 'count': 101}
    >>> percentile_summary(np.array([1.0, 2.0, np.nan, np.inf]), where=np.array([True, True, True, False]))
    {'p50': 1.5, 'p95': 1.95, 'max': 2.0, 'count': 2}
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[~np.isnan(v)] if where is None else v[where][~np.isnan(v[where])]
    if len(v) == 0:
        return {"p50": float("nan"), "p95": float("nan"), "max": float("nan"), "count": 0}
    finite = v[np.isfinite(v)]
    # np.percentile interpolates inf - inf into NaN: stand in the largest float, and call inf what exceeds every
    # finite entry (some part of an inf went into it)
    p = np.percentile(np.minimum(v, np.finfo(np.float64).max), [50, 95])
    p = np.where(p > (finite.max() if len(finite) else -np.inf), np.inf, p)
    return {"p50": float(p[0]), "p95": float(p[1]), "max": float(v.max()), "count": int(len(v))}


def _vertex_mask(region, n_vertices: int) -> np.ndarray:
    region = np.asarray(region)
    if region.dtype == bool:
        if region.shape != (n_vertices,):
            raise ValueError(f"a region mask needs one entry per vertex ({n_vertices}), got shape {region.shape}")
        return region
    mask = np.zeros(n_vertices, dtype=bool)
    mask[region.astype(np.int64)] = True
    return mask


def region_triangles(faces: np.ndarray, region, n_vertices: int) -> np.ndarray:
    """(F,) bool: the triangles whose three vertices lie in ``region`` ((V,) bool mask or vertex indices).

    Examples
    --------
    >>> region_triangles(np.array([[0, 1, 2], [1, 2, 3]]), [0, 1, 2], 4).tolist()
    [True, False]
    """
    return _vertex_mask(region, n_vertices)[np.asarray(faces, dtype=np.int64)].all(axis=1)


def region_edges(edges: np.ndarray, region, n_vertices: int) -> np.ndarray:
    """(E,) bool: the edges (``interior_edges(...)[2]``) whose two vertices lie in ``region``.

    Examples
    --------
    >>> region_edges(np.array([[0, 1], [1, 3]]), [0, 1, 2], 4).tolist()
    [True, False]
    """
    return _vertex_mask(region, n_vertices)[np.asarray(edges, dtype=np.int64)].all(axis=1)


def negative_weight_fraction(weights: np.ndarray, tolerance: float = NEGATIVE_TOLERANCE) -> float:
    """The fraction of the (vertex, handle) weights below ``-tolerance``: the negative ones.

    Parameters
    ----------
    weights : (V, L) array
    tolerance : float >= 0; weights in [-tolerance, 0) count as zero (default :data:`NEGATIVE_TOLERANCE`, float32
        noise); 0 counts every weight below zero

    Returns
    -------
    float in [0, 1]

    Examples
    --------
    >>> w = np.array([[0.5, 0.6, -0.1], [0.5, 0.5, -1e-7]])           # rows sum to one
    >>> negative_weight_fraction(w), negative_weight_fraction(w, tolerance=0.0)
    (0.16666666666666666, 0.3333333333333333)
    """
    weights = np.asarray(weights)
    count = sum(int(np.count_nonzero(weights[rows] < -tolerance)) for rows in _row_chunks(*weights.shape))
    return count / weights.size if weights.size else 0.0


def nearest_faces(cage: Cage, points: np.ndarray, device=None) -> np.ndarray:
    """(N,) index of the cage face nearest to each point (Warp's BVH query, float32)."""
    from .geometry.grid import _cage_mesh

    device = resolve_device(device)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (cage.vertices.min(axis=0) + cage.vertices.max(axis=0))
    with wp.ScopedDevice(device):
        mesh = _cage_mesh(cage, centre, device)
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
    from .geometry.local_boundary import cage_graph_distances

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
    for rows in _row_chunks(*weights.shape):
        out[rows] = (np.abs(weights[rows].astype(np.float64)) * distant[face[rows]]).sum(axis=1)
    return out


def vertex_weight_difference(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex, the largest and the RMS difference over the handles between two sets of weights.

    Parameters
    ----------
    a, b : (V, L) arrays or Bindings (their ``weights``) of the same mesh and cage, e.g. two resolutions

    Returns
    -------
    largest : (V,) float64, max_l |a_l - b_l|
    rms : (V,) float64, sqrt(mean_l (a_l - b_l)^2)

    Examples
    --------
    >>> a = np.array([[0.5, 0.5], [1.0, 0.0]]); b = np.array([[0.5, 0.5], [0.7, 0.3]])
    >>> [np.round(x, 3).tolist() for x in vertex_weight_difference(a, b)]
    [[0.0, 0.3], [0.0, 0.3]]
    """
    a, b = np.asarray(getattr(a, "weights", a)), np.asarray(getattr(b, "weights", b))
    if a.shape != b.shape:
        raise ValueError(f"weights of shapes {a.shape} and {b.shape} cannot be compared")
    largest, rms = np.zeros(len(a)), np.zeros(len(a))
    if a.size:
        for rows in _row_chunks(*a.shape):
            d = a[rows].astype(np.float64) - b[rows]
            largest[rows] = np.abs(d).max(axis=1)
            rms[rows] = np.sqrt((d * d).mean(axis=1))
    return largest, rms


def weight_difference(a, b) -> dict:
    """Max and RMS over vertices of the largest per-vertex weight change between two weight sets (V, L).

    Parameters
    ----------
    a, b : (V, L) arrays or Bindings

    Returns
    -------
    dict: ``max`` (over vertices and handles), ``rms`` (over vertices, of each vertex's largest change)

    Examples
    --------
    >>> weight_difference(np.eye(2), np.eye(2))
    {'max': 0.0, 'rms': 0.0}
    """
    largest, _ = vertex_weight_difference(a, b)
    rms = float(np.sqrt(np.mean(largest**2))) if len(largest) else 0.0
    return {"max": float(largest.max(initial=0.0)), "rms": rms}


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
        from .geometry.cage import check_cage

        cage = check_cage(cage)
    vertices = np.asarray(mesh_vertices, dtype=np.float64)
    faces = np.asarray(mesh_faces, dtype=np.int64)
    if w.shape != (len(vertices), cage.n_handles):
        raise ValueError(f"weights of shape {w.shape} do not fit {len(vertices)} vertices and {cage.n_handles} handles")
    n_vertices, n_handles = w.shape
    masks = {name: _vertex_mask(region, n_vertices)
             for name, region in (regions or {"all": np.ones(n_vertices, dtype=bool)}).items()}

    conformal = dihedral = signed = edges = None
    if pose is not None:
        pose = _pose(pose, cage)
        deformed = np.empty((n_vertices, 3))
        for rows in _row_chunks(n_vertices, n_handles):
            deformed[rows] = w[rows].astype(np.float64) @ pose
        conformal = conformal_distortion(faces, vertices, deformed)
        if reference is not None:
            reference = np.asarray(reference, dtype=np.float64) if isinstance(reference, np.ndarray) else \
                load_surface(reference).vertices
            if reference.shape != vertices.shape:
                raise ValueError(f"the reference mesh has {len(reference)} vertices, the mesh {n_vertices}")
            edges = interior_edges(faces)
            dihedral = dihedral_change(faces, deformed, reference, edges)
            signed = dihedral_change(faces, deformed, reference, edges, signed=True)

    # per-vertex weight statistics, one pass over the weights
    smallest = np.empty(n_vertices)
    negatives = np.empty(n_vertices, dtype=np.int64)
    for rows in _row_chunks(n_vertices, n_handles):
        smallest[rows] = w[rows].min(axis=1, initial=np.inf)
        negatives[rows] = np.count_nonzero(w[rows] < -NEGATIVE_TOLERANCE, axis=1)
    distant = distant_handle_weight(w, cage, vertices, fraction, device)
    change = None if finer is None else vertex_weight_difference(w, finer)[0]

    out = {"vertices": n_vertices, "handles": n_handles, "distant_threshold": distant_handles(cage, fraction)[1],
           "min_weight": float(smallest.min(initial=np.inf)),
           "negative_fraction": float(negatives.sum() / max(1, w.size)), "regions": {}}
    for name, mask in masks.items():
        count = int(mask.sum())
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
        out["regions"][name] = row
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
    from .geometry.boundary import mean_value_coordinates

    if not isinstance(cage, Cage):
        from .geometry.cage import check_cage

        cage = check_cage(cage)
    weights = mean_value_coordinates(cage, mesh_vertices, device=device)
    out = deformation_quality(weights, mesh_vertices, mesh_faces, cage, pose, reference, regions, device, finer,
                              fraction)
    out["weights"] = weights
    return out
