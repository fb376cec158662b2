"""The Binding: a mesh's weights with respect to its cage, that deforms the mesh when the cage moves, saved to and
loaded from ``.npz`` files."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import warp as wp

from .. import __version__
from ..device import Backend
from ..errors import BindingError, WarpStokesError
from ..io.door import read_numpy
from ..io.outputs import atomic_output
from ..io.load import Surface, load_surface
from ..io.poses import pose_vertices
from .deform import deform_on_host, deform_vertices
from .record import check_metadata
from .stats import BindStats

__all__ = ["Binding", "load_binding", "fingerprint", "FORMAT"]

#: identifies files written by Binding.save; bump the number when the layout changes
FORMAT = "warp-stokes-binding/1"


def fingerprint(vertices: np.ndarray, faces: np.ndarray) -> str:
    """SHA-256 of a mesh's vertex positions (float64) and faces (int64), as hex."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return digest.hexdigest()


class Binding:
    """Weights of a mesh with respect to a cage, and what is needed to deform the mesh with it.

    Attributes
    ----------
    weights : (V, L) float32 numpy array; row j holds vertex j's weight for each handle, rows sum to one
    cage_vertices, cage_faces : the rest cage (faces outward oriented)
    mesh_vertices, mesh_faces : the rest mesh
    mesh_normals : (V, 3) rest normals when the mesh file had them, else None
    cage_source_index : for a cage merged from a triangle soup, the handle of each of its source's vertices
    mesh_face_counts, mesh_face_indices : the mesh's polygons as read (quads stay quads), over all parts
    mesh_uvs : (st (N, 2), st_indices per polygon corner) face-varying texture coordinates, or None
    parts : list of dict, the meshes bound together, in the order of their vertices: ``path`` (USD prim path,
        glTF node or file), ``vertices`` (count), ``normals`` (the interpolation of the normals their asset
        authors, or None) and ``to_world`` (4 x 4 local-to-world at the rest time, row vectors)
    asset : dict or None, for a binding of a USD asset: ``path`` (absolute, at bind time), ``up_axis``,
        ``meters_per_unit``, ``default_prim``, ``time_codes_per_second`` and ``rest_time``
    settings : dict of the grid and solver settings used
    stats : BindStats, what the bind measured (or its record, as a binding file holds it)
    sources : list of str, the files it was bound from (real paths: the mesh's and the cage's, each USD file's
        whole layer stack): a command's output never replaces one of them
    batch_inputs : str or None, for a binding a batch wrote: the digest of the asset's inputs and entry, which a
        later run compares to know the asset is up to date
    looks : :class:`~warp_stokes.io.looks.Looks` or None, the mesh's materials (a glTF's, an OBJ's ``.mtl``), with
        their images by path and digest: glTF and standalone USD outputs carry them (see :mod:`warp_stokes.io.looks`)
    mesh_face_materials : (len(mesh_face_counts),) int64 or None, each polygon's material among ``looks.materials``
        (-1: none)
    device : the Warp device ``deform`` runs on
    """

    def __init__(self, weights, cage_vertices, cage_faces, mesh_vertices, mesh_faces, settings, stats,
                 device=None, mesh_normals=None, cage_source_index=None, mesh_polygons=None, mesh_uvs=None,
                 parts=None, asset=None, sources=None, batch_inputs=None, looks=None, mesh_face_materials=None):
        self.weights = np.ascontiguousarray(weights, dtype=np.float32)
        self.cage_vertices = np.asarray(cage_vertices, dtype=np.float64)
        self.cage_faces = np.asarray(cage_faces, dtype=np.int64)
        self.mesh_vertices = np.asarray(mesh_vertices, dtype=np.float64)
        self.mesh_faces = np.asarray(mesh_faces, dtype=np.int64)
        self.mesh_normals = None if mesh_normals is None else np.asarray(mesh_normals, dtype=np.float64)
        self.cage_source_index = None if cage_source_index is None else np.asarray(cage_source_index, dtype=np.int64)
        if mesh_polygons is None:
            mesh_polygons = (np.full(len(self.mesh_faces), 3), self.mesh_faces.ravel())
        self.mesh_face_counts = np.asarray(mesh_polygons[0], dtype=np.int64)
        self.mesh_face_indices = np.asarray(mesh_polygons[1], dtype=np.int64)
        self.mesh_uvs = None if mesh_uvs is None else (np.asarray(mesh_uvs[0], dtype=np.float64),
                                                        np.asarray(mesh_uvs[1], dtype=np.int64))
        self.parts = [dict(p) for p in parts] if parts else [
            {"path": settings.get("mesh", "mesh"), "vertices": len(self.mesh_vertices), "normals": None,
             "to_world": np.eye(4).tolist()}]
        self.asset = None if asset is None else dict(asset)
        self.settings = dict(settings)
        self.stats = stats if isinstance(stats, BindStats) else BindStats.from_record(stats)
        self.sources = list(sources or [])
        self.batch_inputs = batch_inputs
        self.looks = looks
        self.mesh_face_materials = None if looks is None or mesh_face_materials is None else \
            np.asarray(mesh_face_materials, dtype=np.int64)
        self.backend = Backend.of(device)
        self._weights_t = None

    @property
    def device(self):
        """The Warp device ``deform`` runs on."""
        return self.backend.device

    @property
    def n_vertices(self) -> int:
        return self.weights.shape[0]

    @property
    def n_handles(self) -> int:
        return self.weights.shape[1]

    def __repr__(self) -> str:
        parts = f", {len(self.parts)} meshes" if len(self.parts) > 1 else ""
        method = self.settings.get("method", "stokes")
        how = "mean value coordinates" if method == "mvc" else f"{method}, resolution {self.settings.get('resolution')}"
        return f"Binding({self.n_vertices} vertices{parts}, {self.n_handles} handles, {how})"

    def part_slices(self) -> list:
        """Each part's rows of ``weights`` (and of the deformed vertices), in the order of :attr:`parts`."""
        offsets = np.cumsum([0] + [int(p["vertices"]) for p in self.parts])
        return [slice(int(a), int(b)) for a, b in zip(offsets[:-1], offsets[1:])]

    def _check_topology(self, surface: Surface) -> np.ndarray:
        return pose_vertices(surface.vertices, surface.faces, self.cage_faces, self.cage_source_index, surface.name)

    def deform(self, poses):
        """Deformed mesh vertices ``p' = W c'`` for one cage pose or a batch.

        Parameters
        ----------
        poses : (L, 3) or (F, L, 3) array, a Warp vec3 array (L,) or (F, L), or a deformed cage with the bound
            cage's topology (a path, a trimesh.Trimesh or a ``(vertices, faces)`` tuple)

        Returns
        -------
        (V, 3) or (F, V, 3) float32 numpy array (a Warp vec3 array on ``self.device`` for Warp input)

        Raises
        ------
        BindingError
            When a deformed cage's vertex count or faces differ from the bound cage's.
        WarpStokesError
            When an array has the wrong shape or non-finite values.

        Examples
        --------
        >>> rest = b.deform(b.cage_vertices)                       # doctest: +SKIP
        >>> frames = b.deform(np.stack([cage0, cage1, cage2]))       # doctest: +SKIP
        """
        is_cage = isinstance(poses, (str, os.PathLike)) or type(poses).__name__ == "Trimesh" or (
            isinstance(poses, tuple) and len(poses) == 2 and np.issubdtype(np.asarray(poses[1]).dtype, np.integer)
        )
        if is_cage:
            poses = self._check_topology(load_surface(poses))
        if self.backend.on_cpu and not isinstance(poses, wp.array):
            return deform_on_host(self.weights, poses)
        if self._weights_t is None:
            self._weights_t = wp.array(np.ascontiguousarray(self.weights.T), dtype=wp.float32,
                                       device=self.backend.device)
        return deform_vertices(self._weights_t, poses, device=self.backend)

    def save(self, path) -> None:
        """Write the binding to ``path`` (a .npz file), atomically: a temporary file renamed when complete.

        Parameters
        ----------
        path : str | os.PathLike
        """
        path = os.fspath(path)
        meta = {
            "format": FORMAT,
            "version": __version__,
            "settings": self.settings,
            "stats": self.stats.record(),
            "cage_fingerprint": fingerprint(self.cage_vertices, self.cage_faces),
            "mesh_fingerprint": fingerprint(self.mesh_vertices, self.mesh_faces),
            "parts": self.parts,
            "asset": self.asset,
            "sources": self.sources,
            "batch_inputs": self.batch_inputs,
        }
        if self.looks is not None:
            meta["looks"] = self.looks.record()
        optional = {"mesh_face_counts": self.mesh_face_counts, "mesh_face_indices": self.mesh_face_indices}
        if self.mesh_normals is not None:
            optional["mesh_normals"] = self.mesh_normals
        if self.cage_source_index is not None:
            optional["cage_source_index"] = self.cage_source_index
        if self.mesh_uvs is not None:
            optional["mesh_st"], optional["mesh_st_indices"] = self.mesh_uvs
        if self.mesh_face_materials is not None:
            optional["mesh_face_materials"] = self.mesh_face_materials
        check_metadata(json.loads(json.dumps(meta)), path, *self.weights.shape)  # as a reader will find it
        try:
            with atomic_output(path, ".npz") as tmp, open(tmp, "wb") as fh:
                np.savez(
                    fh,
                    weights=self.weights,
                    cage_vertices=self.cage_vertices,
                    cage_faces=self.cage_faces,
                    mesh_vertices=self.mesh_vertices,
                    mesh_faces=self.mesh_faces,
                    meta=np.array(json.dumps(meta)),
                    **optional,
                )
        except WarpStokesError as exc:
            raise BindingError(str(exc)) from None


