"""Cage poses in: a folder of OBJ frames, a .npy/.npz array (F, L, 3), or a USD file with a time-sampled cage."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..arguments import FLOAT32_MAX, number
from ..errors import BindingError
from .door import checked_input, read_numpy
from .load import finite_coordinates, load_surface
from .naming import natural_key
from .usd.layers import reads_usd

__all__ = ["Poses", "load_poses", "checked_poses", "numeric", "obj_sequence", "pose_vertices", "read_positions",
           "same_triangles"]


@dataclass
class Poses:
    """A sequence of cage poses.

    Attributes
    ----------
    positions : (F, L, 3) float64, the cage vertices of every frame
    frames : (F,) float64, the frame number (USD time code) of every pose
    name : str, where they came from
    time_codes_per_second : float or None, the rate of the animation they came from (a USD stage's), if any
    """

    positions: np.ndarray
    frames: np.ndarray
    name: str
    time_codes_per_second: float | None = None


def pose_vertices(vertices: np.ndarray, faces: np.ndarray, cage_faces: np.ndarray,
                  source_index: np.ndarray | None, name: str) -> np.ndarray:
    """The handles' positions in a deformed cage with the bound cage's topology: its vertices as they are, or, for
    a triangle soup laid out like the bound cage's source, merged by the same map.

    Parameters
    ----------
    vertices, faces : the deformed cage as loaded
    cage_faces : (F, 3) the bound cage's faces (outward)
    source_index : the bound cage's map from source vertices to handles, or None
    name : str, for messages

    Returns
    -------
    (L, 3) float64

    Raises
    ------
    BindingError
        When the vertex count or the faces differ from the bound cage's.
    """
    from ..errors import BindingError

    n_handles = int(cage_faces.max()) + 1
    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces)
    if source_index is not None and len(vertices) == len(source_index) and len(vertices) != n_handles:
        faces = source_index[faces]
        merged = np.zeros((n_handles, 3))
        np.add.at(merged, source_index, vertices)
        vertices = merged / np.bincount(source_index, minlength=n_handles)[:, None]
    if len(vertices) != n_handles:
        raise BindingError(f"{name}: the pose has {len(vertices)} vertices, the bound cage has {n_handles}")
    if not same_triangles(faces, cage_faces):
        raise BindingError(f"{name}: the pose's faces differ from the bound cage's (different topology: "
                           f"{len(faces)} faces against {len(cage_faces)}, or other vertex triples)")
    return vertices


def same_triangles(faces: np.ndarray, other: np.ndarray) -> bool:
    """Whether two face lists hold the same triangles over the same vertices, in any order, each triangle's
    corners rotated in any way, and with the orientation of all of them flipped or not (an exporter may list
    faces in another order or wind them the other way; the vertices are what a pose moves).

    Examples
    --------
    >>> f = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    >>> same_triangles(f[::-1], f), same_triangles(np.roll(f, 1, axis=1), f), same_triangles(f[:, ::-1], f)
    (True, True, True)
    >>> same_triangles(np.array([[0, 1, 2], [0, 1, 3], [0, 3, 1], [1, 3, 2]]), f)
    False
    """
    faces, other = np.asarray(faces), np.asarray(other)
    if faces.shape != other.shape or faces.ndim != 2 or faces.shape[1] != 3:
        return False

    def canonical(f: np.ndarray) -> np.ndarray:
        # rotate each triangle so that its smallest index comes first (keeps the winding), then sort the rows
        f = np.take_along_axis(f, (np.argmin(f, axis=1)[:, None] + np.arange(3)) % 3, axis=1)
        return f[np.lexsort(f.T[::-1])]

    target = canonical(other)
    return bool(np.array_equal(canonical(faces), target) or np.array_equal(canonical(faces[:, ::-1]), target))


def _frame_number(name: str, default: int) -> float:
    digits = re.findall(r"\d+", os.path.splitext(name)[0])
    return float(digits[-1]) if digits else float(default)


def obj_sequence(path: str, positions_of) -> Poses:
    """The OBJ files of a folder as a sequence: sorted naturally, each loaded and turned into positions by
    ``positions_of(surface, file)`` (which checks it against what it must fit), frame numbers from the last number
    in each name (1, 2, ... when those do not identify the frames)."""
    names = sorted((f for f in os.listdir(path) if f.lower().endswith(".obj")), key=natural_key)
    if not names:
        raise BindingError(f"{path}: the folder has no .obj frames")
    positions, frames = [], []
    for k, name in enumerate(names):
        frame = os.path.join(path, name)
        try:
            surface = load_surface(frame)
        except ValueError as exc:  # already names the frame's file
            raise BindingError(str(exc)) from None
        positions.append(positions_of(surface, frame))
        frames.append(_frame_number(name, k + 1))
    frames = np.asarray(frames)
    if len(np.unique(frames)) != len(frames):  # numbers in the names do not identify frames: number them
        frames = np.arange(1, len(frames) + 1, dtype=np.float64)
    return Poses(np.stack(positions), frames, path)


def _from_folder(path: str, cage_faces: np.ndarray, n_handles: int, source_index=None) -> Poses:
    return obj_sequence(path, lambda surface, frame: pose_vertices(surface.vertices, surface.faces, cage_faces,
                                                                    source_index, frame))


def numeric(value, name: str, what: str) -> np.ndarray:
    """``value`` as float64, or a BindingError naming ``name`` when it holds no numbers (strings, records, objects).

    Examples
    --------
    >>> numeric(np.array([["a", "b", "c"]]), "s.npy", "poses").dtype
    Traceback (most recent call last):
    ...
    warp_stokes.errors.BindingError: s.npy: poses must be numbers, not an array of <U1
    """
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):  # ragged lists
        raise BindingError(f"{name}: {what} must be an array of numbers of one shape") from None
    if array.dtype.kind not in "biuf":
        raise BindingError(f"{name}: {what} must be numbers, not an array of {array.dtype}")
    return array.astype(np.float64)


def read_positions(path: str, n_points: int, keys=("poses",), numbers_key: str = "frames", what: str = "poses",
                   of: str = "cage") -> Poses:
    """Positions (F, n_points, 3) from a ``.npy`` array or a ``.npz`` archive (the first of ``keys`` it has, else its
    first array; frame numbers from ``numbers_key`` where it has them, else 1, 2, ...), every entry checked: numbers
    (no strings, records or objects), the shape, finite.

    Raises
    ------
    BindingError, naming the file and the problem
    """
    data = read_numpy(path, BindingError, what)
    numbers = None
    if isinstance(data, dict):
        key = next((k for k in keys if k in data), next(iter(data), None))
        if key is None:
            raise BindingError(f"{path}: the archive is empty")
        array = data[key]
        if numbers_key in data:
            numbers = numeric(data[numbers_key], path, f"'{numbers_key}'")
    else:
        array = data
    array = numeric(array, path, what)
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3 or array.shape[1:] != (n_points, 3):
        raise BindingError(f"{path}: {what} must have shape (frames, {n_points}, 3) for this {of}, got {array.shape}")
    finite_coordinates(array, path, "frame, point" if what == "poses" else "frame, vertex", BindingError)
    if numbers is None:
        numbers = np.arange(1, len(array) + 1, dtype=np.float64)
    elif numbers.shape != (len(array),):
        raise BindingError(f"{path}: '{numbers_key}' has shape {numbers.shape}, expected ({len(array)},) for "
                           f"{len(array)} {what}")
    return Poses(array, numbers, path)


@reads_usd(BindingError)
def _from_usd(path: str, cage_faces: np.ndarray, n_handles: int, source_index=None,
              cage_prim: str | None = None) -> Poses:
    from pxr import UsdGeom

    from .usd.asset import cage_animation, open_stage

    if cage_prim is None:  # the first mesh with time-sampled points and the cage's vertex count
        stage = open_stage(path, BindingError)
        sizes = {n_handles} | ({len(source_index)} if source_index is not None else set())
        for prim in stage.Traverse():
            points = UsdGeom.Mesh(prim).GetPointsAttr() if prim.IsA(UsdGeom.Mesh) else None
            if points is not None and points.GetNumTimeSamples() > 0:
                value = points.Get(points.GetTimeSamples()[0])
                if value is not None and len(value) in sizes:
                    cage_prim = str(prim.GetPath())
                    break
        else:
            raise BindingError(f"{path}: no mesh with {n_handles} time-sampled points (the bound cage's vertex count); "
                               "name the cage's prim (--cage-prim)")
        del stage
    positions, times, rate, surface = cage_animation(path, cage_prim, n_handles)
    name = f"{path}:{cage_prim}"
    pose_vertices(positions[0], surface.faces, cage_faces, source_index, name)  # the topology, checked once
    if positions.shape[1] != n_handles:  # a triangle soup laid out like the bound cage's source: merged
        merge = np.zeros((n_handles, positions.shape[1]))
        merge[source_index, np.arange(len(source_index))] = 1.0
        positions = (merge / merge.sum(axis=1, keepdims=True)) @ positions
    return Poses(positions, times, name, rate)


def checked_poses(poses: Poses, what: str = "poses") -> Poses:
    """Poses (or mesh frames) as every writer takes them: at least one, every position finite and within
    :data:`~warp_stokes.io.load.COORDINATE_LIMIT`, frame numbers finite, distinct and within float32's range (glTF
    keeps times as float32), one per pose. The one place where a sequence's numbers are checked, whatever it came
    from.

    Raises
    ------
    BindingError, naming where the poses came from
    """
    positions = numeric(poses.positions, poses.name, what)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise BindingError(f"{poses.name}: {what} must have shape (frames, points, 3), got {positions.shape}")
    if len(positions) == 0:
        raise BindingError(f"{poses.name}: there are no {what}")
    finite_coordinates(positions, poses.name, "frame, point", BindingError)
    frames = numeric(poses.frames, poses.name, "frame numbers")
    if frames.shape != (len(positions),):
        raise BindingError(f"{poses.name}: {len(frames.ravel())} frame numbers for {len(positions)} {what}")
    if not np.all(np.abs(frames) <= FLOAT32_MAX) or len(np.unique(frames)) != len(frames):
        raise BindingError(f"{poses.name}: frame numbers must be finite, distinct and within float32's range, got "
                           f"{frames.tolist()[:10]}")
    rate = poses.time_codes_per_second
    if rate is not None:
        number(rate, f"{poses.name}: time codes per second", 0, low_open=True)
    return Poses(positions, frames, poses.name, rate)


def load_poses(source, cage_faces: np.ndarray, n_handles: int | None = None, source_index=None,
               cage_prim: str | None = None) -> Poses:
    """Read a sequence of cage poses and check that every frame has the bound cage's topology.

    Parameters
    ----------
    source : path | array (F, L, 3) | Poses
        A folder of OBJ frames (sorted naturally, frame numbers taken from the last number in each name),
        a ``.npy`` array or ``.npz`` archive (key ``poses``, optional ``frames``), or a USD file whose cage mesh
        has time-sampled points (``cage_prim``, else the first mesh with the cage's vertex count), one pose per
        time sample in world space, at its time code.
    cage_faces : (T, 3) int array, the bound cage's triangles
    n_handles : int, the bound cage's vertex count (default: from ``cage_faces``)
    source_index : the bound cage's map from its source's vertices to handles (``Cage.source_index``), for OBJ
        frames laid out like a triangle-soup source
    cage_prim : str, optional, for a USD file: the cage's prim path

    Returns
    -------
    Poses

    Raises
    ------
    BindingError
        Naming the file (or frame) and the problem: missing, unreadable, wrong vertex count or topology.

    Examples
    --------
    >>> poses = load_poses("walk/", binding.cage_faces)   # doctest: +SKIP
    >>> poses.positions.shape                            # doctest: +SKIP
    (48, 118, 3)
    """
    cage_faces = np.asarray(cage_faces, dtype=np.int64)
    n_handles = int(cage_faces.max()) + 1 if n_handles is None else int(n_handles)
    if isinstance(source, Poses):
        return checked_poses(source)
    if isinstance(source, (list, tuple)):  # a list of (L, 3) poses, as a user collects them
        try:
            source = np.asarray(source, dtype=np.float64)
        except (TypeError, ValueError):
            raise BindingError(f"poses: a list of {len(source)} poses that are not all ({n_handles}, 3) arrays of "
                               "numbers") from None
    if isinstance(source, np.ndarray):
        array = numeric(source, "<array>", "poses")
        array = array[None] if array.ndim == 2 else array
        if array.ndim != 3 or array.shape[1:] != (n_handles, 3):
            raise BindingError(f"poses must have shape (frames, {n_handles}, 3) for this cage, got {source.shape}")
        return checked_poses(Poses(array, np.arange(1, len(array) + 1, dtype=np.float64), "<array>"))
    path = checked_input(source, BindingError, "poses", folder=True)
    if os.path.isdir(path):
        return checked_poses(_from_folder(path, cage_faces, n_handles, source_index))
    ext = os.path.splitext(path)[1].lower()
    if ext in (".npy", ".npz"):
        return checked_poses(read_positions(path, n_handles))
    if ext in (".usd", ".usda", ".usdc", ".usdz"):
        return checked_poses(_from_usd(path, cage_faces, n_handles, source_index, cage_prim))
    if cage_prim is not None:
        raise BindingError(f"{path}: a cage prim is named, but the poses are not a USD file")
    raise BindingError(f"{path}: poses must be a folder of OBJ frames, a .npy/.npz array or a USD file")
