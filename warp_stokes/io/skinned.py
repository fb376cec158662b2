"""Rigged animation in (:func:`load_frames`): a skinned glTF/GLB's animation (:mod:`.gltf_pose`) or a UsdSkel
asset's (pxr's own skinning, :mod:`.usd.skel_frames`), as mesh frames in the vertex order ``bind`` reads the same
file, ready for :func:`warp_stokes.binding.encode.encode_poses`.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import BindingError, WarpStokesError
from .door import checked_input, reason
from .frame_times import frame_numbers, sample_times
from .gltf_file import GltfDamaged, GltfFile
from .gltf_pose import animation_channels, key_times, posed_primitive, world_matrices
from .poses import Poses, checked_poses

__all__ = ["load_frames", "GLTF_RATE"]

#: time codes per second of frames read from a glTF (which keeps seconds, no frame rate) without ``fps``: USD's
#: default, so that a USD written from them plays in real time and a 24 fps animation's keys land on whole frames
GLTF_RATE = 24.0


def _animation_names(document: GltfFile) -> list[str]:
    return [a.get("name") or f"#{k}" for k, a in enumerate(document.entries("animations"))]


def _chosen_animation(document: GltfFile, animation) -> tuple[dict, str]:
    """The animation named ``animation`` (its name, or its number), or the file's only one; else one error listing
    the animations it has."""
    animations = document.entries("animations")
    names = _animation_names(document)
    listed = ", ".join(names[:20]) + (f" and {len(names) - 20} more" if len(names) > 20 else "")
    if not animations:
        raise BindingError(f"{document.path}: the file has no animations")
    if animation is None:
        if len(animations) > 1:
            raise BindingError(f"{document.path}: {len(animations)} animations ({listed}); name one (--animation)")
        return animations[0], names[0]
    text = str(animation)
    for k, name in enumerate(names):
        if text in (name, str(k), f"#{k}"):
            return animations[k], name
    raise BindingError(f"{document.path}: no animation {text!r}; its animations: {listed}")


def _trimesh_names(document: GltfFile) -> tuple[dict, dict]:
    """What trimesh names the file's nodes and primitives (its scene graph's frames and geometries): {frame: node},
    {geometry: (mesh, primitive)}, named by trimesh's own function in its own order, so that the meshes ``bind`` reads
    (through trimesh) are found in the file."""
    from trimesh.util import unique_name

    node_of, counts = {}, {}
    for index, node in enumerate(document.entries("nodes")):
        node_of[unique_name(node.get("name", str(index)), node_of, counts=counts)] = index
    if "world" in node_of:  # trimesh's base frame: a node of that name is renamed
        index = node_of.pop("world")
        node_of[unique_name("world", set(node_of))] = index
    geometry_of, counts = {}, {}
    for m, mesh in enumerate(document.entries("meshes")):
        for p, primitive in enumerate(mesh.get("primitives") or []):
            name = unique_name(mesh.get("name", "GLTF"), geometry_of, counts=counts)
            if isinstance(primitive, dict) and primitive.get("mode", 4) in (0, 1, 4, 5):  # the modes trimesh keeps
                geometry_of[name] = (m, p)
    return node_of, geometry_of


def _bound_primitives(path: str, document: GltfFile) -> list[tuple[int, int, int]]:
    """(node, mesh, primitive) of every mesh ``bind`` reads from the file, in its order, each checked against the
    vertices bind reads for it."""
    from .load import read_with_trimesh
    from .scene import gltf_mesh_nodes

    loaded = read_with_trimesh(path, "scene")
    node_of, geometry_of = _trimesh_names(document)
    parents = loaded.graph.transforms.parents
    found = []
    for frame, geometry_name, _ in gltf_mesh_nodes(loaded):
        node = node_of.get(frame, node_of.get(parents.get(frame)))  # a primitive of several hangs under its node
        mesh, primitive = geometry_of.get(geometry_name, (None, None))
        if node is None or mesh is None or document.entries("nodes")[node].get("mesh") != mesh:
            raise BindingError(f"{path}: cannot find the mesh {frame!r} ({geometry_name}) that bind reads among the "
                               "file's nodes")
        rest = document.accessor(document.entries("meshes")[mesh]["primitives"][primitive]["attributes"]["POSITION"])
        read = np.asarray(loaded.geometry[geometry_name].vertices)
        if rest.shape != read.shape or not np.allclose(rest, read, rtol=1e-6, atol=1e-6 * np.abs(read).max()):
            raise BindingError(f"{path}: the mesh {frame!r} has other vertices in the file than bind reads "
                               "(quantised positions?)")
        found.append((node, mesh, primitive))
    if not found:
        raise BindingError(f"{path}: the scene has no meshes with faces")
    return found


def _gltf_frames(path: str, animation, fps: float | None) -> Poses:
    try:
        return _animation_frames(path, animation, fps)
    except GltfDamaged as exc:  # the file is the frames' input: its damage is theirs
        raise BindingError(str(exc)) from None


def _animation_frames(path: str, animation, fps: float | None) -> Poses:
    document = GltfFile(path)
    document.check_version()
    chosen, name = _chosen_animation(document, animation)
    for primitive in (p for m in document.entries("meshes") for p in m.get("primitives") or []):
        if "KHR_draco_mesh_compression" in (primitive.get("extensions") or {}):
            raise BindingError(f"{path}: its meshes are compressed (KHR_draco_mesh_compression); export the file "
                               "without compression")
    channels = animation_channels(document, chosen, repr(name))
    keys = key_times(channels)
    if len(keys) == 0:
        raise BindingError(f"{path}: animation {name!r} has no channels that move nodes")
    times = sample_times(keys, None if fps is None else 1.0 / fps, f"{path}:{name}")
    world = world_matrices(document, channels, times)
    parts = [posed_primitive(document, node, mesh, primitive, channels, times, world)
             for node, mesh, primitive in _bound_primitives(path, document)]
    rate = GLTF_RATE if fps is None else float(fps)
    return Poses(np.concatenate(parts, axis=1), frame_numbers(times, rate), f"{path}:{name}", rate)


def load_frames(source, animation=None, fps: float | None = None, mesh_prims=None) -> Poses:
    """The mesh frames of a rigged character's animation: a skinned glTF/GLB, or a UsdSkel asset.

    Parameters
    ----------
    source : path
        A ``.glb``/``.gltf`` file (its mesh nodes posed by the animation: morph targets, then linear blend skinning
        over every JOINTS_n/WEIGHTS_n set, weights normalised; a mesh without a skin moves with its node), or a USD
        file (its meshes posed by UsdSkel's own skinning: ``UsdSkel.SkinningQuery`` with blend shapes).
    animation : str or int, optional
        The glTF animation's name (or number); for USD a ``SkelAnimation`` prim's path or name, bound to every
        skeleton in place of its own for the reading (default: the glTF's only animation; USD: the skeletons' own).
    fps : float, optional
        Sample the animation at this rate from its first key to its last (default: at its key times).
    mesh_prims : list of str, optional, for USD: the mesh prims to read (default: every mesh, as ``bind`` reads)

    Returns
    -------
    Poses
        ``positions`` (F, V, 3) in world space, the vertices in the order ``bind`` reads the same file (glTF: all
        its meshes together, in world space; a skinned mesh's own node transform is ignored, as glTF says);
        ``frames`` the frame numbers at ``time_codes_per_second`` (glTF: ``fps``, else 24, so that
        ``frames / time_codes_per_second`` are the seconds; USD: the stage's time codes and rate).

    Raises
    ------
    BindingError
        One line naming the file: unreadable, no animation, an animation name it does not have (the line lists
        those it has), a skin that names joints it does not have.

    Examples
    --------
    >>> walk = load_frames("Fox.glb", animation="Walk")      # doctest: +SKIP
    >>> walk.positions.shape, walk.frames[:3].tolist()       # doctest: +SKIP
    ((18, 1728, 3), [0.0, 1.0, 2.0])
    """
    from ..arguments import number
    from .scene import is_usd

    path = checked_input(source, BindingError, "animation")
    if fps is not None:
        try:
            fps = number(fps, f"{path}: fps", 0, low_open=True)
        except WarpStokesError as exc:  # of the animation's reading: its kind of error
            raise BindingError(str(exc)) from None
    if is_usd(path):
        from .usd.skel_frames import usd_skinned_frames

        positions, frames, rate = usd_skinned_frames(path, animation, fps, mesh_prims)
        return checked_poses(Poses(positions, frames, path if animation is None else f"{path}:{animation}", rate),
                             "frames")
    if mesh_prims:
        raise BindingError(f"{path}: mesh prims are named, but it is not a USD file")
    if os.path.splitext(path)[1].lower() not in (".glb", ".gltf"):
        raise BindingError(f"{path}: a rigged animation is read from a glTF/GLB or a USD file")
    try:
        return checked_poses(_gltf_frames(path, animation, fps), "frames")
    except WarpStokesError:
        raise
    except (KeyError, IndexError, TypeError, AttributeError, ValueError, OverflowError) as exc:
        # a document whose objects are not of the kinds glTF says (a list where an object goes, a string for a
        # number): one line naming the file, whichever object it is
        raise BindingError(f"{path}: not a glTF file whose animation can be read ({reason(exc)})") from None
