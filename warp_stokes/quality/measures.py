"""Per-triangle, per-edge and per-weight measures of a deformation, and their summaries by region."""

from __future__ import annotations

import numpy as np

from ..geometry.cage import interior_edges

__all__ = ["conformal_distortion", "dihedral_angles", "dihedral_change", "percentile_summary", "region_triangles",
           "region_edges", "negative_weight_fraction", "NEGATIVE_TOLERANCE", "row_chunks", "vertex_mask"]


#: weights in [-NEGATIVE_TOLERANCE, 0) count as zero, not negative: a float32 solve (its partition-of-unity check is
#: 1e-5) leaves the weights of handles far away at +-1e-7..1e-5, as often below zero as above: counted as negative,
#: that noise would hide the negative weights that matter
NEGATIVE_TOLERANCE = 1e-5

#: entries of a (V, L) weight matrix read at once (rows per chunk = this / L)
_CHUNK_ENTRIES = 1 << 20


def row_chunks(n_rows: int, n_columns: int):
    """Slices of rows of a (n_rows, n_columns) weight matrix, about 2**20 entries each: measures read the weights
    a block at a time, in float64, without a float64 copy of all of them."""
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


def vertex_mask(region, n_vertices: int) -> np.ndarray:
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
    return vertex_mask(region, n_vertices)[np.asarray(faces, dtype=np.int64)].all(axis=1)


def region_edges(edges: np.ndarray, region, n_vertices: int) -> np.ndarray:
    """(E,) bool: the edges (``interior_edges(...)[2]``) whose two vertices lie in ``region``.

    Examples
    --------
    >>> region_edges(np.array([[0, 1], [1, 3]]), [0, 1, 2], 4).tolist()
    [True, False]
    """
    return vertex_mask(region, n_vertices)[np.asarray(edges, dtype=np.int64)].all(axis=1)


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
    count = sum(int(np.count_nonzero(weights[rows] < -tolerance)) for rows in row_chunks(*weights.shape))
    return count / weights.size if weights.size else 0.0
