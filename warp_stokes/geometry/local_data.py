"""Local boundary data: the cage's hat functions at each node's closest cage point, Taylor-extended with normal
derivatives that stay on the handles near that point along the cage.

Mean value coordinates (MVC) are global: across a narrow gap between parts that are far apart along the cage (a
hand hanging beside a thigh) the MVC of one part's nodes carry the other part's handles (``method.md`` §8). Here a
ring or band node x with closest cage point y on face f (unit normal n_f) gets

    q_l(x) = hat_l(y) + (x - y) . (grad_T hat_l + g_l n_f),      G_l = h (grad_T hat_l + g_l n_f),

with per-face normal derivatives g (:func:`normal_derivatives`) such that sum_l g_l = 0 and sum_l g_l c_l = n_f:
then sum_l q_l = 1, sum_l c_l q_l = x and the same for G, exactly, whatever y is on f's plane, so partition of
unity and linear precision stay exact. The normal derivatives are MVC's own (outward, at the face's centroid) with
the handles farther than ``radius`` mean edge lengths along the cage from the face dropped, and the constraints
restored by the least change, weighted by exp(d / (falloff * mean edge)) with d the distance along the cage, so
that the change falls on the near handles. Measured (``benchmarks/RESULTS.md``): it keeps MVC's quality where the
cage has no gaps and removes the coupling across them.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import threading
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import warp as wp

from ..device import Backend
from ..errors import WarpStokesError
from ..kernels import local_boundary
from .cage import FOLD_DEGREES, Cage, face_edges, folded_edges, unit_normals
from .mean_value import mean_value_coordinates

__all__ = ["LocalData", "MeanValueData", "MVC_DATA", "boundary_settings", "cage_graph_distances", "cage_key", "local_data_bytes",
           "normal_derivatives", "data_slopes", "tangent_gradients"]


@dataclass(frozen=True)
class LocalData:
    """Settings of the local boundary data.

    Attributes
    ----------
    model : "mvc-cut" | "least-norm"
        Normal derivatives from MVC's with the far handles cut ("mvc-cut"), or the weighted least-norm ones that
        meet the constraints ("least-norm", no MVC).
    radius : float, mean edge lengths along the cage beyond which a handle's normal derivative is cut
    falloff : float, mean edge lengths: the weights exp(d / (falloff * mean edge)) of the least change
    least_norm_share : float in [0, 1], with "mvc-cut": the normal derivatives are this share of the least-norm
        ones and the rest MVC's cut ones (both meet the constraints, so any mix does)
    fold_radius : float, mean edge lengths: faces within this distance along the cage of a folded edge (its faces'
        normals more than ``fold_degrees`` apart) take the least-norm normal derivatives, fading out linearly over
        the next ``fold_radius`` (MVC's normal derivatives are large there, and the weights near the fold with
        them); 0 = none
    fold_degrees : float
    """

    #: the data is local: near each node's closest faces (cut off by thin wedges of outside space)
    local: ClassVar[bool] = True

    model: str = "mvc-cut"
    radius: float = 2.0
    falloff: float = 0.5
    least_norm_share: float = 0.0
    fold_radius: float = 1.0
    fold_degrees: float = FOLD_DEGREES

    def __post_init__(self):
        if self.model not in ("mvc-cut", "least-norm"):
            raise ValueError(f"local data model must be 'mvc-cut' or 'least-norm', got {self.model!r}")
        if not (self.radius >= 0 and self.falloff > 0):
            raise ValueError(f"local data needs radius >= 0 and falloff > 0, got {self.radius}, {self.falloff}")

    def __str__(self) -> str:
        share = f", least-norm share {self.least_norm_share:g}" if self.least_norm_share else ""
        folds = f", least-norm within {self.fold_radius:g} of folds > {self.fold_degrees:g} deg" if self.fold_radius else ""
        return f"local({self.model}, radius {self.radius:g}, falloff {self.falloff:g}{share}{folds})"


@dataclass(frozen=True)
class MeanValueData:
    """The boundary data by mean value coordinates at the ring and band nodes, their gradients by central differences
    (the seed's): global, the same on both sides of a thin wedge, so no node is cut off for it."""

    local: ClassVar[bool] = False

    def __str__(self) -> str:
        return "mvc-central-difference"


#: the mean value coordinates' boundary data
MVC_DATA = MeanValueData()


def boundary_settings(boundary) -> "LocalData | MeanValueData":
    """The boundary data named by ``boundary``: :data:`MVC_DATA` ("mvc"), or the local data's settings ("local" is
    ``LocalData()``); its ``local`` says which.

    Raises
    ------
    WarpStokesError
        When ``boundary`` is none of "mvc", "local" or a LocalData.

    Examples
    --------
    >>> boundary_settings("local") == LocalData()
    True
    >>> boundary_settings("mvc").local
    False
    """
    if isinstance(boundary, (LocalData, MeanValueData)):
        return boundary
    if isinstance(boundary, str) and boundary in ("mvc", "local"):
        return LocalData() if boundary == "local" else MVC_DATA
    raise WarpStokesError(f"boundary must be 'mvc', 'local' or a LocalData, got {boundary!r}")


def cage_graph_distances(cage: Cage, device=None) -> np.ndarray:
    """Shortest-path distances between the handles along the cage's edges (edge length weights).

    One Dijkstra search per handle in a Warp kernel (O(L E log L) in all; Floyd-Warshall's O(L^3) took 140 s at
    4,898 handles), over the handles in groups whose scratch heaps stay within :data:`GRAPH_SCRATCH_BYTES`.

    Parameters
    ----------
    cage : Cage
    device : None | str | Backend

    Returns
    -------
    (L, L) float64, symmetric, zero diagonal; inf between handles that no path joins

    Examples
    --------
    >>> from warp_stokes.geometry.cage import Cage
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> d = cage_graph_distances(Cage(v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]), "tetrahedron"))
    >>> bool(np.isclose(d[1, 2], np.sqrt(2)))
    True
    """
    backend = Backend.of(device)
    v = np.asarray(cage.vertices, dtype=np.float64)
    n = len(v)
    edges = face_edges(cage.faces)
    # both directions of every edge, once each (face_edges holds an interior edge once per face, one way each)
    edges = np.unique(np.concatenate([edges, edges[:, ::-1]]), axis=0)
    lengths = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
    offsets = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(np.bincount(edges[:, 0], minlength=n), out=offsets[1:])
    distances = np.empty((n, n))
    per_group = max(1, min(n, GRAPH_SCRATCH_BYTES // (16 * max(n, 1))))
    with backend.scope():
        graph = [wp.array(offsets, dtype=wp.int32), wp.array(edges[:, 1].astype(np.int32), dtype=wp.int32),
                 wp.array(lengths, dtype=wp.float64)]
        heap = wp.empty((per_group, n), dtype=wp.int32)
        position = wp.empty((per_group, n), dtype=wp.int32)
        group = wp.empty((per_group, n), dtype=wp.float64)
        for first in range(0, n, per_group):
            rows = min(per_group, n - first)
            wp.launch(local_boundary.graph_distances, dim=rows, inputs=[*graph, first],
                      outputs=[heap, position, group])
            distances[first:first + rows] = group.numpy()[:rows]
    return distances


#: bytes of a group of Dijkstra searches' scratch and distance rows (16 per handle and search)
GRAPH_SCRATCH_BYTES = 64 << 20


#: normal derivatives of the last cages, by cage arrays, settings and device: at most KEPT_CAGES of them and, past
#: the newest, KEPT_BYTES in all (a cage of 400 handles: 800 x 400 float64, 2.6 MB; of 4,898: 384 MB)
KEPT_CAGES = 4
KEPT_BYTES = 256 << 20
_KEPT_DERIVATIVES: collections.OrderedDict = collections.OrderedDict()
#: the data slopes of the kept cages (a bind asks three times: the wedge cut-off, resolution "auto", its warning)
_KEPT_SLOPES: dict = {}
_KEPT_LOCK = threading.Lock()
#: faces x handles per group of faces whose (faces, handles) arrays are formed at once (2 MB per float64 array;
#: the 4 x 4 systems' (faces, handles, 4) arrays 8 MB)
FACE_GROUP_HANDLES = 1 << 18


def local_data_bytes(cage: Cage) -> tuple[int, int, int]:
    """Bytes of the local data: its per-face normal derivatives, (F, L) float64, held on the host once computed (and
    as large again on the device while a boundary field is formed), and what computing them adds for a while: on the
    host the handles' graph distances (L, L) float64 and a group of faces' arrays (measured: 38 MB at 1,250 and 4,898
    handles), on the device the Dijkstra searches' scratch and a group's mean value coordinates.

    Returns
    -------
    kept : int
    work : int, on the host
    device_work : int

    Examples
    --------
    >>> from warp_stokes.geometry.cage import Cage
    >>> local_data_bytes(Cage(np.zeros((4, 3)), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]), "tet"))[0]
    128
    """
    n_faces, n_handles = len(cage.faces), cage.n_handles
    group = min(n_faces, max(1, FACE_GROUP_HANDLES // max(n_handles, 1))) * n_handles
    searches = min(n_handles, max(1, GRAPH_SCRATCH_BYTES // (16 * max(n_handles, 1))))
    return 8 * n_faces * n_handles, 8 * n_handles**2 + 20 * 8 * group, 16 * searches * n_handles + 8 * group


def normal_derivatives(cage: Cage, settings: LocalData = LocalData(), device=None) -> np.ndarray:
    """Per-face normal derivatives g of the handles' data, with sum_l g_l = 0 and sum_l g_l c_l = n_f.

    A bind needs them three times (the folded-edge cut-off, its resolution check and the ring data): those of the
    last cages are kept (:data:`KEPT_CAGES`, :data:`KEPT_BYTES`), keyed by the cage's arrays, the settings and the
    device, and returned read-only.

    Parameters
    ----------
    cage : Cage
    settings : LocalData
    device : None | str | Backend, where MVC is evaluated ("mvc-cut")

    Returns
    -------
    (F, L) float64, read-only, row f holds g_l for face f

    Examples
    --------
    >>> g = normal_derivatives(cage)                                                    # doctest: +SKIP
    >>> np.allclose(g.sum(axis=1), 0), np.allclose(g @ cage.vertices, unit_normals)     # doctest: +SKIP
    (True, True)
    """
    backend = Backend.of(device)
    cage, key = cage_key(cage, settings, backend)
    with _KEPT_LOCK:
        kept = _KEPT_DERIVATIVES.get(key)
        if kept is not None:
            _KEPT_DERIVATIVES.move_to_end(key)
    if kept is None:
        kept = _normal_derivatives(cage, settings, backend)
        kept.flags.writeable = False
        with _KEPT_LOCK:
            _KEPT_DERIVATIVES[key] = kept
            while len(_KEPT_DERIVATIVES) > 1 and (
                    len(_KEPT_DERIVATIVES) > KEPT_CAGES
                    or sum(g.nbytes for g in _KEPT_DERIVATIVES.values()) > KEPT_BYTES):
                _KEPT_DERIVATIVES.popitem(last=False)
            for stale in set(_KEPT_SLOPES) - set(_KEPT_DERIVATIVES):
                del _KEPT_SLOPES[stale]
    return kept


def cage_key(cage: Cage, settings: LocalData, backend: Backend) -> tuple[Cage, tuple]:
    """The cage with float64 vertices and int64 faces (what is computed from them), and the key of what is kept
    for it: its arrays, the settings and, for MVC's normal derivatives, the device."""
    vertices = np.ascontiguousarray(cage.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(cage.faces, dtype=np.int64)
    if vertices is not cage.vertices or faces is not cage.faces:
        cage = dataclasses.replace(cage, vertices=vertices, faces=faces)
    key = (vertices.shape, faces.shape, hashlib.sha1(vertices.tobytes() + faces.tobytes()).hexdigest(), settings,
           backend.alias if settings.model == "mvc-cut" else None)
    return cage, key


def _face_groups(cage: Cage):
    per_group = max(1, FACE_GROUP_HANDLES // max(cage.n_handles, 1))
    for first in range(0, len(cage.faces), per_group):
        yield slice(first, min(first + per_group, len(cage.faces)))


def _normal_derivatives(cage: Cage, settings: LocalData, backend: Backend) -> np.ndarray:
    v, f = cage.vertices, cage.faces
    mean_edge = float(np.linalg.norm(np.subtract(*v[face_edges(f)].transpose(1, 0, 2)), axis=1).mean())
    graph = cage_graph_distances(cage, backend)
    normals = unit_normals(cage)
    fold_ends = np.zeros(0, dtype=np.int64)
    if settings.model == "mvc-cut" and settings.fold_radius > 0:
        fold_ends = np.unique(folded_edges(cage, settings.fold_degrees))
    out = np.empty((len(f), len(v)))
    for group in _face_groups(cage):  # (faces, handles) arrays of a group at a time: thousands of handles fit
        corners = f[group]
        distance = np.minimum(np.minimum(graph[corners[:, 0]], graph[corners[:, 1]]), graph[corners[:, 2]])
        # inverse weights exp(-d / scale), shifted per face (only their ratios matter) so that none underflows to
        # 0 on the near handles
        inverse_weight = np.exp(-(distance - distance.min(axis=1, keepdims=True)) / (settings.falloff * mean_edge))
        start = np.zeros_like(distance)
        if settings.model == "mvc-cut":
            start = _mvc_normal_derivatives(cage, group, mean_edge, backend)
            start *= distance <= settings.radius * mean_edge
        # per face, the least weighted change to `start` that meets the constraints, on (1, c - centroid) for
        # conditioning: a (4, 4) system each, solved for the group's faces at once
        target = np.concatenate([np.zeros((len(corners), 1)), normals[group]], axis=1)  # (faces, 4)
        a = np.concatenate([np.ones((len(corners), len(v), 1)), v[None] - v[corners].mean(axis=1)[:, None]],
                           axis=2)  # (faces, L, 4)
        aw = a * inverse_weight[:, :, None]
        # stacked matrix products (BLAS): einsum's loops took half of the time at thousands of handles
        solve = np.linalg.inv(np.matmul(aw.transpose(0, 2, 1), a))
        change = np.matmul(solve, (target - np.matmul(start[:, None, :], a)[:, 0])[:, :, None])
        least = np.matmul(aw, np.matmul(solve, target[:, :, None]))[:, :, 0]
        start += np.matmul(aw, change)[:, :, 0]
        share = np.full((len(corners), 1), settings.least_norm_share if settings.model == "mvc-cut" else 1.0)
        if len(fold_ends):
            to_fold = distance[:, fold_ends].min(axis=1) / (settings.fold_radius * mean_edge)
            share = np.maximum(share, np.clip(2.0 - to_fold, 0.0, 1.0)[:, None])
        out[group] = (1.0 - share) * start + share * least
    return out


def data_slopes(cage: Cage, settings: LocalData = LocalData(), device=None) -> np.ndarray:
    """How steep the local data is around each handle: the largest |grad_T hat_l + g_l n_f| over all handles l and
    the faces f that have this handle as a corner.

    Parameters
    ----------
    cage : Cage
    settings : LocalData
    device : None | str | Backend, where MVC is evaluated ("mvc-cut")

    Returns
    -------
    (L,) float64, per unit length: the data extended a distance d from a point of those faces changes by at most d
    times this

    Examples
    --------
    >>> from warp_stokes.geometry.cage import check_cage
    >>> import trimesh
    >>> box = trimesh.creation.box(extents=[2, 2, 2])
    >>> slopes = data_slopes(check_cage((box.vertices, box.faces)), device="cpu")
    >>> slopes.shape, bool((slopes >= 1 / np.sqrt(2)).all())  # a hat falls from 1 to 0 over a height of sqrt(2)
    ((8,), True)
    """
    backend = Backend.of(device)
    derivatives = normal_derivatives(cage, settings, backend)
    _, key = cage_key(cage, settings, backend)
    with _KEPT_LOCK:
        kept = _KEPT_SLOPES.get(key)
    if kept is not None:
        return kept.copy()
    normals = unit_normals(cage)
    tangent = tangent_gradients(cage)
    face_slope = np.empty(len(cage.faces))
    for group in _face_groups(cage):
        gradient = derivatives[group, :, None] * normals[group, None, :]  # (faces, L, 3)
        faces = np.arange(group.stop - group.start)
        for corner in range(3):
            gradient[faces, cage.faces[group, corner]] += tangent[group, corner]
        face_slope[group] = np.sqrt(np.einsum("flk,flk->fl", gradient, gradient).max(axis=1))
    slope = np.zeros(cage.n_handles)
    for corner in range(3):
        np.maximum.at(slope, cage.faces[:, corner], face_slope)
    with _KEPT_LOCK:
        if key in _KEPT_DERIVATIVES:  # kept as long as its cage's derivatives are
            _KEPT_SLOPES[key] = slope.copy()
    return slope


def _mvc_normal_derivatives(cage: Cage, faces: slice, mean_edge: float, backend: Backend) -> np.ndarray:
    """(faces, L): MVC's outward normal derivative at the centroids of ``faces``, by a one-sided difference (MVC
    reproduces constants and linear functions, so the constraints hold up to the difference's rounding)."""
    f = cage.faces[faces]
    step = 1e-4 * mean_edge
    centroid = cage.vertices[f].mean(axis=1)
    w = mean_value_coordinates(cage, centroid + step * unit_normals(cage)[faces], device=backend)
    np.put_along_axis(w, f, np.take_along_axis(w, f, axis=1) - 1.0 / 3.0, axis=1)
    w /= step
    return w


def tangent_gradients(cage: Cage) -> np.ndarray:
    """(F, 3, 3): in-plane gradient of each corner's barycentric function, n x (opposite edge) / (2 area)."""
    p = cage.vertices[cage.faces]  # (F, 3, 3)
    area_normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # 2 A n
    double_area = np.linalg.norm(area_normal, axis=1)
    n = area_normal / double_area[:, None]
    opposite = np.stack([p[:, 2] - p[:, 1], p[:, 0] - p[:, 2], p[:, 1] - p[:, 0]], axis=1)
    return np.cross(n[:, None, :], opposite) / double_area[:, None, None]
