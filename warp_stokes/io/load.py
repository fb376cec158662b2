"""Loading meshes and cages from what users have: paths, trimesh objects, or (vertices, faces) arrays.

Vertex order is preserved exactly (no merging, no reordering): users map weights back to their own vertex ids.
"""

from __future__ import annotations

import io
import os
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..errors import MeshError
from .door import checked_input, gltf_dependencies, input_bytes, read_input, reason
from .obj import read_obj_with_usage

__all__ = ["Surface", "load_surface", "fan_triangles", "first_missing_vertex", "polygons_by_part", "EXTENTS",
           "COORDINATE_LIMIT", "finite_coordinates", "read_with_trimesh"]

#: the bounding diagonals the package's float32 kernels resolve, in any unit: a sphere binds and gets a cage at
#: diagonals of 3.5e-10 to 3.5e19; at 3.5e-11 the distances and inside tests lose the mesh, at 3.5e20 squared lengths
#: overflow (both ends kept about 30 times inside what was measured)
EXTENTS = (1e-8, 1e18)


@dataclass(frozen=True)
class Surface:
    """Vertices and triangles of a loaded mesh or cage.

    Attributes
    ----------
    vertices : (V, 3) float64 array
    faces : (F, 3) int64 array of triangles (polygons are fan-triangulated); may be empty for point sets
    name : str
        Where it came from (a path, or a description such as ``"<array>"``), used in error messages.
    normals : (V, 3) float64 or None
        Per-vertex normals when an OBJ file gives them (``vn`` records referenced by its faces); a vertex given
        several normals gets their normalised mean.
    face_counts, face_indices : int64 arrays or None
        The polygons as read (a quad stays a quad): each polygon's corner count and all corners' vertex ids, as in
        USD's ``faceVertexCounts`` / ``faceVertexIndices``; None when only the triangles are known.
    uvs : tuple (st (N, 2) float64, st_indices (len(face_indices),) int64) or None
        Texture coordinates per polygon corner (face-varying, indexed), when the file has them (OBJ ``vt``,
        a glTF/PLY mesh's per-vertex UVs).
    face_materials : (len(face_counts),) int64 or None
        Each polygon's material, a number among ``looks.materials`` (-1: none), where the looks were asked for
        and the file has materials.
    looks : :class:`~.looks.Looks` or None, the materials themselves
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str
    normals: np.ndarray | None = None
    face_counts: np.ndarray | None = None
    face_indices: np.ndarray | None = None
    uvs: tuple | None = None
    face_materials: np.ndarray | None = None
    looks: object | None = None

    def polygons(self) -> tuple[np.ndarray, np.ndarray]:
        """The polygons as read, ``(face_counts, face_indices)``; the triangles when no polygons were kept.

        Examples
        --------
        >>> counts, indices = load_surface((np.eye(4)[:, :3], [[0, 1, 2, 3]])).polygons()
        >>> counts.tolist(), indices.tolist()
        ([4], [0, 1, 2, 3])
        """
        if self.face_counts is not None:
            return self.face_counts, self.face_indices
        return np.full(len(self.faces), 3, dtype=np.int64), self.faces.ravel()


def polygons_by_part(face_counts, face_indices, part_slices) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each part's polygons and their corners, for polygons in part order each over its own part's vertices (a
    binding's layout): per part, (polygon numbers, corner positions in ``face_indices``).

    Examples
    --------
    >>> [(f.tolist(), c.tolist()) for f, c in polygons_by_part([3, 3], [0, 1, 2, 3, 4, 5], [slice(0, 3), slice(3, 6)])]
    [([0], [0, 1, 2]), ([1], [3, 4, 5])]
    """
    counts = np.asarray(face_counts, dtype=np.int64)
    indices = np.asarray(face_indices, dtype=np.int64)
    first_corner = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    face_part = np.searchsorted(np.array([s.stop for s in part_slices]), indices[first_corner], side="right")
    corner_part = np.repeat(face_part, counts)
    return [(np.flatnonzero(face_part == k), np.flatnonzero(corner_part == k)) for k in range(len(part_slices))]


