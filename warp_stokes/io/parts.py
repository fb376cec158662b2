"""A character as pipelines hold it: one or several meshes ("parts"), each with its place in the world.

A USD asset gives its ``UsdGeom.Mesh`` prims, a glTF/GLB scene its mesh nodes, any other file one part. All parts
are bound together, in world space at the rest time; each keeps its transform so that the animation can be written
back in its own local space. The readers that make them are in :mod:`.scene` and :mod:`.usd.asset`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .load import Surface, load_surface  # noqa: F401 (load_surface: the examples use it)

__all__ = ["MeshPart", "Scene"]


@dataclass(frozen=True)
class MeshPart:
    """One mesh of a scene.

    Attributes
    ----------
    path : str, the USD prim path, glTF node name, or the mesh's name for a single-mesh file
    surface : Surface, its vertices in world space at the rest time, its triangles and polygons
    to_world : (4, 4) float64, local-to-world at the rest time, row-vector convention (``[p, 1] @ to_world``)
    normals : str or None, the interpolation of the normals its asset authors (recomputed per frame), else None
    """

    path: str
    surface: Surface
    to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    normals: str | None = None


@dataclass(frozen=True)
class Scene:
    """The meshes to bind, and where they came from.

    Attributes
    ----------
    parts : tuple of MeshPart
    name : str, the source (for messages)
    asset : str or None, the absolute path of the USD asset the parts are prims of (the animation is then
        written as a layer over it)
    metadata : dict, the asset's stage metadata: ``up_axis``, ``meters_per_unit``, ``default_prim``,
        ``time_codes_per_second``, ``rest_time``
    looks : :class:`~.looks.Looks` or None, the materials the parts' ``face_materials`` number (a glTF's; an OBJ's
        are its one part's surface's own)
    """

    parts: tuple
    name: str
    asset: str | None = None
    metadata: dict = field(default_factory=dict)
    looks: object | None = None

    def surface(self) -> Surface:
        """All parts as one surface (vertices, triangles and polygons concatenated in part order).

        Examples
        --------
        >>> a = load_surface((np.eye(3), [[0, 1, 2]]))
        >>> Scene((MeshPart("a", a), MeshPart("b", a)), "two").surface().faces.tolist()
        [[0, 1, 2], [3, 4, 5]]
        """
        if len(self.parts) == 1:
            only = self.parts[0].surface
            return only if self.looks is None else replace(only, looks=self.looks)
        offsets = self.vertex_offsets()
        surfaces = [p.surface for p in self.parts]
        polygons = [s.polygons() for s in surfaces]
        normals = None
        if all(s.normals is not None for s in surfaces):
            normals = np.concatenate([s.normals for s in surfaces])
        uvs = None
        without = [p.path for p in self.parts if p.surface.uvs is None]
        if without and len(without) < len(self.parts):
            import warnings

            # the others keep theirs (and their textures): one UV (0, 0) at every corner of a mesh without any
            warnings.warn(f"{self.name}: {len(without)} of its {len(self.parts)} meshes have no UVs (e.g. "
                          f"{without[0]}); they are given (0, 0)", stacklevel=2)
            surfaces = [s if s.uvs is not None else
                        replace(s, uvs=(np.zeros((1, 2)), np.zeros(len(c[1]), dtype=np.int64)))
                        for s, c in zip(surfaces, polygons)]
        if len(without) < len(self.parts):
            st_offsets = np.cumsum([0] + [len(s.uvs[0]) for s in surfaces])
            uvs = (np.concatenate([s.uvs[0] for s in surfaces]),
                   np.concatenate([s.uvs[1] + o for s, o in zip(surfaces, st_offsets)]))
        return Surface(
            vertices=np.concatenate([s.vertices for s in surfaces]),
            faces=np.concatenate([s.faces + o for s, o in zip(surfaces, offsets)]),
            name=self.name, normals=normals,
            face_counts=np.concatenate([c for c, _ in polygons]),
            face_indices=np.concatenate([i + o for (_, i), o in zip(polygons, offsets)]),
            uvs=uvs, face_materials=self._face_materials([c for c, _ in polygons]),
            looks=self.looks or next((s.looks for s in surfaces if s.looks is not None), None),
        )

    def _face_materials(self, counts: list) -> np.ndarray | None:
        """The parts' polygons' materials, in part order (-1 for a part without any), or None where none has any."""
        surfaces = [p.surface for p in self.parts]
        if all(s.face_materials is None for s in surfaces):
            return None
        return np.concatenate([np.full(len(c), -1, dtype=np.int64) if s.face_materials is None else s.face_materials
                               for s, c in zip(surfaces, counts)])

    def vertex_offsets(self) -> np.ndarray:
        """(P + 1,) where each part's vertices start in :meth:`surface`, and the total."""
        return np.cumsum([0] + [len(p.surface.vertices) for p in self.parts])
