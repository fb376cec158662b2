"""A UsdSkel asset's animation as mesh frames, by pxr's own skinning: ``UsdSkel.Cache`` finds each skinned mesh's
skeleton, ``SkeletonQuery.ComputeSkinningTransforms`` poses it, ``BlendShapeQuery`` applies its blend shapes and
``SkinningQuery.ComputeSkinnedPoints`` (or ``ComputeSkinnedTransform`` for a rigidly deformed prim) skins it, in the
skeleton's space, then the skeleton's local-to-world. Meshes without a skeleton give their own points in world
space. A named animation is bound to every skeleton in the stage's session layer, in memory: the files are only read.
"""

from __future__ import annotations

import numpy as np

from ...errors import BindingError
from ..frame_times import sample_times
from .asset import mesh_prim, open_stage, time_codes_per_second, to_world, world_matrix
from .layers import reads_usd

__all__ = ["usd_skinned_frames", "skel_animations"]


def skel_animations(stage) -> list:
    """The stage's ``SkelAnimation`` prims, in traversal order."""
    from pxr import UsdSkel

    return [prim for prim in stage.Traverse() if prim.IsA(UsdSkel.Animation)]


def _bind_animation(stage, path: str, animation) -> None:
    """Bind the SkelAnimation named ``animation`` (its prim path or name) to every skeleton, in the session layer;
    a name the stage does not have is one error listing those it has."""
    from pxr import Usd, UsdSkel

    animations = skel_animations(stage)
    text = str(animation)
    chosen = [p for p in animations if text in (str(p.GetPath()), p.GetName())]
    if not chosen:
        listed = ", ".join(str(p.GetPath()) for p in animations[:20]) or "none"
        raise BindingError(f"{path}: no animation {text!r}; its animations (SkelAnimation prims): {listed}")
    skeletons = [prim for prim in stage.Traverse() if prim.IsA(UsdSkel.Skeleton)]
    if not skeletons:
        raise BindingError(f"{path}: the stage has no Skeleton for animation {text!r} to move")
    with Usd.EditContext(stage, stage.GetSessionLayer()):  # in memory: the asset's own layers are not edited
        for skeleton in skeletons:
            UsdSkel.BindingAPI.Apply(skeleton).CreateAnimationSourceRel().SetTargets([chosen[0].GetPath()])


def _skinning_targets(stage) -> dict:
    """{mesh prim path: (SkeletonQuery, SkinningQuery)} for every skinned prim under the stage's SkelRoots."""
    from pxr import Usd, UsdSkel

    cache = UsdSkel.Cache()
    targets = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdSkel.Root):
            continue
        root = UsdSkel.Root(prim)
        cache.Populate(root, Usd.PrimDefaultPredicate)
        for binding in cache.ComputeSkelBindings(root, Usd.PrimDefaultPredicate):
            skeleton = cache.GetSkelQuery(binding.GetSkeleton())
            for skinning in binding.GetSkinningTargets():
                targets[str(skinning.GetPrim().GetPath())] = (skeleton, skinning)
    return targets


def _key_times(meshes, targets: dict) -> np.ndarray:
    """Every time code at which something moves a mesh: its skeleton's animation (joints, blend shape weights), its
    points' samples, its transforms' samples."""
    from pxr import UsdGeom

    times = set()
    for mesh in meshes:
        path = str(mesh.GetPrim().GetPath())
        if path in targets:
            skeleton, _ = targets[path]
            animation = skeleton.GetAnimQuery()
            if animation:
                times.update(animation.GetJointTransformTimeSamples())
                times.update(animation.GetBlendShapeWeightTimeSamples())
        times.update(mesh.GetPointsAttr().GetTimeSamples())
        prim = mesh.GetPrim()
        while prim and not prim.IsPseudoRoot():
            if prim.IsA(UsdGeom.Xformable):
                times.update(UsdGeom.Xformable(prim).GetTimeSamples())
            prim = prim.GetParent()
    return np.array(sorted(times), dtype=np.float64)


def _blend_shaped(skeleton, skinning, points, time) -> None:
    """Apply the prim's blend shapes at ``time`` to ``points`` (a Vt.Vec3fArray, in place)."""
    from pxr import UsdSkel

    animation = skeleton.GetAnimQuery()
    weights = animation.ComputeBlendShapeWeights(time) if animation else None
    if weights is None:
        return
    mapper = skinning.GetBlendShapeMapper()
    if mapper is not None and not mapper.IsNull():
        weights = mapper.Remap(weights)
    query = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(skinning.GetPrim()))
    sub_weights, shape_indices, sub_indices = query.ComputeSubShapeWeights(weights)
    query.ComputeDeformedPoints(sub_weights, shape_indices, sub_indices, query.ComputeBlendShapePointIndices(),
                                query.ComputeSubShapePointOffsets(), points)


