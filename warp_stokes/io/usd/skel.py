"""The cage animation as a UsdSkel rig: a ``Skeleton`` of one joint per handle, a ``SkelAnimation`` of the joints'
translations per time code, and the bound meshes skinned to it (``primvars:skel:jointIndices`` /
``jointWeights``), instead of baked points.

Spaces: the joints live in the space of the ``SkelRoot`` (the skeleton is its child, with no transform of its own):
bind transforms ``translate(S0^-1 c_l)`` with ``S0`` the root's rest local-to-world, animated translations
``S(t)^-1 c'_l(t)``, and each skinned mesh's ``geomBindTransform`` its rest transform relative to the root. UsdSkel
then moves a rest point ``p`` to ``S(t) (S0^-1 p + sum_l w_l (S(t)^-1 c'_l - S0^-1 c_l))``, which is
``sum_l w_l c'_l + S(t) S0^-1 (p - sum_l w_l c_l)`` in world space: the cage deformation, up to the skin's own rest
error (zero with all influences, to the binding's linear precision), also where the root moves. (World-space joints
through ``!resetXformStack!`` would be simpler, but Blender's importer ignores it, and takes ``geomBindTransform`` as
the mesh's transform under its parent: the root is therefore the bound meshes' nearest common parent.)

Normals: translation-only joints do not turn normals, so a skinned mesh carries no authored normals (a standalone
stage writes none; over an asset the bound prims' normals are blocked) and consumers compute them from the skinned
points.

Two forms, as :mod:`.standalone` and :mod:`.layer`: a stage ``/Root`` (the ``SkelRoot``) with the meshes (and the
cage, skinned rigidly), and a layer over an asset whose bound prims' nearest common ancestor becomes the ``SkelRoot``
(an override of its type); there the cage prim, wherever it is, gets its points per time code (a few hundred points).
"""

from __future__ import annotations

import os

import numpy as np

from ...errors import WarpStokesError
from ..outputs import atomic_output, together
from .common import deformed_frames, define_mesh, extent, new_stage, save_layer, set_timing, vec3f
from .layers import reads_usd

__all__ = ["write_standalone_skeleton", "write_layer_skeleton"]


def _matrices(points: np.ndarray):
    """A Vt.Matrix4dArray of translations to ``points`` (L, 3) (row vectors: translation in the last row)."""
    from pxr import Vt

    matrices = np.broadcast_to(np.eye(4), (len(points), 4, 4)).copy()
    matrices[:, 3, :3] = points
    return Vt.Matrix4dArray.FromNumpy(matrices)


def _define_skeleton(stage, root: str, rest_cage: np.ndarray, joints: list[str]):
    """The ``Skeleton`` and ``SkelAnimation`` under ``root``: joints in the root's space (``rest_cage`` given in it),
    bind and rest transforms the rest cage, identity rotations and unit scales. Returns the skeleton and the
    animation's translations attribute."""
    from pxr import Gf, UsdSkel, Vt

    skeleton = UsdSkel.Skeleton.Define(stage, _free_path(stage, f"{root}/CageSkeleton"))
    skeleton.CreateJointsAttr(joints)
    skeleton.CreateBindTransformsAttr(_matrices(rest_cage))
    skeleton.CreateRestTransformsAttr(_matrices(rest_cage))
    animation = UsdSkel.Animation.Define(stage, _free_path(stage, f"{root}/CageAnimation"))
    animation.CreateJointsAttr(joints)
    animation.CreateRotationsAttr(Vt.QuatfArray([Gf.Quatf(1.0)] * len(joints)))
    animation.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0, 1.0, 1.0)] * len(joints)))
    translations = animation.CreateTranslationsAttr(vec3f(rest_cage))
    UsdSkel.BindingAPI.Apply(skeleton.GetPrim()).CreateAnimationSourceRel().SetTargets([animation.GetPath()])
    return skeleton, translations


def _free_path(stage, path: str) -> str:
    """``path``, or ``path_2``, ``path_3``, ... where a prim is already there."""
    candidate, k = path, 1
    while stage.GetPrimAtPath(candidate).IsValid():
        k += 1
        candidate = f"{path}_{k}"
    return candidate


def _skin_prim(prim, skeleton, indices: np.ndarray, weights: np.ndarray, bind_transform) -> None:
    """Bind a mesh prim to the skeleton: the binding API, its joints and weights per vertex (element size K) and
    ``bind_transform`` (4 x 4, row vectors: its rest points into the skeleton's space) as the geom bind transform."""
    from pxr import Gf, UsdSkel, Vt

    binding = UsdSkel.BindingAPI.Apply(prim)
    binding.CreateSkeletonRel().SetTargets([skeleton.GetPath()])
    k = indices.shape[1]
    binding.CreateJointIndicesPrimvar(False, k).Set(Vt.IntArray.FromNumpy(indices.astype(np.int32).ravel()))
    binding.CreateJointWeightsPrimvar(False, k).Set(Vt.FloatArray.FromNumpy(weights.astype(np.float32).ravel()))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(np.asarray(bind_transform, dtype=np.float64).tolist()))


