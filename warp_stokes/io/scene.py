"""The meshes to bind from what users have (:func:`load_scene`): a USD asset's mesh prims (:mod:`.usd.asset`), a
glTF/GLB scene's mesh nodes, or any other mesh file, arrays or trimesh object as one part (:mod:`.parts`)."""

from __future__ import annotations

import os
import warnings
from collections import Counter
from dataclasses import replace

import numpy as np

from ..errors import MeshError
from .door import checked_input, read_input
from .load import load_surface, read_with_trimesh, with_vertex_uvs
from .looks_in import texture_coordinates
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
    name, local-to-world matrix (column vectors)), in the order they are bound (by ``bind`` and by
    :func:`warp_stokes.io.skinned.load_frames`, which must agree): the natural order of the node names (trimesh keeps no
    file order), the primitives of one node in their file order (trimesh hangs each under the node by a random name,
    so that name's order would change from one reading to the next).

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


def _gltf_scene(path: str, looks: bool = True) -> Scene:
    """The mesh nodes of a glTF/GLB scene, each in world space by its node's transform (trimesh's scene graph),
    in the order of :func:`gltf_mesh_nodes`; with ``looks``, its materials and each part's (:mod:`.looks_in`).

    A node whose mesh has several primitives gives a part per primitive, named ``NODE.K`` by the primitive's number
    (trimesh names them by random suffixes)."""
    data = read_input(path, MeshError, "mesh")
    loaded = read_with_trimesh(path, "scene", data)
    gltf, primitives, scene_looks = _gltf_materials(path, data, loaded, looks)
    per_mesh = Counter(m for m, _, _ in primitives.values())
    parents = loaded.graph.transforms.parents
    parts = []
    for node, geometry_name, matrix in gltf_mesh_nodes(loaded):
        mesh = loaded.geometry[geometry_name]
        m, p, material = primitives.get(geometry_name, (None, None, None))
        name = f"{parents.get(node, node)}.{p}" if per_mesh.get(m, 0) > 1 else str(node)
        to_world = matrix.T  # trimesh: column vectors; here: row vectors
        world = np.asarray(mesh.vertices, dtype=np.float64) @ to_world[:3, :3] + to_world[3, :3]
        surface = with_vertex_uvs(load_surface((world, np.asarray(mesh.faces)), name=f"{path}:{name}"), mesh)
        if surface.uvs is None and m is not None:  # trimesh reads a primitive's UVs only where it has a material
            surface = with_vertex_uvs(surface, texture_coordinates(gltf, m, p))
        if scene_looks is not None:
            number = material if material is not None and 0 <= material < len(scene_looks.materials) else -1
            surface = replace(surface, face_materials=np.full(len(surface.polygons()[0]), number, dtype=np.int64))
        parts.append(MeshPart(name, surface, to_world))
    if not parts:
        raise MeshError(f"{path}: the scene has no meshes with faces")
    return Scene(tuple(parts), path, looks=scene_looks)


def _gltf_materials(path: str, data: bytes, loaded, looks: bool):
    """The file read (:class:`~.gltf_file.GltfFile`), the glTF primitive of each of trimesh's geometries (name
    -> (mesh, primitive, material)) and, with ``looks``, the file's looks; none of these (with a warning where it has
    materials) where the primitives cannot be matched to the geometries with certainty: no materials rather than
    materials on the wrong parts."""
    from .gltf_file import GltfDamaged, GltfFile
    from .looks_in import gltf_looks, gltf_primitives, position_count

    try:
        gltf = GltfFile(path, data)
        primitives = gltf_primitives(gltf)
    except GltfDamaged as exc:
        if looks:
            warnings.warn(f"{path}: its materials are left out ({exc.detail})", stacklevel=4)
        return None, {}, None
    unmatched = [name for name, geometry in loaded.geometry.items() if name not in primitives or
                 position_count(gltf, *primitives[name][:2]) != len(getattr(geometry, "vertices", ()))]
    if unmatched:
        if looks and gltf.document.get("materials"):
            warnings.warn(f"{path}: its materials are left out (its meshes could not be matched to its primitives: "
                          f"{unmatched[0]})", stacklevel=4)
        return None, {}, None
    return gltf, primitives, gltf_looks(gltf, path) if looks else None


def load_scene(source, mesh_prims=None, cage_prim: str | None = None, rest_time=None, looks: bool = True) -> Scene:
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
    looks : bool, read the materials of a glTF or OBJ file too (:mod:`.looks`); a USD asset keeps its own

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
        return _gltf_scene(checked_input(source, MeshError, "mesh"), looks)
    surface = load_surface(source, looks=looks)
    return Scene((MeshPart(surface.name, surface),), surface.name)