def fan_triangles(face_counts, face_indices) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangles ``(first, k, k + 1)`` of polygons given as counts and flat corner indices (USD's layout),
    vectorised, each polygon's triangles together and in order; and the polygon of each triangle.

    Examples
    --------
    >>> triangles, polygon = fan_triangles([4, 3], [0, 1, 2, 3, 3, 2, 4])
    >>> triangles.tolist(), polygon.tolist()
    ([[0, 1, 2], [0, 2, 3], [3, 2, 4]], [0, 0, 1])
    """
    counts = np.asarray(face_counts, dtype=np.int64)
    corners = np.asarray(face_indices, dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]) if len(counts) else np.zeros(0, dtype=np.int64)
    n_fans = np.maximum(counts - 2, 0)
    polygon = np.repeat(np.arange(len(counts)), n_fans)
    k = np.arange(int(n_fans.sum())) - np.repeat(np.cumsum(n_fans) - n_fans, n_fans)
    start = first[polygon]
    triangles = np.stack([corners[start], corners[start + k + 1], corners[start + k + 2]], axis=1)
    return triangles.reshape(-1, 3), polygon


def first_missing_vertex(counts, corners, n_vertices: int) -> tuple[int, int] | None:
    """The first polygon that names a vertex outside ``0 .. n_vertices - 1``, as (its number among the faces, as a
    file counts them, not the fan triangles'; that vertex), or None.

    Examples
    --------
    >>> first_missing_vertex([3, 4], [0, 1, 2, 0, 2, 3, 8], 4)
    (1, 8)
    """
    corners = np.asarray(corners)
    outside = (corners < 0) | (corners >= n_vertices)
    if not outside.any():
        return None
    corner = int(np.flatnonzero(outside)[0])
    return int(np.searchsorted(np.cumsum(counts), corner, side="right")), int(corners[corner])


def _check_corners(counts: np.ndarray, corners: np.ndarray, n_vertices: int, name: str) -> None:
    """A one-line error for the first polygon that names a vertex the mesh does not have."""
    missing = first_missing_vertex(counts, corners, n_vertices)
    if missing is not None:
        raise MeshError(f"{name}: face {missing[0]} refers to vertex {missing[1]}, but there are only {n_vertices} "
                        "vertices")


#: the largest coordinate taken anywhere (vertices, cages, poses, frames): the diagonals' upper end, so that the
#: float32 arithmetic of the kernels and of the files written (USD points, glTF) holds every position and its square
COORDINATE_LIMIT = EXTENTS[1]


def finite_coordinates(values: np.ndarray, name: str, what: str = "vertex", error=MeshError) -> np.ndarray:
    """``values`` (..., 3) float64 when every coordinate is finite and within :data:`COORDINATE_LIMIT` in magnitude;
    else one ``error`` naming the first ``what`` (its index over the leading axes) that is not.

    Examples
    --------
    >>> finite_coordinates(np.array([[0.0, 1e300, 0.0]]), "p.npy", "point")
    Traceback (most recent call last):
    ...
    warp_stokes.errors.MeshError: p.npy: point 0 has a coordinate beyond 1e+18 ([0.0, 1e+300, 0.0]); scale it (to metres, say)
    """
    values = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(values) <= COORDINATE_LIMIT).all(axis=-1)
    if bad.any():
        where = np.argwhere(bad)[0]
        row = values[tuple(where)]
        index = ", ".join(str(int(i)) for i in where)
        if np.isfinite(row).all():
            raise error(f"{name}: {what} {index} has a coordinate beyond {COORDINATE_LIMIT:g} ({row.tolist()}); "
                        "scale it (to metres, say)")
        raise error(f"{name}: {what} {index} has a non-finite coordinate {row.tolist()}")
    return values


def _checked_vertices(vertices, name: str) -> np.ndarray:
    """(V, 3) float64 vertices, or a one-line error: not numbers, the wrong shape, none, non-finite, or an extent
    outside :data:`EXTENTS`."""
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"{name}: vertices are not a numeric array ({exc})") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"{name}: vertices must have shape (V, 3), got {v.shape}")
    if len(v) == 0:
        raise MeshError(f"{name}: the mesh has no vertices")
    if not np.isfinite(v).all():
        finite_coordinates(v, name, "vertex", MeshError)  # names the first vertex that is not finite
    with np.errstate(over="ignore"):
        diagonal = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    if diagonal > 0 and not EXTENTS[0] <= diagonal <= EXTENTS[1]:  # one point (or none apart) is said elsewhere
        raise MeshError(f"{name}: its bounding diagonal is {diagonal:.3g}, outside what the solver's float32 "
                        f"arithmetic resolves ({EXTENTS[0]:g} to {EXTENTS[1]:g} in any unit); "
                        "scale it (to metres, say)")
    finite_coordinates(v, name, "vertex", MeshError)  # and no coordinate beyond the limit (far from the origin)
    return np.ascontiguousarray(v)


def _polygon_surface(v: np.ndarray, counts: np.ndarray, corners: np.ndarray, name: str) -> Surface:
    """The surface of checked vertices ``v`` and polygons given as corner counts and flat corner indices (0-based,
    int64), fan-triangulated, each polygon's triangles together; a one-line error for a polygon of fewer than three
    corners or one naming a vertex the mesh does not have."""
    if (counts < 3).any():
        bad = int(np.flatnonzero(counts < 3)[0])
        raise MeshError(f"{name}: face {bad} has {counts[bad]} vertices; a face needs at least 3")
    _check_corners(counts, corners, len(v), name)
    triangles, _ = fan_triangles(counts, corners)
    return Surface(vertices=v, faces=np.ascontiguousarray(triangles, dtype=np.int64), name=name, face_counts=counts,
                   face_indices=corners)


def _from_arrays(vertices, faces, name: str) -> Surface:
    """A surface from vertices and faces: None, an (F, k) array, or a list of index lists (polygons)."""
    v = _checked_vertices(vertices, name)
    if faces is None or len(faces) == 0:
        return Surface(vertices=v, faces=np.zeros((0, 3), dtype=np.int64), name=name)
    if (faces.ndim == 2 if isinstance(faces, np.ndarray) else
            np.ndim(faces[0]) == 1 and len({len(x) for x in faces}) == 1):  # all polygons of one size
        rows = np.asarray(faces)
        if rows.shape[1] < 3:
            raise MeshError(f"{name}: faces must have at least 3 vertices, got an array of shape {rows.shape}")
        if not np.issubdtype(rows.dtype, np.integer):
            if not np.all(np.isfinite(rows)) or np.any(rows != np.round(rows)):
                raise MeshError(f"{name}: face indices must be integers")
        return _polygon_surface(v, np.full(len(rows), rows.shape[1], dtype=np.int64), rows.astype(np.int64).ravel(),
                                name)
    polys = [np.asarray(poly) for poly in faces]
    for i, poly in enumerate(polys):
        if poly.ndim != 1 or len(poly) < 3:
            raise MeshError(f"{name}: face {i} has {poly.size} vertices; a face needs at least 3")
    counts = np.array([len(p) for p in polys], dtype=np.int64)
    return _polygon_surface(v, counts, np.concatenate(polys).astype(np.int64), name)


def _from_polygons(vertices, counts: np.ndarray, corners: np.ndarray, name: str) -> Surface:
    """A surface from polygons of different sizes given as corner counts and flat corner indices (0-based)."""
    return _polygon_surface(_checked_vertices(vertices, name), counts, corners, name)


def with_vertex_uvs(surface: Surface, mesh) -> Surface:
    """``surface`` with the per-vertex UVs of a trimesh mesh (glTF, PLY), or of an (V, 2) array, as face-varying
    indexed coordinates."""
    uv = mesh if isinstance(mesh, np.ndarray) else getattr(getattr(mesh, "visual", None), "uv", None)
    if uv is None or len(uv) != len(surface.vertices) or np.ndim(uv) != 2 or np.shape(uv)[1] < 2:
        return surface
    counts, indices = surface.polygons()
    return _finite_attributes(replace(surface, face_counts=counts, face_indices=indices,
                                      uvs=(np.asarray(uv, dtype=np.float64)[:, :2].copy(), indices.copy())))


class _CheckedResolver:
    """trimesh's resolver for the files a glTF names, through the one door in: exactly the file named beside it
    (trimesh's own resolver tries other names, and so can read another file than the one named)."""

    def __init__(self, path: str):
        self.folder = os.path.dirname(os.path.abspath(path))
        self.name = path

    def get(self, key: str) -> bytes:
        from urllib.parse import unquote

        return read_input(os.path.join(self.folder, unquote(key)), MeshError, f"glTF resource ({self.name})")

    __getitem__ = get

    def keys(self):
        return []

    def namespaced(self, namespace: str):
        return _CheckedResolver(os.path.join(self.folder, namespace, "x"))

    def write(self, name, data):
        raise MeshError(f"{self.name}: reading it would write {name}")


def read_with_trimesh(path: str, force: str, data: bytes | None = None):
    """A mesh file trimesh reads (PLY, STL, OFF, glTF/GLB, ...), its bytes through the one door in: any failure to
    parse it, whatever trimesh raises, is one MeshError naming the file.

    Parameters
    ----------
    path : str
    force : "mesh" (all geometry as one mesh) or "scene" (the scene graph kept)
    data : bytes, optional, the file's contents where already read (through the door)
    """
    import trimesh

    ext = os.path.splitext(path)[1].lower().lstrip(".")
    if ext == "gltf":
        for dependency in gltf_dependencies(path, MeshError):
            checked_input(dependency, MeshError, f"glTF resource ({path})")
    data = input_bytes(path, MeshError, "mesh") if data is None else io.BytesIO(data)
    if ext == "stl":
        _check_stl(path, data.getvalue())
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # trimesh warns of what it then raises for
            return trimesh.load(data, file_type=ext, resolver=_CheckedResolver(path), force=force, process=False,
                                maintain_order=True)
    except MeshError:
        raise
    except Exception as exc:  # trimesh raises many different types for unreadable files, ImportError among them
        why = "not a valid file of this format" if isinstance(exc, ImportError) else reason(exc)
        raise MeshError(f"{path}: cannot read it as a {ext.upper() or 'mesh'} file ({why})") from None


def _check_stl(path: str, data: bytes) -> None:
    """An STL file whole: a binary one's size is what its triangle count says (trimesh reads a binary STL cut short
    as an empty mesh, or as text), a text one starts with ``solid`` and has facets."""
    if len(data) >= 84 and 84 + 50 * int.from_bytes(data[80:84], "little") == len(data):
        return  # binary, whole
    head = data[:1024].lstrip().lower()
    if head.startswith(b"solid") and (b"facet" in data[:1 << 16].lower() or b"endsolid" in data[-1024:].lower()):
        return  # text
    if len(data) >= 84:
        count = int.from_bytes(data[80:84], "little")
        raise MeshError(f"{path}: cannot read it as a STL file (a binary STL of {count} triangles has "
                        f"{84 + 50 * count} bytes, this file {len(data)}: cut short or damaged)")
    raise MeshError(f"{path}: cannot read it as a STL file (neither a binary STL nor one of text)")


def _finite_attributes(surface: "Surface") -> "Surface":
    """``surface`` without normals or texture coordinates that are not finite (dropped with a warning naming the
    file): a binding holds only finite numbers, and a mesh's shape does not depend on them."""
    normals, uvs = surface.normals, surface.uvs
    dropped = []
    if normals is not None and not np.isfinite(normals).all():
        normals = None
        dropped.append("normals")
    if uvs is not None and not np.isfinite(uvs[0]).all():
        uvs = None
        dropped.append("texture coordinates")
    if not dropped:
        return surface
    warnings.warn(f"{surface.name}: its {' and '.join(dropped)} are not all finite numbers; dropped", stacklevel=3)
    return replace(surface, normals=normals, uvs=uvs)


def _is_trimesh(source) -> bool:
    """Whether ``source`` is a trimesh.Trimesh, without importing trimesh (it can only be one if trimesh is loaded)."""
    import sys

    trimesh = sys.modules.get("trimesh")
    return trimesh is not None and isinstance(source, trimesh.Trimesh)


def load_surface(source, name: str | None = None, looks: bool = False) -> Surface:
    """Load a triangle surface (polygons are fan-triangulated) from a path, a trimesh object or arrays.

    Parameters
    ----------
    source : str | os.PathLike | trimesh.Trimesh | tuple(vertices, faces) | Surface
        A file trimesh can read (OBJ, PLY, OFF, STL, glTF/GLB, ...), a ``trimesh.Trimesh``, or a pair
        ``(vertices (V, 3), faces)`` where faces is an (F, k) integer array or a list of polygons
        (``faces`` may be ``None`` for a point set).
    name : str, optional
        Name used in error messages; defaults to the path or a description of the object.
    looks : bool, read an OBJ file's materials too (its ``.mtl`` files and the images they name: see
        :mod:`.looks`), into ``face_materials`` and ``looks``

    Returns
    -------
    Surface
        Vertices in the source's order (no merging) and triangles.

    Raises
    ------
    MeshError
        Unreadable or missing file, empty mesh, non-finite coordinates, out-of-range face indices.

    Examples
    --------
    >>> s = load_surface((np.eye(3), [[0, 1, 2]]))
    >>> s.vertices.shape, s.faces.tolist()
    ((3, 3), [[0, 1, 2]])
    """
    if isinstance(source, Surface):
        return source
    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        name = name or path
        checked_input(path, MeshError, "mesh")
        if path.lower().endswith(".obj"):
            verts, polys, normals, uvs, usage = read_obj_with_usage(path)
            if len(verts) == 0:
                raise MeshError(f"{path}: the file has no vertices")
            surface = _from_arrays(verts, polys, name) if not isinstance(polys, tuple) else \
                _from_polygons(verts, *polys, name)
            surface = _finite_attributes(replace(surface, normals=normals, uvs=uvs))
            if looks and usage is not None:
                from .looks_in import mtl_looks

                libraries, used, face_used = usage
                read, numbers = mtl_looks(path, libraries, used)
                if read is not None:
                    number = np.append(np.asarray(numbers, dtype=np.int64), -1)  # (-1: no usemtl before the face)
                    surface = replace(surface, face_materials=number[face_used], looks=read)
            return surface
        import trimesh  # here only: importing it takes half a second, and OBJ files do not need it

        loaded = read_with_trimesh(path, "mesh")
        if not isinstance(loaded, trimesh.Trimesh) or len(loaded.vertices) == 0:
            raise MeshError(f"{path}: the file has no mesh vertices")
        return with_vertex_uvs(_from_arrays(loaded.vertices, loaded.faces, name), loaded)
    if _is_trimesh(source):
        return with_vertex_uvs(_from_arrays(source.vertices, source.faces, name or "<trimesh.Trimesh>"), source)
    if isinstance(source, (tuple, list)) and len(source) == 2:
        return _from_arrays(source[0], source[1], name or "<arrays>")
    raise MeshError(
        f"{name or '<input>'}: expected a path, a trimesh.Trimesh or a (vertices, faces) pair, "
        f"got {type(source).__name__}"
    )
