"""USD assets in: mesh prims (and a cage prim) of a composed stage, in world space at the rest time."""

from __future__ import annotations

import os
import warnings

import numpy as np

from ...errors import BindingError, CageError, MeshError, WarpStokesError
from ..load import Surface, fan_triangles, first_missing_vertex, load_surface
from ..parts import MeshPart, Scene
from .layers import layer_stack, reads_usd, usd_reason

__all__ = ["open_stage", "read_asset", "read_cage_prim", "rest_time_code", "mesh_prim",
           "world_matrix", "stage_metadata"]


def open_stage(path: str, error=MeshError):
    """The composed stage of a USD file, every layer of its stack read first (:func:`~.layers.layer_stack`): a
    layer that is missing or unreadable is one ``error`` naming it, never a stage composed without it."""
    from pxr import Usd

    stack = layer_stack(path, error)  # held while the stage opens: it composes these very layers
    try:
        stage = Usd.Stage.Open(stack.layers[0])
    except Exception as exc:  # pxr raises Tf.ErrorException (a RuntimeError) for unreadable layers
        raise error(f"{path}: cannot open it as a USD stage ({usd_reason(exc)})") from None
    if stage is None:
        raise error(f"{path}: cannot open it as a USD stage")
    return stage


def time_codes_per_second(stage, path, error=BindingError) -> float:
    """The stage's time codes per second, refused unless a positive finite number (a stage with -24 or nan wrote a
    file that USD would not open again)."""
    rate = float(stage.GetTimeCodesPerSecond())
    if not (np.isfinite(rate) and rate > 0):
        raise error(f"{path}: timeCodesPerSecond is {rate:g}, not a positive number of time codes per second")
    return rate


def mesh_prim(stage, prim_path: str, name: str, error=MeshError):
    """The ``UsdGeom.Mesh`` at ``prim_path``; a missing prim or another type is one ``error``."""
    from pxr import Sdf, UsdGeom

    if not Sdf.Path.IsValidPathString(prim_path) or not Sdf.Path(prim_path).IsAbsolutePath():
        raise error(f"{name}: {prim_path!r} is not an absolute prim path (e.g. /Character/Cage)")
    prim = stage.GetPrimAtPath(prim_path)
    if not prim.IsValid():
        meshes = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
        listed = ", ".join(meshes[:8]) + (" ..." if len(meshes) > 8 else "")
        raise error(f"{name}: no prim {prim_path} (mesh prims: {listed or 'none'})")
    if not prim.IsA(UsdGeom.Mesh):
        raise error(f"{name}: {prim_path} is a {prim.GetTypeName() or 'typeless prim'}, not a Mesh")

    return UsdGeom.Mesh(prim)


def world_matrix(prim, time) -> np.ndarray:
    """(4, 4) local-to-world of ``prim`` at ``time`` (row vectors: ``[p, 1] @ M``)."""
    from pxr import UsdGeom

    return np.array(UsdGeom.XformCache(time).GetLocalToWorldTransform(prim), dtype=np.float64)