def load_binding(path, device=None) -> Binding:
    """Read a binding written by :meth:`Binding.save`.

    Parameters
    ----------
    path : str | os.PathLike
    device : None | str, where ``deform`` will run (default: CUDA when present)

    Returns
    -------
    Binding

    Raises
    ------
    BindingError
        Missing or unreadable file, not a warp-stokes binding, or inconsistent contents.

    Examples
    --------
    >>> b = load_binding("arm.npz")   # doctest: +SKIP
    """
    path = os.fspath(path)
    arrays = read_numpy(path, BindingError, "binding")
    if not isinstance(arrays, dict):
        raise BindingError(f"{path}: not a warp-stokes binding (a single array, not an archive)")
    needed = {"weights", "cage_vertices", "cage_faces", "mesh_vertices", "mesh_faces", "meta"}
    if not needed <= set(arrays):
        raise BindingError(f"{path}: not a warp-stokes binding (missing {sorted(needed - set(arrays))})")
    try:
        if arrays["meta"].dtype.kind != "U" or arrays["meta"].shape != ():
            raise ValueError
        meta = json.loads(str(arrays["meta"]))
    except ValueError:
        raise BindingError(f"{path}: the binding's metadata is corrupt") from None
    if not isinstance(meta, dict):
        raise BindingError(f"{path}: the binding's metadata is not a record (a {type(meta).__name__})")
    if meta.get("format") != FORMAT:
        raise BindingError(f"{path}: unsupported binding format {meta.get('format')!r} (this version reads {FORMAT})")
    _check_contents(path, arrays, meta)
    check_metadata(meta, path, *arrays["weights"].shape)
    w = arrays["weights"]
    if fingerprint(arrays["cage_vertices"], arrays["cage_faces"]) != meta.get("cage_fingerprint") or fingerprint(
        arrays["mesh_vertices"], arrays["mesh_faces"]
    ) != meta.get("mesh_fingerprint"):
        raise BindingError(f"{path}: the stored cage or mesh does not match its fingerprint (file modified?)")
    polygons = uvs = None
    if "mesh_face_counts" in arrays and "mesh_face_indices" in arrays:
        polygons = arrays["mesh_face_counts"], arrays["mesh_face_indices"]
    if "mesh_st" in arrays and "mesh_st_indices" in arrays:
        uvs = arrays["mesh_st"], arrays["mesh_st_indices"]
    parts = meta.get("parts")
    looks = _stored_looks(path, arrays, meta)
    return Binding(
        w, arrays["cage_vertices"], arrays["cage_faces"], arrays["mesh_vertices"], arrays["mesh_faces"],
        meta["settings"], meta["stats"], device=device, mesh_normals=arrays.get("mesh_normals"),
        cage_source_index=arrays.get("cage_source_index"), mesh_polygons=polygons, mesh_uvs=uvs, parts=parts,
        asset=meta.get("asset"), sources=meta.get("sources"), batch_inputs=meta.get("batch_inputs"),
        looks=looks, mesh_face_materials=arrays.get("mesh_face_materials") if looks is not None else None,
    )


