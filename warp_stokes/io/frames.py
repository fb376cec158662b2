"""Sequences of meshes in: captured or simulated frames with the bound mesh's topology, or a rigged character's
animation (:mod:`.skinned`), to encode as cage poses."""

from __future__ import annotations

import os

import numpy as np

from ..errors import BindingError
from .door import checked_input
from .poses import Poses, checked_poses, numeric, obj_sequence, read_positions, same_triangles
from .usd.layers import reads_usd

__all__ = ["load_mesh_frames"]


def _from_folder(path: str, faces: np.ndarray, n_vertices: int) -> Poses:
    def positions_of(surface, frame):
        if len(surface.vertices) != n_vertices:
            raise BindingError(f"{frame}: the frame has {len(surface.vertices)} vertices, the bound mesh {n_vertices}")
        if not same_triangles(surface.faces, faces):
            raise BindingError(f"{frame}: the frame's faces differ from the bound mesh's (different topology)")
        return surface.vertices

    return obj_sequence(path, positions_of)


@reads_usd(BindingError)
def _from_usd(path: str, n_vertices: int, prims) -> Poses:
    from pxr import UsdGeom

    from .usd.asset import mesh_prim, open_stage, time_codes_per_second, to_world, world_matrix

    stage = open_stage(path, BindingError)
    if prims:
        meshes = [mesh_prim(stage, p, path, BindingError) for p in prims]
    else:  # the first mesh with the bound mesh's point count and time samples
        meshes = []
        for prim in stage.Traverse():
            points = UsdGeom.Mesh(prim).GetPointsAttr() if prim.IsA(UsdGeom.Mesh) else None
            if points is not None and points.GetNumTimeSamples() > 0:
                value = points.Get(points.GetTimeSamples()[0])
                if value is not None and len(value) == n_vertices:
                    meshes = [UsdGeom.Mesh(prim)]
                    break
        if not meshes:
            raise BindingError(f"{path}: no mesh with {n_vertices} time-sampled points (the bound mesh's count)")
    times = meshes[0].GetPointsAttr().GetTimeSamples()
    if not times:
        raise BindingError(f"{path}: {meshes[0].GetPrim().GetPath()}'s points have no time samples")
    positions = []
    for t in times:
        values = [m.GetPointsAttr().Get(t) for m in meshes]
        missing = [str(m.GetPrim().GetPath()) for m, v in zip(meshes, values) if v is None]
        if missing:
            raise BindingError(f"{path}: {missing[0]} has no points at time {t:g}")
        frame = [to_world(np.asarray(v), world_matrix(m.GetPrim(), t)) for m, v in zip(meshes, values)]
        frame = np.concatenate(frame)
        if frame.shape != (n_vertices, 3):
            raise BindingError(f"{path}: the frame at time {t:g} has {len(frame)} points, the bound mesh {n_vertices}")
        if not np.isfinite(frame).all():
            raise BindingError(f"{path}: the frame at time {t:g} has points that are not finite")
        positions.append(frame)
    return Poses(np.stack(positions), np.asarray(times, dtype=np.float64), path, time_codes_per_second(stage, path))


@reads_usd(BindingError)
def _has_skinned_meshes(path: str) -> bool:
    """Whether a USD file has a UsdSkel skeleton binding (its meshes are posed by skinning, not by time samples)."""
    from pxr import UsdSkel

    from .usd.asset import open_stage

    stage = open_stage(path, BindingError)
    return any(prim.HasAPI(UsdSkel.BindingAPI) and UsdSkel.BindingAPI(prim).GetSkeletonRel().HasAuthoredTargets()
               for prim in stage.Traverse())


def _rigged(path: str, faces: np.ndarray, n_vertices: int, prims, animation, fps) -> Poses:
    """A rigged animation's frames (:func:`~.skinned.load_frames`), checked against the bound mesh."""
    from .scene import is_usd
    from .skinned import load_frames

    frames = load_frames(path, animation, fps, mesh_prims=prims)
    if frames.positions.shape[1] != n_vertices:
        raise BindingError(f"{frames.name}: the animation poses {frames.positions.shape[1]} vertices, the bound mesh "
                           f"has {n_vertices}")
    if not is_usd(path):  # the meshes bind reads from the file: their triangles are the bound mesh's
        from .scene import load_scene

        if not same_triangles(load_scene(path).surface().faces, faces):
            raise BindingError(f"{path}: its meshes' faces differ from the bound mesh's (different topology)")
    return frames


def load_mesh_frames(source, faces: np.ndarray, n_vertices: int, prims=None, animation=None,
                     fps: float | None = None) -> Poses:
    """A sequence of meshes with the bound mesh's topology, as positions (F, V, 3) at frame numbers.

    Parameters
    ----------
    source : path | array (F, V, 3)
        A folder of OBJ frames (sorted naturally, frame numbers from the last number in each name; each frame's
        triangles must be the bound mesh's), a ``.npy`` array or ``.npz`` archive (``frames``, optional ``times``),
        or a USD file: the time samples of ``prims`` (concatenated, world space), or of the first mesh with the
        bound mesh's point count; or a rigged animation (:func:`~.skinned.load_frames`): a glTF/GLB file, or a USD
        file whose meshes are skinned (UsdSkel).
    faces : (T, 3) the bound mesh's triangles
    n_vertices : int
    prims : list of str, optional, for USD
    animation : str, optional, a rigged file's animation (glTF: its name; USD: a SkelAnimation prim)
    fps : float, optional, sample a rigged file's animation at this rate instead of at its keys

    Returns
    -------
    Poses, whose positions are mesh vertices

    Raises
    ------
    BindingError
        Naming the file (or frame) and the problem.

    Examples
    --------
    >>> frames = load_mesh_frames("capture/", binding.mesh_faces, binding.n_vertices)   # doctest: +SKIP
    """
    if isinstance(source, np.ndarray):
        array = numeric(source, "<array>", "frames")
        array = array[None] if array.ndim == 2 else array
        if array.ndim != 3 or array.shape[1:] != (n_vertices, 3):
            raise BindingError(f"frames must have shape (frames, {n_vertices}, 3), got {source.shape}")
        return checked_poses(Poses(array, np.arange(1, len(array) + 1, dtype=np.float64), "<array>"), "frames")
    path = checked_input(source, BindingError, "frames", folder=True)
    ext = os.path.splitext(path)[1].lower()
    rigged = ext in (".glb", ".gltf") or (ext in (".usd", ".usda", ".usdc", ".usdz") and (
        animation is not None or fps is not None or _has_skinned_meshes(path)))
    if rigged and not os.path.isdir(path):
        return _rigged(path, np.asarray(faces), n_vertices, prims, animation, fps)
    if animation is not None or fps is not None:
        raise BindingError(f"{path}: an animation and its rate are read from a rigged glTF/GLB or USD file")
    if os.path.isdir(path):
        return checked_poses(_from_folder(path, np.asarray(faces), n_vertices), "frames")
    if ext in (".npy", ".npz"):
        return checked_poses(read_positions(path, n_vertices, keys=("frames", "positions", "vertices"),
                                            numbers_key="times", what="frames", of="mesh"), "frames")
    if ext in (".usd", ".usda", ".usdc", ".usdz"):
        return checked_poses(_from_usd(path, n_vertices, prims), "frames")
    raise BindingError(f"{path}: frames must be a folder of OBJ files, a .npy/.npz array, a USD file or a rigged "
                       "glTF/GLB")