def _posed_points(mesh, targets: dict, time, path: str) -> np.ndarray:
    """A mesh's world-space points at ``time``: skinned by its skeleton, or as they are."""
    from pxr import UsdGeom

    prim = mesh.GetPrim()
    points = mesh.GetPointsAttr().Get(time)
    if points is None or len(points) == 0:
        raise BindingError(f"{path}: {prim.GetPath()} has no points at time {time:g}")
    target = targets.get(str(prim.GetPath()))
    if target is None:
        return to_world(np.asarray(points), world_matrix(prim, time))
    skeleton, skinning = target
    if skinning.HasBlendShapes():
        _blend_shaped(skeleton, skinning, points, time)
    transforms = skeleton.ComputeSkinningTransforms(time)
    skeleton_to_world = np.array(UsdGeom.XformCache(time).GetLocalToWorldTransform(skeleton.GetPrim()))
    if skinning.IsRigidlyDeformed():
        moved = np.array(skinning.ComputeSkinnedTransform(transforms, time), dtype=np.float64)
        return to_world(np.asarray(points), moved @ skeleton_to_world)
    if not skinning.ComputeSkinnedPoints(transforms, points, time):
        raise BindingError(f"{path}: UsdSkel could not skin {prim.GetPath()} at time {time:g} (its joint influences "
                           "do not fit its points)")
    return to_world(np.asarray(points), skeleton_to_world)  # skinned points are in the skeleton's space


def _meshes(stage, path: str, mesh_prims) -> list:
    """The mesh prims named, else every mesh the stage traverses (as ``bind`` reads the asset)."""
    from pxr import UsdGeom

    if mesh_prims:
        return [mesh_prim(stage, p, path, BindingError) for p in dict.fromkeys(mesh_prims)]
    meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    if not meshes:
        raise BindingError(f"{path}: the stage has no mesh prims")
    return meshes


@reads_usd(BindingError)
def usd_skinned_frames(path: str, animation=None, fps: float | None = None, mesh_prims=None):
    """A UsdSkel asset's meshes posed at its animation's time codes (or every ``stage rate / fps`` time codes from
    the first to the last).

    Parameters
    ----------
    path : str, a USD file
    animation : str, optional, a SkelAnimation prim's path or name, bound to every skeleton for this reading
    fps : float, optional, samples per second instead of the animation's own time codes
    mesh_prims : list of str, optional, the meshes (default: every mesh prim, in traversal order)

    Returns
    -------
    positions : (F, V, 3) float64 world-space points, the meshes concatenated in order
    times : (F,) time codes
    rate : the stage's time codes per second

    Raises
    ------
    BindingError
        One line naming the file: no skinned mesh, no animation, an animation it does not have (listing those it has).

    Examples
    --------
    >>> positions, times, rate = usd_skinned_frames("character.usda", animation="Walk")   # doctest: +SKIP
    """
    stage = open_stage(path, BindingError)
    if animation is not None:
        _bind_animation(stage, path, animation)
    meshes = _meshes(stage, path, mesh_prims)
    targets = _skinning_targets(stage)
    if not any(str(m.GetPrim().GetPath()) in targets for m in meshes):
        raise BindingError(f"{path}: none of its meshes is skinned to a skeleton (UsdSkel); its animations: "
                           + (", ".join(str(p.GetPath()) for p in skel_animations(stage)[:20]) or "none"))
    keys = _key_times(meshes, targets)
    if len(keys) == 0:
        raise BindingError(f"{path}: nothing is animated (no time samples on its skeletons' animations, points or "
                           "transforms)")
    rate = time_codes_per_second(stage, path)
    times = sample_times(keys, None if fps is None else rate / fps, path)
    sizes = [len(m.GetPointsAttr().Get(float(times[0])) or []) for m in meshes]
    frames = []
    for time in times:
        parts = [_posed_points(m, targets, float(time), path) for m in meshes]
        if [len(p) for p in parts] != sizes:
            raise BindingError(f"{path}: the meshes' point counts change at time {time:g}")
        frames.append(np.concatenate(parts))
    return np.stack(frames), times, rate