def _key_frames(binding, positions, frames, translations, root_extent, root, pad: float, layer, path, ext,
                cage=None):
    """The joints' translations per time code, in the space of the ``root`` prim (None: world space), and the
    SkelRoot's extent (the deformed points' box in that space, widened by the skin's measured error ``pad``, scaled
    into it); ``cage``: an override that writes the cage prim's points per time code."""
    from pxr import Usd, UsdGeom

    for t, pose, deformed in deformed_frames(binding, positions, frames, layer, path, ext):
        time = Usd.TimeCode(t)
        cache = UsdGeom.XformCache(time)
        inverse = np.eye(4) if root is None else _world_to_local(root, cache, time)
        translations.Set(vec3f(_transform(pose, inverse)), time)
        local, scale = _transform(deformed, inverse), float(np.linalg.norm(inverse[:3, :3], ord=2))
        root_extent.Set(extent(np.stack([local.min(axis=0) - pad * scale, local.max(axis=0) + pad * scale])), time)
        if cage is not None:
            cage.write(pose, cache, time)


def _world_to_local(prim, cache, time) -> np.ndarray:
    """The inverse of ``prim``'s local-to-world transform (4 x 4, row vectors) at ``time``."""
    try:
        return np.linalg.inv(np.array(cache.GetLocalToWorldTransform(prim)))
    except np.linalg.LinAlgError:
        raise WarpStokesError(f"{prim.GetPath()}: its local-to-world transform at time {time.GetValue():g} is "
                              "singular (scaled to zero?); it cannot be the skin's SkelRoot") from None