def to_world(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return np.asarray(points, dtype=np.float64) @ matrix[:3, :3] + matrix[3, :3]


def rest_time_code(stage, rest_time=None, cage=None):
    """The time code of the rest pose: ``rest_time`` if given, else the cage's earliest time sample (the pose it
    starts its animation in), else the stage's earliest (a sample if any attribute has one, else default)."""
    from pxr import Usd

    if rest_time is not None:
        return Usd.TimeCode(float(rest_time))
    if cage is not None:
        samples = cage.GetPointsAttr().GetTimeSamples()
        if samples:
            return Usd.TimeCode(samples[0])
    return Usd.TimeCode.EarliestTime()


def _surface(mesh, time, name: str, error) -> tuple[Surface, np.ndarray]:
    """A mesh prim's polygons and world-space points at ``time``, and its local-to-world matrix."""
    points = mesh.GetPointsAttr().Get(time)
    counts = mesh.GetFaceVertexCountsAttr().Get(time)
    indices = mesh.GetFaceVertexIndicesAttr().Get(time)
    path = mesh.GetPrim().GetPath()
    if points is None or len(points) == 0:
        raise error(f"{name}: {path} has no points")
    if counts is None or indices is None or len(counts) == 0:
        raise error(f"{name}: {path} has no faces")
    counts, indices = np.asarray(counts, dtype=np.int64), np.asarray(indices, dtype=np.int64)
    if counts.min() < 3 or counts.sum() != len(indices):
        raise error(f"{name}: {path} has inconsistent faceVertexCounts and faceVertexIndices")
    missing = first_missing_vertex(counts, indices, len(points))
    if missing is not None:
        raise error(f"{name}:{path}: face {missing[0]} refers to vertex {missing[1]}, but there are only "
                    f"{len(points)} points")
    matrix = world_matrix(mesh.GetPrim(), time)
    triangles, _ = fan_triangles(counts, indices)  # vectorised: a USD mesh may have a million polygons
    try:
        surface = load_surface((to_world(np.asarray(points), matrix), triangles), name=f"{name}:{path}")
    except MeshError as exc:
        raise error(str(exc)) from None
    return Surface(surface.vertices, surface.faces, surface.name, None, counts, indices), matrix


def _authored_normals(mesh) -> str | None:
    """The interpolation of the normals the prim authors (``primvars:normals`` wins over ``normals``), or None."""
    from pxr import UsdGeom

    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals")
    if primvar and primvar.HasAuthoredValue():
        return str(primvar.GetInterpolation())
    if mesh.GetNormalsAttr().HasAuthoredValue():
        return str(mesh.GetNormalsInterpolation())
    return None


def stage_metadata(stage) -> dict:
    """What a layer over the stage carries on: up axis, meters per unit, default prim, time codes per second."""
    from pxr import UsdGeom

    default = stage.GetDefaultPrim()
    return {
        "up_axis": str(UsdGeom.GetStageUpAxis(stage)),
        "meters_per_unit": float(UsdGeom.GetStageMetersPerUnit(stage)),
        "default_prim": default.GetName() if default else None,
        "time_codes_per_second": time_codes_per_second(stage, stage.GetRootLayer().identifier, WarpStokesError),
    }


@reads_usd(MeshError)
def read_asset(path: str, mesh_prims=None, exclude=(), rest_time=None, cage_prim: str | None = None) -> Scene:
    """The mesh prims of a USD asset, in world space at the rest time.

    Parameters
    ----------
    path : str, a USD file
    mesh_prims : list of str, optional, the prims to bind (default: every mesh prim the stage traverses, except
        those in ``exclude``; instance proxies are not visited)
    exclude : prim paths left out by default (the cage's)
    rest_time : float, optional, the rest pose's time code (default: see :func:`rest_time_code`)
    cage_prim : str, optional, the cage's prim in this stage, whose first time sample is the default rest time

    Returns
    -------
    Scene, its ``asset`` the absolute path, its ``metadata`` the stage's and the rest time code

    Raises
    ------
    MeshError
        Unreadable file, a named prim missing or not a mesh, no mesh prims to bind.
    """
    from pxr import Sdf, Usd, UsdGeom

    stage = open_stage(path)
    cage = None
    if cage_prim is not None and Sdf.Path.IsValidPathString(cage_prim) and Sdf.Path(cage_prim).IsAbsolutePath():
        found = stage.GetPrimAtPath(cage_prim)
        cage = UsdGeom.Mesh(found) if found.IsValid() and found.IsA(UsdGeom.Mesh) else None
    time = rest_time_code(stage, rest_time, cage)
    if mesh_prims:
        meshes = [mesh_prim(stage, p, path) for p in dict.fromkeys(mesh_prims)]
        for mesh in meshes:
            if mesh.GetPrim().IsInstanceProxy():
                raise MeshError(f"{path}: {mesh.GetPrim().GetPath()} is inside an instance (an instanceable prim above "
                                "it): its points are shared by every instance and cannot be overridden on their own; "
                                "make that prim not instanceable")
    else:
        skip = {str(p) for p in exclude}
        meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and str(p.GetPath()) not in skip]
        # meshes inside instances: their points are shared by every instance and cannot be overridden per instance
        instanced = [str(p.GetPath()) for p in Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies())
                     if p.IsInstanceProxy() and p.IsA(UsdGeom.Mesh)]
        if instanced:
            warnings.warn(f"{path}: {len(instanced)} mesh prim(s) inside instances are not bound (e.g. {instanced[0]}): "
                          "an instance's points cannot be overridden on their own; make the prim not instanceable "
                          "to bind it", stacklevel=3)
        if not meshes:
            raise MeshError(f"{path}: the stage has no mesh prims to bind" + (" besides the cage" if skip else "")
                            + (f" outside instances ({len(instanced)} inside)" if instanced else ""))
    parts = []
    for mesh in meshes:
        surface, matrix = _surface(mesh, time, path, MeshError)
        parts.append(MeshPart(str(mesh.GetPrim().GetPath()), surface, matrix, _authored_normals(mesh)))
    metadata = stage_metadata(stage)
    metadata["rest_time"] = None if time.IsDefault() else float(time.GetValue())
    return Scene(tuple(parts), path, os.path.abspath(path), metadata)


@reads_usd(CageError)
def read_cage_prim(path: str, prim_path: str, rest_time=None) -> Surface:
    """A cage prim's surface in world space at the rest time (its earliest time sample by default).

    Raises
    ------
    CageError
        Unreadable file, a missing prim or one that is not a mesh.
    """
    stage = open_stage(path, CageError)
    mesh = mesh_prim(stage, prim_path, path, CageError)
    surface, _ = _surface(mesh, rest_time_code(stage, rest_time, mesh), path, CageError)
    return surface


@reads_usd(BindingError)
def cage_animation(path: str, prim_path: str, n_handles: int):
    """A cage prim's world-space points at each of its points' time samples: (positions (F, P, 3), time codes
    (F,), time codes per second, the polygons' triangles (T, 3)).

    Raises
    ------
    BindingError
        Unreadable file, a missing prim, no time samples, a sample with another point count.
    """
    stage = open_stage(path, BindingError)
    mesh = mesh_prim(stage, prim_path, path, BindingError)
    times = mesh.GetPointsAttr().GetTimeSamples()
    if not times:
        raise BindingError(f"{path}: {prim_path}'s points have no time samples (no animation to follow)")
    surface, _ = _surface(mesh, times[0], path, BindingError)
    positions = []
    for t in times:
        value = mesh.GetPointsAttr().Get(t)
        if value is None or len(value) != len(surface.vertices):
            raise BindingError(f"{path}: {prim_path} has {0 if value is None else len(value)} points at time {t:g}, "
                               f"{len(surface.vertices)} at {times[0]:g}")
        positions.append(to_world(np.asarray(value), world_matrix(mesh.GetPrim(), t)))
        if not np.isfinite(positions[-1]).all():
            raise BindingError(f"{path}: {prim_path} has points that are not finite at time {t:g}")
    return np.stack(positions), np.asarray(times, dtype=np.float64), time_codes_per_second(stage, path), surface
