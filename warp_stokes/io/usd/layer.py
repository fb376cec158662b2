"""A layer over a USD asset: the asset sublayered by a relative path, and overrides only (each bound prim's points,
extent and normals per time code, in the prim's local space)."""

from __future__ import annotations

import os

import numpy as np

from ...errors import WarpStokesError
from ..inputs import inputs_of
from ..outputs import atomic_output
from ..normals import NormalsPlan
from .common import animation_rate, deformed_frames, extent, new_stage, save_layer, set_timing, vec3f
from .layers import reads_usd

__all__ = ["write_layer", "asset_context"]


def _asset_path(binding, asset) -> str:
    recorded = (binding.asset or {}).get("path")
    path = os.path.abspath(os.fspath(asset if asset is not None else recorded))
    if not os.path.isfile(path):
        hint = " (moved since binding? give its place with --asset)" if asset is None else ""
        raise WarpStokesError(f"{path}: the binding's USD asset is not there{hint}")
    return path


def asset_context(path, binding, asset, up_axis, meters_per_unit) -> tuple[str, dict]:
    """The asset a layer at ``path`` goes over (the binding's, or ``asset``) and its stage metadata, refused when the
    output is one of the asset's files or the stage settings asked for differ from the asset's."""
    from .asset import open_stage, stage_metadata

    asset_path = _asset_path(binding, asset)
    whose = inputs_of(asset_path, error=WarpStokesError).meets(path)
    if whose is not None:
        raise WarpStokesError(f"{path}: the output would replace {whose}; write the animation layer to another file "
                              "(it sublayers the asset)")
    metadata = stage_metadata(open_stage(asset_path, WarpStokesError))
    if up_axis is not None and up_axis != metadata["up_axis"]:
        raise WarpStokesError(f"up axis {up_axis}: a layer over {asset_path} keeps its up axis "
                              f"{metadata['up_axis']}")
    if meters_per_unit is not None and float(meters_per_unit) != metadata["meters_per_unit"]:
        raise WarpStokesError(f"meters per unit {meters_per_unit:g}: a layer over {asset_path} keeps its "
                              f"{metadata['meters_per_unit']:g}")
    return asset_path, metadata


class _Override:
    """A prim of the asset whose points (and extent, and normals when ``plan`` is given) the layer overrides per
    frame, in the prim's local space: ``rows`` of the deformed world-space points."""

    def __init__(self, mesh, rows: slice, plan: NormalsPlan | None = None, normals_attr=None):
        self.mesh, self.rows, self.plan, self.normals_attr = mesh, rows, plan, normals_attr
        self.points, self.extent = mesh.GetPointsAttr(), mesh.GetExtentAttr()
        self._matrix = self._inverse = None

    def write(self, world: np.ndarray, cache, time) -> None:
        matrix = np.array(cache.GetLocalToWorldTransform(self.mesh.GetPrim()))
        if self._matrix is None or not np.array_equal(matrix, self._matrix):  # most prims do not move
            try:
                self._matrix, self._inverse = matrix, np.linalg.inv(matrix)
            except np.linalg.LinAlgError:
                raise WarpStokesError(
                    f"{self.mesh.GetPrim().GetPath()}: its local-to-world transform at time {time.GetValue():g} is "
                    "singular (scaled to zero?), so its deformed points have no place in its local space") from None
        local = np.asarray(world[self.rows], dtype=np.float64) @ self._inverse[:3, :3] + self._inverse[3, :3]
        self.points.Set(vec3f(local), time)
        self.extent.Set(extent(local), time)
        if self.plan is not None:
            self.normals_attr.Set(vec3f(self.plan(local)), time)


