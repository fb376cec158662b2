"""How the rest of a cage follows when an artist moves a few of its handles: the numerical core of a live cage
editor.

Three schemes: "none" (only the constrained handles move), "laplacian" (the displacement from rest is
bi-Laplacian smooth) and "arap" (as-rigid-as-possible, Sorkine and Alexa 2007, with the spokes-and-rims energy of
Chao et al. 2010, which is what libigl's ``arap_precomputation`` / ``arap_solve`` minimise for a 3-D triangle mesh by
default). Cages have tens to hundreds of handles, so every matrix is dense numpy; the reduced systems are factored
once per constrained set and kept, so the many solves of one drag reuse them.

Rotations are the caller's business: the targets are where the constrained handles go, already rotated.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Literal, overload

import numpy as np

from ..errors import CageError, WarpStokesError
from .topology import bounding_diagonal

__all__ = ["CageFollow", "FollowResult", "SCHEMES", "ITERATIONS", "TOLERANCE", "DEGENERATE_AREA"]

SCHEMES = ("none", "laplacian", "arap")
#: ARAP's default iteration cap: a drag starts each solve from the previous pose, a few iterations away
ITERATIONS = 100
#: ARAP stops once no vertex moved by more than this fraction of the rest diagonal in an iteration
TOLERANCE = 1e-6
#: a triangle whose doubled area is below this fraction of the squared rest diagonal is degenerate: the cotangents
#: of its angles are unbounded, and no weight would be right
DEGENERATE_AREA = 1e-12
#: constrained sets whose factorisations are kept (an editor returns to a few selections over and over)
CACHED_SETS = 16

#: a triangle's edges as (source, destination) corners, edge e opposite corner e: libigl's order
_EDGES = np.array([[1, 2], [2, 0], [0, 1]])


@dataclass(frozen=True)
class FollowResult:
    """A solve's pose and how it got there.

    Attributes
    ----------
    vertices : (L, 3) float64, the cage's new handle positions (the constrained ones exactly at their targets)
    iterations : int, ARAP local/global iterations run (0 for "none" and "laplacian")
    converged : bool, ARAP stopped on the tolerance, not the iteration cap (always True for the other schemes)
    energies : tuple of float, the ARAP energy (:meth:`CageFollow.energy`) of the start (the constrained handles
        already at their targets) and after each iteration; for "none" and "laplacian", the result's alone
    """

    vertices: np.ndarray
    iterations: int
    converged: bool
    energies: tuple[float, ...]

    @property
    def energy(self) -> float:
        """The ARAP energy of ``vertices``."""
        return self.energies[-1]


@dataclass(frozen=True)
class _Factor:
    """The reduced system of one constrained set: the free handles, the inverse of their block, and the block that
    couples them to the constrained ones."""

    free: np.ndarray
    inverse: np.ndarray
    coupling: np.ndarray


class CageFollow:
    """The rest of a cage following a few moved handles, for one rest cage.

    Parameters
    ----------
    rest_vertices : (L, 3) float, the cage at rest
    faces : (T, 3) int, its triangles (every vertex in one at least)

    Raises
    ------
    CageError
        Malformed arrays, an unused vertex, a degenerate triangle (its cotangent weights would be unbounded).

    Examples
    --------
    >>> v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    >>> f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    >>> follow = CageFollow(v, f)
    >>> moved = follow.solve([0, 1], v[[0, 1]] + [0, 0, 0.5], "laplacian")
    >>> bool(np.allclose(moved, v + [0, 0, 0.5]))
    True
    >>> result = follow.solve([0, 1, 5], v[[0, 1, 5]] + [0, 0, 0.5], "arap", report=True)
    >>> bool(np.allclose(result.vertices, v + [0, 0, 0.5])), round(result.energy, 6)
    (True, 0.0)
    """

    def __init__(self, rest_vertices, faces):
        vertices = _float_array(rest_vertices, "rest vertices", CageError)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 4:
            raise CageError(f"rest vertices must have shape (L, 3) with L >= 4, got {vertices.shape}")
        if not np.isfinite(vertices).all():
            raise CageError(f"rest vertex {int(np.argwhere(~np.isfinite(vertices))[0, 0])} is not finite")
        faces = _index_array(faces, "faces", CageError)
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise CageError(f"faces must have shape (T, 3) with T >= 1, got {faces.shape}")
        if faces.min() < 0 or faces.max() >= len(vertices):
            bad = int(np.argwhere((faces < 0) | (faces >= len(vertices)))[0, 0])
            raise CageError(f"face {bad} {faces[bad].tolist()} names a vertex outside 0..{len(vertices) - 1}")
        unused = np.setdiff1d(np.arange(len(vertices)), faces)
        if len(unused):
            raise CageError(f"vertex {int(unused[0])} is in no triangle: nothing ties it to the cage")
        diagonal = bounding_diagonal(vertices)
        if diagonal == 0.0:
            raise CageError("all rest vertices coincide")

        corners = vertices[faces]
        # the angle at corner c lies between the vectors to the next two corners; edge c is opposite it
        to_next, to_last = corners[:, [1, 2, 0]] - corners, corners[:, [2, 0, 1]] - corners
        double_area = np.linalg.norm(np.cross(to_next[:, 0], to_last[:, 0]), axis=1)
        degenerate = np.flatnonzero(double_area <= DEGENERATE_AREA * diagonal ** 2)
        if len(degenerate):
            t = int(degenerate[0])
            raise CageError(f"triangle {t} (vertices {faces[t].tolist()}) is degenerate: area "
                            f"{0.5 * double_area[t]:.3g} for a cage of diagonal {diagonal:.6g}; its cotangent weights "
                            f"are unbounded")
        #: libigl's cotmatrix_entries: half the cotangent of the angle opposite each edge (negative when obtuse)
        weights = 0.5 * np.einsum("tci,tci->tc", to_next, to_last) / double_area[:, None]

        n = len(vertices)
        source, dest = faces[:, _EDGES[:, 0]], faces[:, _EDGES[:, 1]]
        stiffness = np.zeros((n, n))  # minus the cotangent Laplacian: positive semi-definite, rows summing to zero
        np.add.at(stiffness, (source, dest), -weights)
        np.add.at(stiffness, (dest, source), -weights)
        np.add.at(stiffness, (source, source), weights)
        np.add.at(stiffness, (dest, dest), weights)
        mass = np.bincount(faces.ravel(), np.repeat(double_area / 6.0, 3), minlength=n)  # lumped, barycentric
        bilaplacian = stiffness @ (stiffness / mass[:, None])
        # the right-hand side scatters each triangle edge's term to its source (+) and destination (-)
        scatter = np.zeros((n, faces.size))
        column = np.arange(faces.size)
        scatter[source.ravel(), column] = 1.0
        scatter[dest.ravel(), column] = -1.0

        self._rest = vertices.copy()
        self._rest.setflags(write=False)
        self._faces = faces.copy()
        self._faces.setflags(write=False)
        self._diagonal = diagonal
        self._source, self._dest = source, dest
        self._weights = weights
        rest_edges = vertices[source] - vertices[dest]  # (T, 3 edges, 3)
        self._rest_t = np.ascontiguousarray(np.swapaxes(rest_edges, 1, 2))  # (T, 3, 3 edges): matmul's layout
        self._weighted_rest_t = self._rest_t * weights[:, None, :]
        self._stiffness = stiffness
        self._bilaplacian = 0.5 * (bilaplacian + bilaplacian.T)  # symmetric in exact arithmetic; make it so here
        self._scatter = scatter
        self._component = _components(n, faces)
        self._factors: OrderedDict = OrderedDict()

    @property
    def rest_vertices(self) -> np.ndarray:
        """(L, 3) float64, read-only."""
        return self._rest

    @property
    def faces(self) -> np.ndarray:
        """(T, 3) int64, read-only."""
        return self._faces

    @property
    def diagonal(self) -> float:
        """The rest cage's bounding-box diagonal: the scale of ``tolerance``."""
        return self._diagonal

    def energy(self, vertices) -> float:
        """The ARAP (spokes-and-rims) energy of a pose, each handle's rotation the best one for it.

        ``sum over triangles T, edges (s, t) of T, corners k of T of w ||(p_s - p_t) - R_k (x_s - x_t)||^2``, with
        ``w`` half the cotangent of the angle opposite the edge in T, ``x`` the rest pose and ``R_k`` the rotation
        that minimises the terms of handle ``k``. Zero for a rigid motion of the rest pose; in squared length units.

        Parameters
        ----------
        vertices : (L, 3) float

        Returns
        -------
        float, non-negative

        Examples
        --------
        >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
        >>> follow = CageFollow(v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
        >>> follow.energy(v + 1.0) < 1e-25, follow.energy(2.0 * v) > 0.1
        (True, True)
        """
        return self._fit_rotations(self._pose(vertices, "vertices"))[1]

    @overload
    def solve(self, handles, targets, scheme: str = ..., start=..., iterations: int = ..., tolerance: float = ...,
              report: Literal[False] = ...) -> np.ndarray: ...

    @overload
    def solve(self, handles, targets, scheme: str = ..., start=..., iterations: int = ..., tolerance: float = ...,
              *, report: Literal[True]) -> FollowResult: ...

    def solve(self, handles, targets, scheme: str = "arap", start=None, iterations: int = ITERATIONS,
              tolerance: float = TOLERANCE, report: bool = False):
        """Where every handle goes when ``handles`` go to ``targets``.

        Parameters
        ----------
        handles : (H,) int, the constrained handles, each once
        targets : (H, 3) float, their positions
        scheme : "none" | "laplacian" | "arap"
            "none": only the constrained handles move, the others stay at ``start``. "laplacian": the displacement
            from rest ``d`` minimises ``d^T L M^-1 L d`` (cotangent Laplacian ``L``, lumped barycentric mass ``M``)
            with ``d`` fixed at the handles: a translation of every constrained handle translates the cage exactly,
            and ``start`` plays no part. "arap": the as-rigid-as-possible pose, local/global iterations from
            ``start`` until no handle moves by more than ``tolerance`` times the rest diagonal in one, or
            ``iterations`` have run.
        start : (L, 3) float or None, the pose to start from (None: the rest pose); its constrained handles are
            replaced by their targets
        iterations : int >= 0, ARAP's cap
        tolerance : float >= 0, ARAP's stop, relative to the rest diagonal
        report : bool, return a :class:`FollowResult` (iterations, convergence, energies) instead of the pose

        Returns
        -------
        (L, 3) float64, or FollowResult when ``report``

        Raises
        ------
        WarpStokesError
            Unknown scheme, malformed or non-finite arrays, a handle out of range or given twice, and for "laplacian"
            and "arap" no constrained handle on some connected part of the cage (nothing would fix where it goes).

        Examples
        --------
        >>> v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
        >>> f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
        >>> follow = CageFollow(v, f)
        >>> result = follow.solve([4, 5], [[0, 0, 1.2], [0, 0, -1]], "arap", iterations=500, tolerance=1e-9,
        ...                       report=True)
        >>> result.converged, bool(result.vertices[0, 2] > 0)
        (True, True)
        >>> follow.solve([4], [[0, 0, 1.2]], "arap", start=v)[4].tolist()
        [0.0, 0.0, 1.2]
        """
        if not isinstance(scheme, str) or scheme not in SCHEMES:
            raise WarpStokesError(f"unknown scheme {scheme!r}: expected one of {', '.join(map(repr, SCHEMES))}")
        handles, targets = self._constraints(handles, targets)
        pose = self._rest.copy() if start is None else self._pose(start, "start")
        if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 0:
            raise WarpStokesError(f"iterations must be an integer >= 0, got {iterations!r}")
        if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float, np.floating, np.integer)) \
                or not np.isfinite(tolerance) or tolerance < 0:
            raise WarpStokesError(f"tolerance must be a finite number >= 0, got {tolerance!r}")
        if scheme != "none":
            self._check_placed(handles, scheme)
        pose[handles] = targets

        done, converged = 0, True
        if scheme == "laplacian":
            factor = self._factor(handles, "laplacian")
            # displacements relative to the first handle's: a common translation of every handle then solves to
            # exactly zero here, not to the rounding of an ill-conditioned bi-Laplacian
            moved = targets - self._rest[handles]
            relative = moved - moved[0]
            pose[factor.free] = self._rest[factor.free] + moved[0] - factor.inverse @ (factor.coupling @ relative)
        elif scheme == "arap":
            pose, done, converged, energies = self._arap(pose, handles, targets, iterations, tolerance, report)
        if not report:
            return pose
        if scheme != "arap":
            energies = (self._fit_rotations(pose)[1],)
        return FollowResult(pose, done, converged, energies)

    # ------------------------------------------------------------------------------------------------------------

    def _arap(self, pose, handles, targets, iterations, tolerance, report):
        factor = self._factor(handles, "arap")
        fixed = factor.coupling @ targets
        rotations, energy = self._fit_rotations(pose, report)
        energies = [energy]
        done, converged = 0, False
        for done in range(1, iterations + 1):
            free = factor.inverse @ (self._rhs(rotations)[factor.free] - fixed)
            change = float(np.sqrt(((free - pose[factor.free]) ** 2).sum(axis=1).max(initial=0.0)))
            pose[factor.free] = free
            rotations, energy = self._fit_rotations(pose, report)
            energies.append(energy)
            if change <= tolerance * self._diagonal:
                converged = True
                break
        return pose, done, converged, tuple(energies)

    def _fit_rotations(self, pose, energy: bool = True):
        """Each handle's best rotation for ``pose`` (the local step), and the energy with them (nan unless
        ``energy``: a drag that wants no report skips its cost)."""
        edges = pose[self._source] - pose[self._dest]
        # each triangle's weighted covariance, summed over its three edges, goes to all three of its corners
        per_triangle = (self._weighted_rest_t @ edges).reshape(-1, 9)
        corner = self._faces.ravel()
        covariance = np.stack([np.bincount(corner, np.repeat(per_triangle[:, c], 3), minlength=len(pose))
                               for c in range(9)], axis=1).reshape(-1, 3, 3)
        u, _, vt = np.linalg.svd(covariance)
        rotations = np.swapaxes(vt, 1, 2) @ np.swapaxes(u, 1, 2)
        flipped = np.linalg.det(rotations) < 0
        if flipped.any():  # a reflection fits better: the best rotation turns the weakest direction the other way
            vt[flipped, 2] *= -1.0
            rotations[flipped] = np.swapaxes(vt[flipped], 1, 2) @ np.swapaxes(u[flipped], 1, 2)
        if not energy:
            return rotations, float("nan")
        # the residuals themselves, not |d|^2 + |e|^2 - 2 tr(R^T S): near a rigid pose the difference cancels
        residual = np.swapaxes(edges, 1, 2)[:, None] - rotations[self._faces] @ self._rest_t[:, None]
        return rotations, max(float((self._weights[:, None, None, :] * residual ** 2).sum()), 0.0)

    def _rhs(self, rotations):
        """The global step's right-hand side: each triangle edge's rest vector turned by the mean rotation of the
        triangle's corners, weighted, added at its source and taken at its destination (libigl's arap_rhs)."""
        mean = rotations[self._faces].sum(axis=1) / 3.0
        turned = self._weights[..., None] * np.swapaxes(mean @ self._rest_t, 1, 2)
        return self._scatter @ turned.reshape(-1, 3)

    def _factor(self, handles, scheme) -> _Factor:
        """The reduced system for ``handles`` (sorted), from the cache when this set was solved for lately."""
        key = (scheme, tuple(handles.tolist()))
        factor = self._factors.get(key)
        if factor is not None:
            self._factors.move_to_end(key)
            return factor
        matrix = self._stiffness if scheme == "arap" else self._bilaplacian
        free = np.setdiff1d(np.arange(len(self._rest)), handles)
        block = matrix[np.ix_(free, free)]
        try:
            lower = np.linalg.cholesky(block)
        except np.linalg.LinAlgError:
            raise WarpStokesError(f"scheme {scheme!r}: the system for the free handles is singular; "
                                  f"constrain handles apart from {handles.tolist()[:8]}") from None
        lower_inverse = np.linalg.solve(lower, np.eye(len(free)))
        factor = _Factor(free, lower_inverse.T @ lower_inverse, matrix[np.ix_(free, handles)])
        self._factors[key] = factor
        self._factors.move_to_end(key)
        while len(self._factors) > CACHED_SETS:
            self._factors.popitem(last=False)
        return factor

    def _constraints(self, handles, targets):
        n = len(self._rest)
        handles = _index_array(handles, "handles", WarpStokesError)
        if handles.ndim != 1:
            raise WarpStokesError(f"handles must be a 1-D list of vertex indices, got shape {handles.shape}")
        outside = handles[(handles < 0) | (handles >= n)]
        if len(outside):
            raise WarpStokesError(f"handle {int(outside[0])} is out of range: the cage has {n} vertices (0 to {n - 1})")
        values, counts = np.unique(handles, return_counts=True)
        if (counts > 1).any():
            raise WarpStokesError(f"handle {int(values[counts > 1][0])} is constrained more than once")
        targets = _float_array(targets, "targets", WarpStokesError)
        if targets.size == 0 and len(handles) == 0:
            targets = targets.reshape(0, 3)
        if targets.shape != (len(handles), 3):
            raise WarpStokesError(f"targets must have shape ({len(handles)}, 3), one row per handle, "
                                  f"got {targets.shape}")
        bad = np.flatnonzero(~np.isfinite(targets).all(axis=1))
        if len(bad):
            raise WarpStokesError(f"the target of handle {int(handles[bad[0]])} is not finite: "
                                  f"{targets[bad[0]].tolist()}")
        # one order for the cache's key and the coupling's columns, whatever order the caller gives
        order = np.argsort(handles)
        return handles[order], targets[order]

    def _pose(self, vertices, name):
        pose = _float_array(vertices, name, WarpStokesError)
        if pose.shape != self._rest.shape:
            raise WarpStokesError(f"{name} must have shape {self._rest.shape}, like the rest cage, got {pose.shape}")
        if not np.isfinite(pose).all():
            raise WarpStokesError(f"{name}: vertex {int(np.argwhere(~np.isfinite(pose))[0, 0])} is not finite")
        return pose.copy()

    def _check_placed(self, handles, scheme):
        if len(handles) == 0:
            raise WarpStokesError(f"scheme {scheme!r} needs at least one constrained handle: with none, nothing fixes "
                                  f"where the cage goes")
        unplaced = np.setdiff1d(self._component, self._component[handles])
        if len(unplaced):
            vertex = int(np.flatnonzero(self._component == unplaced[0])[0])
            raise WarpStokesError(f"scheme {scheme!r}: no handle is constrained on the part of the cage that holds "
                                  f"vertex {vertex}, so nothing fixes where that part goes")


def _components(n: int, faces: np.ndarray) -> np.ndarray:
    """The connected part of the mesh each vertex is in (labels 0, 1, ...)."""
    parent = np.arange(n)

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]]):
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return np.unique([root(i) for i in range(n)], return_inverse=True)[1]


def _float_array(value, name: str, error: type[Exception]) -> np.ndarray:
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise error(f"{name} must be an array of numbers: {str(exc).splitlines()[0]}") from None


def _index_array(value, name: str, error: type[Exception]) -> np.ndarray:
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise error(f"{name} must be an array of integers: {str(exc).splitlines()[0]}") from None
    if array.size == 0:
        return array.astype(np.int64)
    if array.dtype.kind not in "iu":
        raise error(f"{name} must be integers, got {array.dtype}")
    return array.astype(np.int64)
