"""Validating a cage: a closed, consistently and outward oriented triangle mesh whose vertices are the handles."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from .errors import CageError
from .load import load_surface

__all__ = ["Cage", "check_cage", "signed_volume", "unit_normals", "folded_edges", "FOLD_DEGREES"]

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
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str
    flipped: bool = False
    notes: list = field(default_factory=list)

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
    f = cage.faces
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    face = np.tile(np.arange(len(f)), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort(key.T[::-1])
    key, face = key[order], face[order]
    pair = np.flatnonzero((key[1:] == key[:-1]).all(axis=1))  # a closed cage: each edge twice, adjacent here
    n = unit_normals(cage)
    angle = np.degrees(np.arccos(np.clip((n[face[pair]] * n[face[pair + 1]]).sum(axis=1), -1.0, 1.0)))
    folded = angle > degrees
    return (key[pair][folded], angle[folded]) if angles else key[pair][folded]


def check_cage(source, name: str | None = None) -> Cage:
    """Load a cage and check that it can carry Stokes coordinates.

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
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
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

    flipped = False
    vol = signed_volume(v, f)
    if vol < 0:
        flipped = True
        f = f[:, ::-1].copy()
        msg = f"{name}: the cage is oriented inward (negative volume); its faces were reversed"
        notes.append(msg)
        warnings.warn(msg, stacklevel=2)
    cage = Cage(vertices=v, faces=np.ascontiguousarray(f), name=name, flipped=flipped, notes=notes)
    folds, angle = folded_edges(cage, angles=True)
    if len(folds):
        worst = np.argsort(-angle)[:3]
        listed = ", ".join(f"{a}-{b} ({t:.0f} deg)" for (a, b), t in zip(folds[worst].tolist(), angle[worst]))
        msg = (f"{name}: the cage folds back on itself at {len(folds)} edge(s) whose faces' normals are more than "
               f"{FOLD_DEGREES:.0f} degrees apart, e.g. {listed}; weights near them grow slowly with the resolution")
        notes.append(msg)
        warnings.warn(msg, stacklevel=2)
    return cage