def _stored_looks(path: str, arrays: dict, meta: dict):
    """The looks a binding file records (None for one that records none), checked whole with the polygons'
    materials: each a number among the materials, or -1."""
    if meta.get("looks") is None:
        return None
    from ..io.looks import Looks

    looks = Looks.from_record(meta["looks"], path)
    if "mesh_face_materials" in arrays:
        materials = arrays["mesh_face_materials"]
        polygons = len(arrays["mesh_face_counts"]) if "mesh_face_counts" in arrays else len(arrays["mesh_faces"])
        if materials.dtype.kind not in "iu" or materials.shape != (polygons,) or (materials.size and (
                materials.min() < -1 or materials.max() >= len(looks.materials))):
            raise BindingError(f"{path}: the binding's mesh_face_materials must be one material number (-1 to "
                               f"{len(looks.materials) - 1}) per polygon of its {polygons}")
    return looks


def _array(path: str, arrays: dict, name: str, kind: str, columns: int | None, rows: int | None = None,
           below: int | None = None) -> None:
    """One stored array checked: its dtype kind ("f" numbers, finite; "i" integers within [0, below)), its columns
    and rows; a BindingError naming the file and the array otherwise."""
    a = arrays[name]
    numbers = a.dtype.kind in ("biuf" if kind == "f" else "iu")
    if not numbers or (columns is not None and (a.ndim != 2 or a.shape[1] != columns)) or (
            columns is None and a.ndim != 1) or (rows is not None and len(a) != rows):
        shape = "rows" if columns is None else f"rows of {columns}"
        raise BindingError(f"{path}: the binding's {name} must be {'numbers' if kind == 'f' else 'integers'} in "
                           f"{rows if rows is not None else 'any number of'} {shape}; got {a.dtype} of shape {a.shape}")
    if kind == "f" and not np.isfinite(a).all():
        raise BindingError(f"{path}: the binding's {name} are not all finite")
    if kind == "i" and a.size and (a.min() < 0 or (below is not None and a.max() >= below)):
        raise BindingError(f"{path}: the binding's {name} run from {a.min()} to {a.max()}, outside [0, {below})")


