"""A character as pipelines hold it: one or several meshes ("parts"), each with its place in the world.

A USD asset gives its ``UsdGeom.Mesh`` prims, a glTF/GLB scene its mesh nodes, any other file one part. All parts
are bound together, in world space at the rest time; each keeps its transform so that the animation can be written
back in its own local space.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import MeshError
from .door import checked_input
from .load import Surface, load_surface, read_with_trimesh, with_vertex_uvs

__all__ = ["MeshPart", "Scene", "load_scene", "USD_EXTENSIONS", "is_usd"]

USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")


def is_usd(source) -> bool:
    """Whether ``source`` is a path to a USD file (by its extension)."""
    return isinstance(source, (str, os.PathLike)) and os.fspath(source).lower().endswith(USD_EXTENSIONS)


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
    """

    parts: tuple
    name: str
    asset: str | None = None
    metadata: dict = field(default_factory=dict)

    def surface(self) -> Surface:
        """All parts as one surface (vertices, triangles and polygons concatenated in part order).

        Examples
        --------
        >>> a = load_surface((np.eye(3), [[0, 1, 2]]))
        >>> Scene((MeshPart("a", a), MeshPart("b", a)), "two").surface().faces.tolist()
        [[0, 1, 2], [3, 4, 5]]
        """
        if len(self.parts) == 1:
            return self.parts[0].surface
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

            warnings.warn(f"{self.name}: the UVs of its meshes are dropped: {len(without)} of {len(self.parts)} have "
                          f"none (e.g. {without[0]})", stacklevel=2)
        if not without:
            st_offsets = np.cumsum([0] + [len(s.uvs[0]) for s in surfaces])
            uvs = (np.concatenate([s.uvs[0] for s in surfaces]),
                   np.concatenate([s.uvs[1] + o for s, o in zip(surfaces, st_offsets)]))
        return Surface(
            vertices=np.concatenate([s.vertices for s in surfaces]),
            faces=np.concatenate([s.faces + o for s, o in zip(surfaces, offsets)]),
            name=self.name, normals=normals,
            face_counts=np.concatenate([c for c, _ in polygons]),
            face_indices=np.concatenate([i + o for (_, i), o in zip(polygons, offsets)]),
            uvs=uvs,
        )

    def vertex_offsets(self) -> np.ndarray:
        """(P + 1,) where each part's vertices start in :meth:`surface`, and the total."""
        return np.cumsum([0] + [len(p.surface.vertices) for p in self.parts])


def _gltf_scene(path: str) -> Scene:
    """The mesh nodes of a glTF/GLB scene, each in world space by its node's transform (trimesh's scene graph),
    in the natural order of the node names (trimesh keeps no file order)."""
    import trimesh

    from .poses import natural_key

    loaded = read_with_trimesh(path, "scene")
    parts = []
    for node in sorted(loaded.graph.nodes_geometry, key=lambda n: natural_key(str(n))):
        matrix, geometry_name = loaded.graph[node]
        mesh = loaded.geometry.get(geometry_name)
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0 or len(mesh.faces) == 0:
            continue
        to_world = np.asarray(matrix, dtype=np.float64).T  # trimesh: column vectors; here: row vectors
        world = np.asarray(mesh.vertices, dtype=np.float64) @ to_world[:3, :3] + to_world[3, :3]
        surface = with_vertex_uvs(load_surface((world, np.asarray(mesh.faces)), name=f"{path}:{node}"), mesh)
        parts.append(MeshPart(str(node), surface, to_world))
    if not parts:
        raise MeshError(f"{path}: the scene has no meshes with faces")
    return Scene(tuple(parts), path)


def load_scene(source, mesh_prims=None, cage_prim: str | None = None, rest_time=None) -> Scene:
    """The meshes to bind from what users have.

    Parameters
    ----------
    source : path | trimesh.Trimesh | (vertices, faces) | Surface | Scene
        A USD asset (``.usd/.usda/.usdc/.usdz``: its ``UsdGeom.Mesh`` prims), a glTF/GLB scene (its mesh
        nodes), or anything :func:`load_surface` reads (one part).
    mesh_prims : list of str, optional
        For a USD asset, the prims to bind (default: every mesh prim except those in ``exclude``).
    cage_prim : str, optional
        For a USD asset, the cage's prim: not bound by default, and its first time sample is the rest time.
    rest_time : float, optional
        For a USD asset, the time code at which the rest pose is read (default: the cage prim's first time
        sample, else the stage's earliest).

    Returns
    -------
    Scene

    Raises
    ------
    MeshError
        Unreadable file, a named prim that is missing or not a mesh, no meshes at all.

    Examples
    --------
    >>> scene = load_scene((np.eye(3), [[0, 1, 2]]))
    >>> [p.path for p in scene.parts], scene.asset
    (['<arrays>'], None)
    """
    if isinstance(source, Scene):
        return source
    if is_usd(source):
        from .usd.asset import read_asset

        return read_asset(os.fspath(source), mesh_prims=mesh_prims, exclude=(cage_prim,) if cage_prim else (),
                          rest_time=rest_time, cage_prim=cage_prim)
    if mesh_prims:
        raise MeshError(f"{source}: mesh prims are named, but it is not a USD file")
    if isinstance(source, (str, os.PathLike)) and os.fspath(source).lower().endswith((".glb", ".gltf")):
        return _gltf_scene(checked_input(source, MeshError, "mesh"))
    surface = load_surface(source)
    return Scene((MeshPart(surface.name, surface),), surface.name)