def _transform(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Points (N, 3) through a 4 x 4 affine transform in row-vector form."""
    return np.asarray(points, dtype=np.float64) @ matrix[:3, :3] + matrix[3, :3]


def write_standalone_skeleton(path, ext, binding, skin, joints, positions, frames, rate, with_cage, up_axis,
                              meters_per_unit, pad: float, metadata: dict) -> str:
    """``/Root`` (SkelRoot) with the skeleton, its animation and one skinned mesh per part (``/Root/Mesh`` for one);
    see :func:`warp_stokes.binding.skin.write_skin` for the arguments."""
    from pxr import UsdGeom, UsdSkel

    from .looks import StageLooks
    from .standalone import _define_parts

    looks = StageLooks(path, binding)
    with together([path, *looks.outputs()]), atomic_output(path, ext) as tmp:  # the images renamed with the layer
        looks.write_images()
        layer, stage = new_stage(tmp, ext)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
        set_timing(stage, frames, rate)
        layer.customLayerData = {"warpStokes": metadata}
        root = UsdSkel.Root.Define(stage, "/Root")
        stage.SetDefaultPrim(root.GetPrim())
        skeleton, translations = _define_skeleton(stage, "/Root", binding.cage_vertices, joints)
        # the parts' points are the binding's, in world space: their geom bind transform is the identity
        meshes = []
        for rows, points, *_ in _define_parts(stage, binding, None, False):
            _skin_prim(points.GetPrim(), skeleton, skin.indices[rows], skin.weights[rows], np.eye(4))
            meshes.append(UsdGeom.Mesh(points.GetPrim()))
        looks.define(stage, binding, meshes)
        if with_cage:
            cage = define_mesh(stage, "/Root/Cage", np.full(len(binding.cage_faces), 3), binding.cage_faces.ravel(),
                               binding.cage_vertices)
            UsdGeom.Imageable(cage).CreatePurposeAttr(UsdGeom.Tokens.guide)
            n = binding.n_handles
            _skin_prim(cage.GetPrim(), skeleton, np.arange(n)[:, None], np.ones((n, 1)), np.eye(4))
        _key_frames(binding, positions, frames, translations, root.CreateExtentAttr(), None, pad, layer, path, ext)
        save_layer(layer, path)
        del stage, layer
    return path


def _common_ancestor(paths) -> str:
    """The deepest prim path above all ``paths`` (each excluded itself), or "/" when they share none."""
    from pxr import Sdf

    parents = [Sdf.Path(p).GetParentPath() for p in paths]
    common = parents[0]
    for p in parents[1:]:
        common = common.GetCommonPrefix(p)
    return str(common)


def write_layer_skeleton(path, ext, binding, skin, joints, positions, frames, rate, with_cage, asset_path: str,
                         metadata_of_asset: dict, pad: float, metadata: dict) -> str:
    """A layer over the asset: the bound prims' nearest common ancestor made the ``SkelRoot``, the skeleton and
    animation under it, the bound prims skinned by overrides, and with ``with_cage`` the cage prim's points per time
    code."""
    from pxr import Usd, UsdGeom, UsdSkel

    from .layer import _Override

    paths = [part["path"] for part in binding.parts]
    cage_prim = binding.settings.get("cage_prim")
    if with_cage and not cage_prim:
        raise WarpStokesError("--with-cage: the binding's cage is not a prim of its asset; over an asset only its "
                              "own prims are written (write a standalone stage from a binding of the mesh file)")
    root_path = _common_ancestor(paths)
    if root_path == "/":
        raise WarpStokesError(f"{asset_path}: the bound prims ({', '.join(paths)}) have no common ancestor prim to "
                              "become the SkelRoot; put them under one Xform in the asset")
    relative = os.path.relpath(asset_path, os.path.dirname(os.path.abspath(path))).replace(os.sep, "/")
    rest_time = (binding.asset or {}).get("rest_time")
    rest = Usd.TimeCode.EarliestTime() if rest_time is None else Usd.TimeCode(rest_time)
    with atomic_output(path, ext) as tmp:
        layer, _ = new_stage(tmp, ext)
        layer.subLayerPaths.append(relative)
        stage = Usd.Stage.Open(layer)
        if metadata_of_asset["default_prim"]:
            layer.defaultPrim = metadata_of_asset["default_prim"]
        UsdGeom.SetStageUpAxis(stage, metadata_of_asset["up_axis"])
        UsdGeom.SetStageMetersPerUnit(stage, metadata_of_asset["meters_per_unit"])
        set_timing(stage, frames, rate)
        layer.customLayerData = {"warpStokes": metadata}
        root_prim = stage.GetPrimAtPath(root_path)
        if root_prim.IsA(UsdGeom.Gprim):
            raise WarpStokesError(f"{asset_path}: the bound prims' common parent {root_path} is a "
                                  f"{root_prim.GetTypeName()}, which cannot become the SkelRoot")
        root_prim.SetTypeName("SkelRoot")  # an override of the ancestor's type, in this layer
        root = UsdSkel.Root(root_prim)
        root_inverse = _world_to_local(root_prim, UsdGeom.XformCache(rest), rest)
        skeleton, translations = _define_skeleton(stage, root_path, _transform(binding.cage_vertices, root_inverse),
                                                  joints)
        for part, rows in zip(binding.parts, binding.part_slices()):
            mesh = _bound_mesh(stage, asset_path, part["path"], rows.stop - rows.start, rest_time)
            for attribute in (mesh.GetNormalsAttr(), UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals").GetAttr()):
                if attribute and attribute.HasAuthoredValue():
                    attribute.Block()  # stale under translation-only joints: consumers compute them
            # the mesh's rest transform relative to the root (row vectors: local -> world -> root)
            relative_to_root = np.asarray(part["to_world"], dtype=np.float64) @ root_inverse
            _skin_prim(mesh.GetPrim(), skeleton, skin.indices[rows], skin.weights[rows], relative_to_root)
        cage = None
        if with_cage:
            cage = _Override(_bound_mesh(stage, asset_path, cage_prim, binding.n_handles, rest_time),
                             slice(0, binding.n_handles))
        _key_frames(binding, positions, frames, translations, root.CreateExtentAttr(), root_prim, pad, layer, path,
                    ext, cage)
        save_layer(layer, path)
        del stage, layer
    return path


@reads_usd(WarpStokesError, path_argument=1)
def _bound_mesh(stage, asset_path: str, prim_path: str, n_points: int, rest_time):
    """The asset's mesh at ``prim_path``, checked against the binding (the asset may have changed since)."""
    from pxr import Usd, UsdGeom

    prim = stage.GetPrimAtPath(prim_path)
    if not prim.IsValid() or not prim.IsA(UsdGeom.Mesh):
        raise WarpStokesError(f"{asset_path}: the bound prim {prim_path} is no longer a mesh in the asset")
    mesh = UsdGeom.Mesh(prim)
    time = Usd.TimeCode.EarliestTime() if rest_time is None else Usd.TimeCode(rest_time)
    rest = mesh.GetPointsAttr().Get(time)
    if rest is None or len(rest) != n_points:
        raise WarpStokesError(f"{asset_path}: {prim_path} has {0 if rest is None else len(rest)} points, the "
                              f"binding {n_points}: the asset changed since binding; bind it again")
    return mesh