def _check_contents(path: str, arrays: dict, meta: dict) -> None:
    """Every array and record a binding holds, checked before any of it is used: a file written by hand or by
    another tool gets one error naming what is wrong, never a traceback or an output with out-of-range faces or NaN
    points."""
    n_cage = len(arrays["cage_vertices"])
    _array(path, arrays, "cage_vertices", "f", 3)
    _array(path, arrays, "cage_faces", "i", 3, below=n_cage)
    _array(path, arrays, "mesh_vertices", "f", 3)
    n_mesh = len(arrays["mesh_vertices"])
    _array(path, arrays, "mesh_faces", "i", 3, below=n_mesh)
    _array(path, arrays, "weights", "f", n_cage, rows=n_mesh)
    if "mesh_normals" in arrays:
        _array(path, arrays, "mesh_normals", "f", 3, rows=n_mesh)
    if "cage_source_index" in arrays:
        _array(path, arrays, "cage_source_index", "i", None, below=n_cage)
    if "mesh_face_counts" in arrays and "mesh_face_indices" in arrays:
        _array(path, arrays, "mesh_face_counts", "i", None)
        _array(path, arrays, "mesh_face_indices", "i", None, below=n_mesh)
        if arrays["mesh_face_counts"].sum() != len(arrays["mesh_face_indices"]):
            raise BindingError(f"{path}: the stored polygons do not match the mesh")
    if "mesh_st" in arrays and "mesh_st_indices" in arrays:
        _array(path, arrays, "mesh_st", "f", 2)
        _array(path, arrays, "mesh_st_indices", "i", None, below=len(arrays["mesh_st"]))
        corners = len(arrays["mesh_face_indices"]) if "mesh_face_indices" in arrays else 3 * len(arrays["mesh_faces"])
        if len(arrays["mesh_st_indices"]) != corners:
            raise BindingError(f"{path}: the binding's mesh_st_indices name {len(arrays['mesh_st_indices'])} face "
                               f"corners; the mesh has {corners}")
