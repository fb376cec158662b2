"""The meshes to bind from what users have (:func:`load_scene`): a USD asset's mesh prims (:mod:`.usd.asset`), a
glTF/GLB scene's mesh nodes, or any other mesh file, arrays or trimesh object as one part (:mod:`.parts`)."""

from __future__ import annotations

import os

import numpy as np

from ..errors import MeshError
from .door import checked_input
from .load import load_surface, read_with_trimesh, with_vertex_uvs
from .naming import natural_key
from .parts import MeshPart, Scene
from .usd.asset import read_asset

__all__ = ["MeshPart", "Scene", "load_scene", "USD_EXTENSIONS", "is_usd", "gltf_mesh_nodes"]

USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")

def is_usd(source) -> bool:
    """Whether ``source`` is a path to a USD file (by its extension)."""
    return isinstance(source, (str, os.PathLike)) and os.fspath(source).lower().endswith(USD_EXTENSIONS)


def gltf_mesh_nodes(loaded) -> list[tuple[str, str, np.ndarray]]:
    """The mesh nodes of a trimesh scene read from a glTF/GLB file that have faces, as (scene graph node, geometry
    name, local-to-world matrix (column vectors)), in the order they are bound: the natural order of the node names
    (trimesh keeps no file order), the primitives of one node in their file order (trimesh hangs each under the node
    by a random name, so that name's order would change from one reading to the next).

    Examples
    --------
    >>> [node for node, _, _ in gltf_mesh_nodes(read_with_trimesh("Fox.glb", "scene"))]   # doctest: +SKIP
    ['fox']
    """
    import trimesh

    geometry_order = {name: k for k, name in enumerate(loaded.geometry)}  # the file's meshes and primitives, in order
    parents = loaded.graph.transforms.parents
    found = []
    for node in loaded.graph.nodes_geometry:
        matrix, geometry_name = loaded.graph[node]
        mesh = loaded.geometry.get(geometry_name)
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0 or len(mesh.faces) == 0:
            continue
        owner = parents.get(node, node) if mesh.metadata.get("from_gltf_primitive") else node
        found.append(((natural_key(str(owner)), geometry_order.get(geometry_name, 0)), str(node), geometry_name,
                      np.asarray(matrix, dtype=np.float64)))
    return [entry[1:] for entry in sorted(found, key=lambda entry: entry[0])]


def _gltf_scene(path: str) -> Scene:
    """The mesh nodes of a glTF/GLB scene, each in world space by its node's transform (trimesh's scene graph),
    in the order of :func:`gltf_mesh_nodes`."""
    loaded = read_with_trimesh(path, "scene")
    parts = []
    for node, geometry_name, matrix in gltf_mesh_nodes(loaded):
        mesh = loaded.geometry[geometry_name]
        to_world = matrix.T  # trimesh: column vectors; here: row vectors
        world = np.asarray(mesh.vertices, dtype=np.float64) @ to_world[:3, :3] + to_world[3, :3]
        surface = with_vertex_uvs(load_surface((world, np.asarray(mesh.faces)), name=f"{path}:{node}"), mesh)
        parts.append(MeshPart(node, surface, to_world))
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
        return read_asset(os.fspath(source), mesh_prims=mesh_prims, exclude=(cage_prim,) if cage_prim else (),
                          rest_time=rest_time, cage_prim=cage_prim)
    if mesh_prims:
        raise MeshError(f"{source}: mesh prims are named, but it is not a USD file")
    if isinstance(source, (str, os.PathLike)) and os.fspath(source).lower().endswith((".glb", ".gltf")):
        return _gltf_scene(checked_input(source, MeshError, "mesh"))
    surface = load_surface(source)
    return Scene((MeshPart(surface.name, surface),), surface.name)
