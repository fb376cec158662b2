"""Validating a cage: a closed, consistently and outward oriented triangle mesh whose vertices are the handles.

Its edges and soups are in :mod:`.topology`, crossing faces and folds in :mod:`.cage_faults`; their names are
offered here too, where the cage's users look for them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import CageError
from ..io.load import load_surface
from .cage_faults import FOLD_DEGREES, crossing_faces, folded_edges, unit_normals
from .topology import MERGE_TOLERANCE, bounding_diagonal, face_edges, interior_edges, is_closed, merge_coincident

__all__ = ["Cage", "check_cage", "signed_volume", "unit_normals", "face_edges", "interior_edges", "folded_edges",
           "crossing_faces", "merge_coincident", "FOLD_DEGREES", "MERGE_TOLERANCE"]


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
        return bounding_diagonal(self.vertices)


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


def check_cage(source, name: str | None = None) -> Cage:
    """Load a cage and check that it can carry Stokes coordinates.

    A cage that is not closed as given, but is once coincident vertices are merged (a triangle soup: STL, and
    some PLY and glTF files), is merged first (:func:`merge_coincident`, tolerance :data:`MERGE_TOLERANCE` of the
    diagonal; the map from source vertices to handles is ``Cage.source_index``). Cages that need no merging keep
    their vertex order exactly.

    Checks, in order: at least 4 vertices, finite coordinates, no degenerate or duplicate faces, closed
    (every edge shared by exactly two faces), consistent orientation (the two faces at an edge traverse it in
    opposite directions), outward orientation (an inward cage is flipped, with a warning). Edges where the cage
    folds back on itself (:func:`folded_edges`) are named in a note (``Cage.notes``, kept in a binding's stats);
    bind warns where its resolution is too coarse for them.

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
    notes: list[str] = []
    v, f, source_index = _merged_if_soup(surface, notes)
    _check_faces(v, f, name)
    _check_closed_and_oriented(f, name)
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
    flipped = signed_volume(v, f) < 0
    if flipped:
        f = f[:, ::-1].copy()
        notes.append(f"{name}: the cage is oriented inward (negative volume); its faces were reversed")
        warnings.warn(notes[-1], stacklevel=2)
    cage = Cage(vertices=v, faces=np.ascontiguousarray(f), name=name, flipped=bool(flipped), notes=notes,
                source_index=source_index)
    folds, angle = folded_edges(cage, angles=True)
    if len(folds):
        worst = np.argsort(-angle)[:3]
        listed = ", ".join(f"{a}-{b} ({t:.0f} deg)" for (a, b), t in zip(folds[worst].tolist(), angle[worst]))
        notes.append(f"{name}: the cage folds back on itself at {len(folds)} edge(s) whose faces' normals are more "
                     f"than {FOLD_DEGREES:.0f} degrees apart, e.g. {listed}; the wedges of outside space there are thinner "
                     "than a grid cell near the edge; bind warns where its resolution is too coarse to cut them off")
        # a note, not a warning: where the grid cuts the wedges off (resolution "auto" does), nothing is to be done
    return cage


def _merged_if_soup(surface, notes: list):
    """(vertices, faces, source_index): the surface as it is, or, when it is not closed but is once coincident
    vertices merge (a triangle soup: STL keeps one vertex per face corner; so do some PLY and glTF files), merged,
    with a note. Too few vertices or faces, or all in one point, are refused first."""
    name, v, f = surface.name, surface.vertices, surface.faces
    if len(v) < 4:
        raise CageError(f"{name}: a cage needs at least 4 vertices, got {len(v)}")
    if len(f) < 4:
        raise CageError(f"{name}: a closed cage needs at least 4 triangles, got {len(f)}")
    diag = bounding_diagonal(v)
    if not diag > 0:
        raise CageError(f"{name}: all cage vertices coincide")
    if not is_closed(f):
        merged_v, merged_f, index = merge_coincident(v, f, MERGE_TOLERANCE * diag)
        if len(merged_v) < len(v) and is_closed(merged_f):
            notes.append(f"{name}: {len(v)} vertices merged into {len(merged_v)} handles (vertices within "
                         f"{MERGE_TOLERANCE:g} of the diagonal are one handle; handles in order of first appearance)")
            return merged_v, merged_f, index
    return v, f, None


def _check_faces(v: np.ndarray, f: np.ndarray, name: str) -> None:
    """No degenerate (zero-area, or a repeated vertex) and no duplicate faces."""
    diag = bounding_diagonal(v)
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    degenerate = repeated | (area2 <= 1e-12 * diag * diag)
    if degenerate.any():
        i = int(np.flatnonzero(degenerate)[0])
        raise CageError(
            f"{name}: {int(degenerate.sum())} degenerate (zero-area) face(s), the first is face {i} "
            f"with vertices {f[i].tolist()}"
        )
    _, first, counts = np.unique(np.sort(f, axis=1), axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        i = int(first[np.flatnonzero(counts > 1)[0]])
        raise CageError(f"{name}: duplicate faces: face {i} with vertices {f[i].tolist()} appears more than once")


def _check_closed_and_oriented(f: np.ndarray, name: str) -> None:
    """Every undirected edge used by exactly two faces, in opposite directions."""
    directed = face_edges(f)
    uniq, inverse, counts = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True, return_counts=True)
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
