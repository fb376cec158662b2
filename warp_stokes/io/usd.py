"""Animated USD out, written with pxr (usd-core).

Two forms, chosen by where the binding came from:

- **a layer over the asset** (a binding of a USD asset): the output's root layer sublayers the asset by a relative
  path and authors only overrides: each bound prim's ``points`` and ``extent`` per time code, in the prim's local
  space, and its normals per time code where the asset authors normals. Topology, UVs, subsets, materials and
  transforms come from the asset through composition.
- **a standalone stage** (OBJ, glTF, arrays): ``/Root`` with one mesh per bound part, its polygons as read (quads
  stay quads), UVs as a face-varying ``primvars:st``, and per-frame normals when the source had normals.

Frames are deformed on the device in chunks of :data:`FRAMES_PER_CHUNK`, so memory stays bounded for long
animations.
"""

from __future__ import annotations

import os
import re

import numpy as np

from ..errors import WarpStokesError
from .files import atomic_output
from .normals import NormalsPlan
from .poses import Poses

__all__ = ["write_animation", "FRAMES_PER_CHUNK"]

#: frames deformed per device launch (bounded so that frames x vertices x 12 bytes stays small)
FRAMES_PER_CHUNK = 64


def _extent(points: np.ndarray):
    from pxr import Gf, Vt

    lo, hi = points.min(axis=0), points.max(axis=0)
    return Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))])


def _vec3f(values: np.ndarray):
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(values, dtype=np.float32))


def _define_mesh(stage, path: str, counts: np.ndarray, indices: np.ndarray, rest: np.ndarray):
    from pxr import UsdGeom, Vt

    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(counts, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(indices, dtype=np.int32)))
    mesh.CreateSubdivisionSchemeAttr("none")
    mesh.CreateOrientationAttr("rightHanded")
    mesh.CreatePointsAttr(_vec3f(rest))
    mesh.CreateExtentAttr(_extent(rest))
    return mesh


