"""A standalone animated stage for meshes from files without USD: ``/Root`` with one mesh per bound part, its
polygons as read, face-varying UVs and per-frame normals, and the input's materials bound to them (:mod:`.looks`:
``/Root/Looks``, the images beside the layer)."""

from __future__ import annotations


import numpy as np

from ...errors import WarpStokesError
from ..outputs import atomic_output, together
from ..load import polygons_by_part
from ..normals import NormalsPlan
from .common import (animation_rate, define_mesh, deformed_frames, extent, new_stage, prim_name, save_layer,
                     set_timing, vec3f)
from .looks import StageLooks

__all__ = ["write_standalone", "write_cage_poses"]


def write_standalone(path, ext, binding, positions, frames, poses, fps, with_cage, with_weights, up_axis,
                     meters_per_unit, normals) -> str:
    """Write ``/Root`` with one mesh per part of the binding (``/Root/Mesh`` for one), deformed by every pose; see
    :func:`warp_stokes.io.usd.write_animation` for the arguments."""
    from pxr import Usd, UsdGeom

    if up_axis not in ("Y", "Z"):
        raise WarpStokesError(f"up axis must be 'Y' or 'Z', got {up_axis!r}")
    if not meters_per_unit > 0:
        raise WarpStokesError(f"meters per unit must be positive, got {meters_per_unit!r}")
    rate = animation_rate(fps, poses)
    normals = binding.mesh_normals if normals is None else np.asarray(normals)
    looks = StageLooks(path, binding)
    with together([path, *looks.outputs()]), atomic_output(path, ext) as tmp:  # the images renamed with the layer
        looks.write_images()
        layer, stage = new_stage(tmp, ext)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
        set_timing(stage, frames, rate)
        root = UsdGeom.Xform.Define(stage, "/Root")
        stage.SetDefaultPrim(root.GetPrim())
        writers = _define_parts(stage, binding, normals, with_weights)
        looks.define(stage, binding, [UsdGeom.Mesh(points.GetPrim()) for _, points, *_ in writers])
        cage = None
        if with_cage:
            cage = define_mesh(stage, "/Root/Cage", np.full(len(binding.cage_faces), 3), binding.cage_faces.ravel(),
                               binding.cage_vertices)
            UsdGeom.Imageable(cage).CreatePurposeAttr(UsdGeom.Tokens.guide)
        for t, pose, deformed in deformed_frames(binding, positions, frames, layer, path, ext):
            time = Usd.TimeCode(t)
            for rows, points, extent_attr, normals_attr, plan in writers:
                local = deformed[rows]
                points.Set(vec3f(local), time)
                extent_attr.Set(extent(local), time)
                if plan is not None:
                    normals_attr.Set(vec3f(plan(local)), time)
            if cage is not None:
                cage.GetPointsAttr().Set(vec3f(pose), time)
                cage.GetExtentAttr().Set(extent(pose), time)
        save_layer(layer, path)
        del stage, layer
    return path


def _define_parts(stage, binding, normals, with_weights: bool) -> list:
    """One mesh per part under /Root, with its polygons, UVs and weights, and normals per frame when ``normals``
    (the rest normals, (V, 3)) are given: per part (rows, points attribute, extent attribute, normals attribute,
    NormalsPlan or None)."""
    with_normals = normals is not None
    from pxr import Sdf, UsdGeom, Vt

    slices = binding.part_slices()
    counts, indices = binding.mesh_face_counts, binding.mesh_face_indices
    taken, writers = set(), []
    for (part, rows), (faces, corners) in zip(zip(binding.parts, slices), polygons_by_part(counts, indices, slices)):
        part_counts, part_indices = counts[faces], indices[corners] - rows.start
        name = "Mesh" if len(slices) == 1 else prim_name(str(part["path"]).rstrip("/").split("/")[-1].split(":")[-1], "Mesh", taken)
        mesh = define_mesh(stage, f"/Root/{name}", part_counts, part_indices, binding.mesh_vertices[rows])
        if binding.mesh_uvs is not None:
            st, st_indices = binding.mesh_uvs
            used, local = np.unique(st_indices[corners], return_inverse=True)
            primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                               UsdGeom.Tokens.faceVarying)
            primvar.Set(Vt.Vec2fArray.FromNumpy(st[used].astype(np.float32)))
            primvar.SetIndices(Vt.IntArray.FromNumpy(local.astype(np.int32).ravel()))
        plan = None
        if with_normals:
            plan = NormalsPlan(part_counts, part_indices, "vertex", rows.stop - rows.start)
            mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
            rest_normals = None if normals is None else np.asarray(normals)[rows]
            if rest_normals is not None and np.mean(np.sum(plan(binding.mesh_vertices[rows]) * rest_normals,
                                                           axis=1)) < 0:
                # the file's normals point against its winding (clockwise faces): say so, and keep their side
                mesh.GetOrientationAttr().Set(UsdGeom.Tokens.leftHanded)
                plan = NormalsPlan(part_counts, part_indices, "vertex", rows.stop - rows.start, left_handed=True)
        if with_weights:
            primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
                "stokesWeights", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex, binding.n_handles)
            primvar.Set(Vt.FloatArray.FromNumpy(binding.weights[rows].ravel()))
        writers.append((rows, mesh.GetPointsAttr(), mesh.GetExtentAttr(), mesh.GetNormalsAttr(), plan))
    return writers


def write_cage_poses(path, cage_vertices, cage_faces, poses, fps: float | None = None) -> str:
    """Write cage poses as a stage with the animated cage ``/Root/Cage``: its points per time code (the poses'
    frame numbers). ``animate`` and :func:`warp_stokes.load_poses` read it back.

    Parameters
    ----------
    path : ``.usd``, ``.usdc`` or ``.usda``
    cage_vertices, cage_faces : the bound cage (its rest points are the default value)
    poses : Poses (F, L, 3)
    fps : float, optional, time codes per second (default: the poses' own, else 24)

    Returns
    -------
    str, the path written
    """
    import os

    from pxr import Usd, UsdGeom

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".usd", ".usdc", ".usda"):
        raise WarpStokesError(f"{path}: the output must end in .usd, .usdc or .usda")
    frames = np.asarray(poses.frames, dtype=np.float64)
    with atomic_output(path, ext) as tmp:
        layer, stage = new_stage(tmp, ext)
        set_timing(stage, frames, animation_rate(fps, poses))
        root = UsdGeom.Xform.Define(stage, "/Root")
        stage.SetDefaultPrim(root.GetPrim())
        cage = define_mesh(stage, "/Root/Cage", np.full(len(cage_faces), 3), np.asarray(cage_faces).ravel(),
                           np.asarray(cage_vertices, dtype=np.float64))
        UsdGeom.Imageable(cage).CreatePurposeAttr(UsdGeom.Tokens.guide)
        for t, pose in zip(frames, np.asarray(poses.positions, dtype=np.float64)):
            cage.GetPointsAttr().Set(vec3f(pose), Usd.TimeCode(float(t)))
            cage.GetExtentAttr().Set(extent(pose), Usd.TimeCode(float(t)))
        save_layer(layer, path)
        del stage, layer
    return path
