"""Validating a cage: a closed, consistently and outward oriented triangle mesh whose vertices are the handles."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import CageError
from ..io.load import load_surface

__all__ = ["Cage", "check_cage", "signed_volume", "unit_normals", "face_edges", "interior_edges", "folded_edges",
           "merge_coincident",
           "FOLD_DEGREES", "MERGE_TOLERANCE"]

#: an edge where the two faces' normals are more than this many degrees apart is folded: the cage folds back on
#: itself there, leaving a wedge of outside (or inside) space thinner than any grid cell near the edge
FOLD_DEGREES = 150.0


@dataclass(frozen=True)
class Cage:
    """A validated cage.

    Attributes
    ----------
    vertices : (L, 3) float64, the handles in the source's order
    faces : (T, 3) int64 triangles, outward oriented
    name : str, where the cage came from
    flipped : bool, True when the input was inward oriented and its faces were reversed
    notes : list of str, warnings issued while checking
    source_index : (V_source,) int64 or None
        For a cage merged from a triangle soup (STL and the like): the handle of each vertex of the source, in its
        order; the handles are the distinct positions in order of first appearance. None when nothing was merged
        (the handles are the source's vertices, in its order).
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str
    flipped: bool = False
    notes: list = field(default_factory=list)
    source_index: np.ndarray | None = None

    @property
    def n_handles(self) -> int:
        return len(self.vertices)

    @property
    def diagonal(self) -> float:
        return float(np.linalg.norm(self.vertices.max(axis=0) - self.vertices.min(axis=0)))


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by a closed triangle mesh (positive when faces are outward oriented).

    Parameters
    ----------
    vertices : (V, 3) array
    faces : (F, 3) int array

    Returns
    -------
    float

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> round(signed_volume(v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])), 6)
    0.166667
    """
    c = vertices.mean(axis=0)
    a, b, d = (vertices[faces[:, k]] - c for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, d)).sum() / 6.0)


def crossing_faces(vertices: np.ndarray, faces: np.ndarray, device=None) -> np.ndarray:
    """Pairs of faces that cross each other (an edge of one passes through the other), found with a BVH.

    Faces that share an edge are not tested (they meet along it); faces that share a corner are, away from it.
    Coplanar overlaps are not detected.

    Parameters
    ----------
    vertices : (L, 3) array
    faces : (F, 3) int array
    device : the Warp device of the test (default: CUDA when present, else the CPU)

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

    from ..device import resolve_device
    from ..kernels import intersect

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int32)
    if len(faces) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    relative = vertices - centre
    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    device = resolve_device(device)
    with wp.ScopedDevice(device):
        mesh = wp.Mesh(points=wp.array(relative.astype(np.float32), dtype=wp.vec3),
                       indices=wp.array(faces.ravel(), dtype=wp.int32))
        first = wp.empty(len(faces), dtype=wp.int32)
        wp.launch(intersect.crossing_faces, dim=len(faces),
                  inputs=[mesh.id, wp.array(relative, dtype=wp.vec3d), wp.array(faces, dtype=wp.vec3i),
                          float(1e-6 * diag), wp.float64(1e-9)], outputs=[first])
        first = first.numpy()
    i = np.flatnonzero(first >= 0)
    return np.column_stack([i, first[i]]).astype(np.int64)


def unit_normals(cage: Cage) -> np.ndarray:
    """(F, 3) unit normals of the cage's faces (outward for a checked cage).

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> unit_normals(check_cage((v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])))[0].tolist()
    [0.0, 0.0, -1.0]
    """
    v, f = cage.vertices, cage.faces
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


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


def folded_edges(cage: Cage, degrees: float = FOLD_DEGREES, angles: bool = False):
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
MERGE_TOLERANCE = 1e-6


def _closed(faces: np.ndarray) -> bool:
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