def _check(path: str, binding, poses: Poses, fps) -> tuple[str, np.ndarray, np.ndarray]:
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".usd", ".usdc", ".usda"):
        raise WarpStokesError(f"{path}: the output must end in .usd, .usdc or .usda")
    if fps is not None and not fps > 0:
        raise WarpStokesError(f"fps must be positive, got {fps!r}")
    positions = np.asarray(poses.positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[1:] != (binding.n_handles, 3):
        raise WarpStokesError(f"{poses.name}: poses of shape {positions.shape} do not fit a cage of "
                              f"{binding.n_handles} vertices")
    frames = np.asarray(poses.frames, dtype=np.float64)
    if len(positions) == 0 or frames.shape != (len(positions),) or len(np.unique(frames)) != len(frames):
        raise WarpStokesError(f"{poses.name}: need at least one pose and one distinct frame number per pose")
    if len(binding.mesh_faces) == 0:
        raise WarpStokesError("the bound mesh has no faces: there is nothing to write as a USD mesh")
    return ext, positions, frames


def _set_timing(stage, frames: np.ndarray, rate: float) -> None:
    stage.SetTimeCodesPerSecond(float(rate))
    stage.SetFramesPerSecond(float(rate))
    stage.SetStartTimeCode(float(frames.min()))
    stage.SetEndTimeCode(float(frames.max()))


def _frames(binding, positions: np.ndarray, frames: np.ndarray, layer, path: str, ext: str):
    """(time code, cage pose, deformed vertices (V, 3) float32) per frame, deformed in chunks on the device.

    After each chunk a binary (crate) layer is saved and reloaded: crate files take new data by appending, and a
    reloaded layer reads its samples from the file on demand, so memory stays bounded by a chunk instead of
    growing with the animation (1,000 frames of 26k vertices: 26 MiB instead of 300, and faster). A text layer
    is rewritten whole on every save, so it is saved once, at the end."""
    for start in range(0, len(positions), FRAMES_PER_CHUNK):
        chunk = positions[start : start + FRAMES_PER_CHUNK]
        deformed = binding.deform(chunk)  # all frames of the chunk in one launch on the binding's device
        for k, frame_points in enumerate(deformed):
            yield float(frames[start + k]), chunk[k], frame_points
        if ext != ".usda" and start + FRAMES_PER_CHUNK < len(positions):
            _save(layer, path)
            layer.Reload()


def write_animation(path, binding, poses: Poses, fps: float | None = None, with_cage: bool = False,
                    with_weights: bool = False, up_axis: str | None = None, meters_per_unit: float | None = None,
                    normals: np.ndarray | None = None, asset=None) -> str:
    """Write the bound mesh, deformed by every cage pose, as animated USD.

    For a binding of a USD asset, a layer over the asset (overrides only, see the module docstring); otherwise a
    standalone stage with one ``UsdGeom.Mesh`` per bound part (``/Root/Mesh`` for a single mesh). ``points`` and
    ``extent`` are time samples at the poses' frame numbers; the stage's start and end time codes and time codes
    per second follow the poses. The file is written under a temporary name in the target folder and renamed when
    complete.

    Parameters
    ----------
    path : str | os.PathLike, ``.usd`` or ``.usdc`` (binary crate) or ``.usda`` (text)
    binding : Binding
    poses : Poses, e.g. from :func:`warp_stokes.load_poses`
    fps : float, optional, time codes per second (default: the poses' own rate when they came from a USD stage,
        else the asset's, else 24)
    with_cage : bool, also write the animated cage: ``/Root/Cage`` (purpose guide) in a standalone stage; over
        an asset, the cage prim's points, when the binding's cage is a prim of the asset
    with_weights : bool, write the weights as the primvar ``primvars:stokesWeights`` (vertex interpolation,
        element size = handles)
    up_axis : "Y" | "Z", optional (standalone: default "Y"; over an asset: the asset's, which cannot be changed)
    meters_per_unit : float, optional (as ``up_axis``; default 1)
    normals : (V, 3) array, optional, standalone only: rest normals that make the output carry normals (default:
        the binding's, when the mesh file had them); recomputed for every frame
    asset : path, optional, the USD asset to layer over, where it is not at the path recorded in the binding

    Returns
    -------
    str, the path written

    Examples
    --------
    >>> write_animation("walk.usd", binding, load_poses("walk/", binding.cage_faces))  # doctest: +SKIP
    """
    ext, positions, frames = _check(path, binding, poses, fps)
    path = os.fspath(path)
    if binding.asset is not None or asset is not None:
        if normals is not None:
            raise WarpStokesError("normals: a layer over an asset recomputes the normals the asset authors")
        return _write_layer(path, ext, binding, positions, frames, poses, fps, with_cage, with_weights, up_axis,
                            meters_per_unit, asset)
    return _write_standalone(path, ext, binding, positions, frames, poses, fps, with_cage, with_weights,
                             up_axis or "Y", 1.0 if meters_per_unit is None else meters_per_unit, normals)


def _new_stage(tmp: str, ext: str):
    from pxr import Sdf, Usd

    layer = Sdf.Layer.CreateNew(tmp, args={"format": "usda"} if ext == ".usda" else {"format": "usdc"})
    return layer, Usd.Stage.Open(layer)


def _prim_name(path: str, taken: set) -> str:
    """A valid, unused USD prim name for a part (its node name or path's last element)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", str(path).rstrip("/").split("/")[-1].split(":")[-1]) or "Mesh"
    if name[0].isdigit():
        name = "_" + name
    base, k = name, 1
    while name in taken:
        k += 1
        name = f"{base}_{k}"
    taken.add(name)
    return name


def _write_standalone(path, ext, binding, positions, frames, poses, fps, with_cage, with_weights, up_axis,
                      meters_per_unit, normals) -> str:
    from pxr import Sdf, Usd, UsdGeom, Vt

    if up_axis not in ("Y", "Z"):
        raise WarpStokesError(f"up axis must be 'Y' or 'Z', got {up_axis!r}")
    if not meters_per_unit > 0:
        raise WarpStokesError(f"meters per unit must be positive, got {meters_per_unit!r}")
    rate = fps or poses.time_codes_per_second or 24.0
    slices = binding.part_slices()
    counts, indices = binding.mesh_face_counts, binding.mesh_face_indices
    # each part's polygons: the polygons are in part order, each over its part's vertices
    corner_offsets = np.concatenate([[0], np.cumsum(counts)])
    face_part = np.searchsorted(np.array([s.stop for s in slices]), indices[corner_offsets[:-1]], side="right")
    corner_part = np.repeat(face_part, counts)
    normals = binding.mesh_normals if normals is None else np.asarray(normals)
    with atomic_output(path, ext) as tmp:
        layer, stage = _new_stage(tmp, ext)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
        _set_timing(stage, frames, rate)
        root = UsdGeom.Xform.Define(stage, "/Root")
        stage.SetDefaultPrim(root.GetPrim())
        taken, writers = set(), []
        for k, (part, rows) in enumerate(zip(binding.parts, slices)):
            faces, corners = np.flatnonzero(face_part == k), np.flatnonzero(corner_part == k)
            part_counts, part_indices = counts[faces], indices[corners] - rows.start
            name = "Mesh" if len(slices) == 1 else _prim_name(part["path"], taken)
            mesh = _define_mesh(stage, f"/Root/{name}", part_counts, part_indices, binding.mesh_vertices[rows])
            if binding.mesh_uvs is not None:
                st, st_indices = binding.mesh_uvs
                used, local = np.unique(st_indices[corners], return_inverse=True)
                primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                                   UsdGeom.Tokens.faceVarying)
                primvar.Set(Vt.Vec2fArray.FromNumpy(st[used].astype(np.float32)))
                primvar.SetIndices(Vt.IntArray.FromNumpy(local.astype(np.int32).ravel()))
            plan = None
            if normals is not None:
                plan = NormalsPlan(part_counts, part_indices, "vertex", rows.stop - rows.start)
                mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
            if with_weights:
                primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
                    "stokesWeights", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex, binding.n_handles)
                primvar.Set(Vt.FloatArray.FromNumpy(binding.weights[rows].ravel()))
            writers.append((rows, mesh.GetPointsAttr(), mesh.GetExtentAttr(), mesh.GetNormalsAttr(), plan))
        cage = None
        if with_cage:
            cage = _define_mesh(stage, "/Root/Cage", np.full(len(binding.cage_faces), 3), binding.cage_faces.ravel(),
                                binding.cage_vertices)
            UsdGeom.Imageable(cage).CreatePurposeAttr(UsdGeom.Tokens.guide)
        for t, pose, deformed in _frames(binding, positions, frames, layer, path, ext):
            time = Usd.TimeCode(t)
            for rows, points, extent, normals_attr, plan in writers:
                local = deformed[rows]
                points.Set(_vec3f(local), time)
                extent.Set(_extent(local), time)
                if plan is not None:
                    normals_attr.Set(_vec3f(plan(local)), time)
            if cage is not None:
                cage.GetPointsAttr().Set(_vec3f(pose), time)
                cage.GetExtentAttr().Set(_extent(pose), time)
        _save(layer, path)
        del stage, layer
    return path


def _asset_path(binding, asset) -> str:
    recorded = (binding.asset or {}).get("path")
    path = os.path.abspath(os.fspath(asset if asset is not None else recorded))
    if not os.path.isfile(path):
        hint = " (moved since binding? give its place with --asset)" if asset is None else ""
        raise WarpStokesError(f"{path}: the binding's USD asset is not there{hint}")
    return path


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
            self._matrix, self._inverse = matrix, np.linalg.inv(matrix)
        local = np.asarray(world[self.rows], dtype=np.float64) @ self._inverse[:3, :3] + self._inverse[3, :3]
        self.points.Set(_vec3f(local), time)
        self.extent.Set(_extent(local), time)
        if self.plan is not None:
            self.normals_attr.Set(_vec3f(self.plan(local)), time)


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
    plan = NormalsPlan(counts, indices, interpolation, len(rest),
                       None if rest_normals is None else np.asarray(rest_normals), left)
    return _Override(mesh, rows, plan, attr)


def _write_layer(path, ext, binding, positions, frames, poses, fps, with_cage, with_weights, up_axis,
                 meters_per_unit, asset) -> str:
    from pxr import Sdf, Usd, UsdGeom, Vt

    from .usd_asset import open_stage, stage_metadata

    asset_path = _asset_path(binding, asset)
    metadata = stage_metadata(open_stage(asset_path, WarpStokesError))
    if up_axis is not None and up_axis != metadata["up_axis"]:
        raise WarpStokesError(f"up axis {up_axis}: a layer over {asset_path} keeps its up axis "
                              f"{metadata['up_axis']}")
    if meters_per_unit is not None and float(meters_per_unit) != metadata["meters_per_unit"]:
        raise WarpStokesError(f"meters per unit {meters_per_unit:g}: a layer over {asset_path} keeps its "
                              f"{metadata['meters_per_unit']:g}")
    rate = fps or poses.time_codes_per_second or metadata["time_codes_per_second"] or 24.0
    cage_prim = binding.settings.get("cage_prim")
    if with_cage and not cage_prim:
        raise WarpStokesError("--with-cage: the binding's cage is not a prim of its asset; over an asset only its "
                              "own prims are overridden (write a standalone stage from a binding of the mesh file)")
    relative = os.path.relpath(asset_path, os.path.dirname(os.path.abspath(path))).replace(os.sep, "/")
    with atomic_output(path, ext) as tmp:
        layer, _ = _new_stage(tmp, ext)
        layer.subLayerPaths.append(relative)
        stage = Usd.Stage.Open(layer)  # composed with the asset; edits go to the new layer, as overrides
        if metadata["default_prim"]:
            layer.defaultPrim = metadata["default_prim"]
        UsdGeom.SetStageUpAxis(stage, metadata["up_axis"])
        UsdGeom.SetStageMetersPerUnit(stage, metadata["meters_per_unit"])
        _set_timing(stage, frames, rate)
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
        for t, pose, deformed in _frames(binding, positions, frames, layer, path, ext):
            time = Usd.TimeCode(t)
            cache = UsdGeom.XformCache(time)
            for part in parts:
                part.write(deformed, cache, time)
            if cage is not None:
                cage.write(pose, cache, time)
        _save(layer, path)
        del stage, layer
    return path


def _save(layer, path) -> None:
    """Save the layer, a failure (a full disk, a vanished folder) as one line naming ``path``: USD reports it as
    a Tf error (or a False return), and the temporary file is then removed by ``atomic_output``."""
    from pxr import Tf

    try:
        saved = layer.Save()
    except Tf.ErrorException as exc:
        reason = " ".join(str(exc).split())
        raise WarpStokesError(f"{path}: could not write the USD file ({reason[:200]})") from None
    if not saved:
        raise WarpStokesError(f"{path}: could not write the USD file (is the disk full or the folder gone?)")
