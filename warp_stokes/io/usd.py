"""Animated USD out: the deformed mesh as time samples, written with pxr (usd-core)."""

from __future__ import annotations

import os

import numpy as np

from ..errors import WarpStokesError
from .files import atomic_output
from .poses import Poses

__all__ = ["write_animation", "FRAMES_PER_CHUNK"]

#: frames deformed per device launch (bounded so that frames x vertices x 12 bytes stays small)
FRAMES_PER_CHUNK = 64


def _extent(points: np.ndarray):
    from pxr import Gf, Vt

    lo, hi = points.min(axis=0), points.max(axis=0)
    return Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))])


def _define_mesh(stage, path: str, faces: np.ndarray, rest: np.ndarray):
    from pxr import UsdGeom, Vt

    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(np.asarray(faces, dtype=np.int32).ravel().tolist()))
    mesh.CreateSubdivisionSchemeAttr("none")
    mesh.CreateOrientationAttr("rightHanded")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(rest.astype(np.float32)))
    mesh.CreateExtentAttr(_extent(rest))
    return mesh


def write_animation(path, binding, poses: Poses, fps: float = 24.0, with_cage: bool = False,
                    with_weights: bool = False, up_axis: str = "Y", meters_per_unit: float = 1.0,
                    normals: np.ndarray | None = None) -> str:
    """Write the bound mesh, deformed by every cage pose, as an animated USD stage.

    One ``UsdGeom.Mesh`` (``/Root/Mesh``) with its topology authored once and ``points`` and ``extent`` as time
    samples at the poses' frame numbers; the stage's start and end time codes, time codes per second, up axis
    and meters per unit are set. The file is written under a temporary name in the target folder and renamed
    when complete.

    Parameters
    ----------
    path : str | os.PathLike, ``.usd`` or ``.usdc`` (binary crate) or ``.usda`` (text)
    binding : Binding
    poses : Poses, e.g. from :func:`warp_stokes.load_poses`
    fps : float, time codes per second
    with_cage : bool, also write the animated cage as ``/Root/Cage``
    with_weights : bool, write the weights as the primvar ``primvars:stokesWeights`` (vertex interpolation,
        element size = handles)
    up_axis : "Y" | "Z"
    meters_per_unit : float
    normals : (V, 3) array, optional rest normals, authored as a rest value (default: the binding's, when
        the mesh file had normals)

    Returns
    -------
    str, the path written

    Examples
    --------
    >>> write_animation("walk.usd", binding, load_poses("walk/", binding.cage_faces))  # doctest: +SKIP
    """
    from pxr import Sdf, Usd, UsdGeom, Vt

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".usd", ".usdc", ".usda"):
        raise WarpStokesError(f"{path}: the output must end in .usd, .usdc or .usda")
    if up_axis not in ("Y", "Z"):
        raise WarpStokesError(f"up axis must be 'Y' or 'Z', got {up_axis!r}")
    if not fps > 0:
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

    with atomic_output(path, ext) as tmp:
        layer = Sdf.Layer.CreateNew(tmp, args={"format": "usda"} if ext == ".usda" else {"format": "usdc"})
        stage = Usd.Stage.Open(layer)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
        stage.SetTimeCodesPerSecond(float(fps))
        stage.SetFramesPerSecond(float(fps))
        stage.SetStartTimeCode(float(frames.min()))
        stage.SetEndTimeCode(float(frames.max()))
        root = UsdGeom.Xform.Define(stage, "/Root")
        stage.SetDefaultPrim(root.GetPrim())

        mesh = _define_mesh(stage, "/Root/Mesh", binding.mesh_faces, binding.mesh_vertices)
        normals = getattr(binding, "mesh_normals", None) if normals is None else normals
        if normals is not None:
            mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(normals, dtype=np.float32)))
            mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        if with_weights:
            primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
                "stokesWeights", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex, binding.n_handles
            )
            primvar.Set(Vt.FloatArray.FromNumpy(binding.weights.ravel()))
        points, extent = mesh.GetPointsAttr(), mesh.GetExtentAttr()
        cage = None
        if with_cage:
            cage = _define_mesh(stage, "/Root/Cage", binding.cage_faces, binding.cage_vertices)
            UsdGeom.Imageable(cage).CreatePurposeAttr(UsdGeom.Tokens.guide)
        for start in range(0, len(positions), FRAMES_PER_CHUNK):
            chunk = positions[start : start + FRAMES_PER_CHUNK]
            deformed = binding.deform(chunk)  # all frames of the chunk in one launch on the binding's device
            for k, frame_points in enumerate(deformed):
                t = Usd.TimeCode(float(frames[start + k]))
                points.Set(Vt.Vec3fArray.FromNumpy(frame_points), t)
                extent.Set(_extent(frame_points), t)
                if cage is not None:
                    cage_points = chunk[k].astype(np.float32)
                    cage.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(cage_points), t)
                    cage.GetExtentAttr().Set(_extent(cage_points), t)
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