def check_cage(source, name: str | None = None) -> Cage:
    """Load a cage and check that it can carry Stokes coordinates.

    A cage that is not closed as given, but is once coincident vertices are merged (a triangle soup: STL, and
    some PLY and glTF files), is merged first (:func:`merge_coincident`, tolerance :data:`MERGE_TOLERANCE` of the
    diagonal; the map from source vertices to handles is ``Cage.source_index``). Cages that need no merging keep
    their vertex order exactly.

    Checks, in order: at least 4 vertices, finite coordinates, no degenerate or duplicate faces, closed
    (every edge shared by exactly two faces), consistent orientation (the two faces at an edge traverse it in
    opposite directions), outward orientation (an inward cage is flipped, with a warning). Edges where the cage
    folds back on itself (:func:`folded_edges`) are named in a warning.

    Parameters
    ----------
    source : path, trimesh.Trimesh, (vertices, faces), Surface or Cage (returned as it is)
        Quads and polygons are fan-triangulated.
    name : str, optional
        Name used in messages.

    Returns
    -------
    Cage

    Raises
    ------
    CageError
        Naming the cage and the problem (with the offending face or edge).

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> cage = check_cage((v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    >>> cage.n_handles, cage.flipped
    (4, False)
    """
    if isinstance(source, Cage):
        return source
    try:
        surface = load_surface(source, name)
    except CageError:
        raise
    except ValueError as exc:
        raise CageError(str(exc)) from None
    name = surface.name
    v, f = surface.vertices, surface.faces
    notes: list[str] = []

    if len(v) < 4:
        raise CageError(f"{name}: a cage needs at least 4 vertices, got {len(v)}")
    if len(f) < 4:
        raise CageError(f"{name}: a closed cage needs at least 4 triangles, got {len(f)}")

    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    if not diag > 0:
        raise CageError(f"{name}: all cage vertices coincide")

    source_index = None
    if len(f) and not _closed(f):
        # a triangle soup (STL stores one vertex per face corner; so do some PLY and glTF files): merge what
        # coincides, and keep it if that closes the cage
        merged_v, merged_f, index = merge_coincident(v, f, MERGE_TOLERANCE * diag)
        if len(merged_v) < len(v) and _closed(merged_f):
            notes.append(f"{name}: {len(v)} vertices merged into {len(merged_v)} handles (vertices within "
                         f"{MERGE_TOLERANCE:g} of the diagonal are one handle; handles in order of first appearance)")
            v, f, source_index = merged_v, merged_f, index

    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    degenerate = repeated | (area2 <= 1e-12 * diag * diag)
    if degenerate.any():
        i = int(np.flatnonzero(degenerate)[0])
        raise CageError(
            f"{name}: {int(degenerate.sum())} degenerate (zero-area) face(s), the first is face {i} "
            f"with vertices {f[i].tolist()}"
        )

    key = np.sort(f, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        i = int(first[np.flatnonzero(counts > 1)[0]])
        raise CageError(f"{name}: duplicate faces: face {i} with vertices {f[i].tolist()} appears more than once")

    # every undirected edge must be used by exactly two faces, in opposite directions
    directed = face_edges(f)
    undirected = np.sort(directed, axis=1)
    uniq, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    if (counts != 2).any():
        bad = np.flatnonzero(counts != 2)
        e = uniq[bad[0]]
        kind = "a boundary (open) edge" if counts[bad[0]] == 1 else f"shared by {counts[bad[0]]} faces"
        raise CageError(
            f"{name}: the cage is not closed: {len(bad)} edge(s) not shared by exactly two faces, "
            f"e.g. edge {e.tolist()} is {kind}"
        )
    forward = directed[:, 0] < directed[:, 1]
    n_forward = np.bincount(inverse, weights=forward, minlength=len(uniq))
    if (n_forward != 1).any():
        e = uniq[np.flatnonzero(n_forward != 1)[0]]
        raise CageError(
            f"{name}: inconsistent face orientation: the two faces at edge {e.tolist()} traverse it in the same "
            f"direction ({int((n_forward != 1).sum())} such edges)"
        )

    unused = np.setdiff1d(np.arange(len(v)), f.ravel())
    if len(unused):
        raise CageError(
            f"{name}: {len(unused)} cage vertex(es) are not used by any face (e.g. vertex {int(unused[0])}); "
            "every cage vertex is a handle and must lie on the surface"
        )

    crossing = crossing_faces(v, f)
    if len(crossing):
        i, j = (int(k) for k in crossing[0])
        raise CageError(
            f"{name}: the cage intersects itself: faces {i} {f[i].tolist()} and {j} {f[j].tolist()} cross "
            f"({len(crossing)} crossing pair(s)); the inside of a self-intersecting cage is not defined"
        )

    flipped = False
    vol = signed_volume(v, f)
    if vol < 0:
        flipped = True
        f = f[:, ::-1].copy()
        msg = f"{name}: the cage is oriented inward (negative volume); its faces were reversed"
        notes.append(msg)
        warnings.warn(msg, stacklevel=2)
    cage = Cage(vertices=v, faces=np.ascontiguousarray(f), name=name, flipped=flipped, notes=notes,
                source_index=source_index)
    folds, angle = folded_edges(cage, angles=True)
    if len(folds):
        worst = np.argsort(-angle)[:3]
        listed = ", ".join(f"{a}-{b} ({t:.0f} deg)" for (a, b), t in zip(folds[worst].tolist(), angle[worst]))
        msg = (f"{name}: the cage folds back on itself at {len(folds)} edge(s) whose faces' normals are more than "
               f"{FOLD_DEGREES:.0f} degrees apart, e.g. {listed}; weights near them grow slowly with the resolution")
        notes.append(msg)
        warnings.warn(msg, stacklevel=2)
    return cage