@reads_usd(WarpStokesError, path_argument=1)
def _part_override(stage, asset_path: str, part: dict, rows: slice, rest_time) -> _Override:
    """The override of one bound prim, checked against the binding (the asset may have changed since), with the
    normals recomputed where the asset authors them (``primvars:normals`` wins over ``normals``, as in USD)."""
    from pxr import Usd, UsdGeom

    prim = stage.GetPrimAtPath(part["path"])
    if not prim.IsValid() or not prim.IsA(UsdGeom.Mesh):
        raise WarpStokesError(f"{asset_path}: the bound prim {part['path']} is no longer a mesh in the asset")
    mesh = UsdGeom.Mesh(prim)
    time = Usd.TimeCode.EarliestTime() if rest_time is None else Usd.TimeCode(rest_time)
    rest = mesh.GetPointsAttr().Get(time)
    if rest is None or len(rest) != rows.stop - rows.start:
        raise WarpStokesError(f"{asset_path}: {part['path']} has {0 if rest is None else len(rest)} points, the "
                              f"binding {rows.stop - rows.start}: the asset changed since binding; bind it again")
    interpolation = part.get("normals")
    if not interpolation:
        return _Override(mesh, rows)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time), dtype=np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time), dtype=np.int64)
    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals")
    if primvar and primvar.HasAuthoredValue():
        rest_normals, attr = primvar.ComputeFlattened(time), primvar.GetAttr()
        if primvar.IsIndexed():
            primvar.BlockIndices()  # the new values are flat, one per element
    else:
        rest_normals, attr = mesh.GetNormalsAttr().Get(time), mesh.GetNormalsAttr()
    left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    rest_normals = None if rest_normals is None else np.asarray(rest_normals)
    plan = NormalsPlan(counts, indices, interpolation, len(rest), rest_normals, left)
    recomputed = plan(np.asarray(rest))
    if rest_normals is not None and len(rest_normals) == len(recomputed) and \
            np.mean(np.sum(recomputed * rest_normals, axis=1)) < 0:
        # the asset's normals point against its winding: keep their side
        plan = NormalsPlan(counts, indices, interpolation, len(rest), rest_normals, not left)
    return _Override(mesh, rows, plan, attr)


def write_layer(path, ext, binding, positions, frames, poses, fps, with_cage, with_weights, up_axis,
                 meters_per_unit, asset) -> str:
    """Write a layer over the binding's asset (or ``asset``) with the bound prims' overrides for every pose; see
    :func:`warp_stokes.io.usd.write_animation` for the arguments."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    asset_path, metadata = asset_context(path, binding, asset, up_axis, meters_per_unit)
    rate = animation_rate(fps, poses, metadata["time_codes_per_second"])
    cage_prim = binding.settings.get("cage_prim")
    if with_cage and not cage_prim:
        raise WarpStokesError("--with-cage: the binding's cage is not a prim of its asset; over an asset only its "
                              "own prims are overridden (write a standalone stage from a binding of the mesh file)")
    relative = os.path.relpath(asset_path, os.path.dirname(os.path.abspath(path))).replace(os.sep, "/")
    with atomic_output(path, ext) as tmp:
        layer, _ = new_stage(tmp, ext)
        layer.subLayerPaths.append(relative)
        stage = Usd.Stage.Open(layer)  # composed with the asset; edits go to the new layer, as overrides
        if metadata["default_prim"]:
            layer.defaultPrim = metadata["default_prim"]
        UsdGeom.SetStageUpAxis(stage, metadata["up_axis"])
        UsdGeom.SetStageMetersPerUnit(stage, metadata["meters_per_unit"])
        set_timing(stage, frames, rate)
        rest_time = (binding.asset or {}).get("rest_time")
        parts = [_part_override(stage, asset_path, part, rows, rest_time)
                 for part, rows in zip(binding.parts, binding.part_slices())]
        if with_weights:
            for part in parts:
                primvar = UsdGeom.PrimvarsAPI(part.mesh).CreatePrimvar(
                    "stokesWeights", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex, binding.n_handles)
                primvar.Set(Vt.FloatArray.FromNumpy(binding.weights[part.rows].ravel()))
        cage = None
        if with_cage:
            cage_mesh = UsdGeom.Mesh(stage.GetPrimAtPath(cage_prim))
            rest = cage_mesh.GetPointsAttr().Get(Usd.TimeCode.EarliestTime()) if cage_mesh else None
            if rest is None or len(rest) != binding.n_handles:
                raise WarpStokesError(f"--with-cage: {asset_path} has no cage prim {cage_prim} with "
                                      f"{binding.n_handles} points")
            cage = _Override(cage_mesh, slice(0, binding.n_handles))
        for t, pose, deformed in deformed_frames(binding, positions, frames, layer, path, ext):
            time = Usd.TimeCode(t)
            cache = UsdGeom.XformCache(time)
            for part in parts:
                part.write(deformed, cache, time)
            if cage is not None:
                cage.write(pose, cache, time)
        save_layer(layer, path)
        del stage, layer
    return path
