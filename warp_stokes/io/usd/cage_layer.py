"""A cage as a prim of a new layer over a USD asset: the asset sublayered by a relative path, and one mesh prim
defined in the layer, so that ``bind LAYER --cage-prim PATH`` finds the asset's meshes and the cage in one stage."""

from __future__ import annotations

import os

import numpy as np

from ...errors import WarpStokesError
from ..inputs import inputs_of
from ..outputs import atomic_output
from .common import define_mesh, new_stage, save_layer

__all__ = ["write_cage_layer", "check_cage_layer", "default_cage_prim"]


def default_cage_prim(asset) -> str:
    """Where a made cage goes in an asset: ``/<default prim>/MadeCage`` (so that a reference to the asset brings
    it along), or ``/MadeCage`` in a stage without a default prim.

    Examples
    --------
    >>> default_cage_prim("examples/arm/arm.usda")  # doctest: +SKIP
    '/Arm/MadeCage'
    """
    from .asset import open_stage

    return _default_prim_path(open_stage(os.fspath(asset), WarpStokesError))


def _default_prim_path(stage) -> str:
    default = stage.GetDefaultPrim()
    return f"{default.GetPath()}/MadeCage" if default else "/MadeCage"


def check_cage_layer(path, asset, prim: str | None = None) -> str:
    """Before any work: the checks of :func:`write_cage_layer` (the output is no file of the asset, the prim path is
    absolute and new); returns the prim path (``prim`` or :func:`default_cage_prim`).

    Examples
    --------
    >>> check_cage_layer("arm_cage.usda", "examples/arm/arm.usda")  # doctest: +SKIP
    '/Arm/MadeCage'
    """
    from pxr import Sdf

    from .asset import open_stage

    path, asset = os.fspath(path), os.path.abspath(os.fspath(asset))
    if os.path.splitext(path)[1].lower() not in (".usd", ".usda", ".usdc"):
        raise WarpStokesError(f"{path}: a cage layer is a .usd, .usda or .usdc file")
    whose = inputs_of(asset, error=WarpStokesError).meets(path)
    if whose is not None:
        raise WarpStokesError(f"{path}: the output would replace {whose}; write the cage layer to another file (it "
                              "sublayers the asset)")
    stage = open_stage(asset, WarpStokesError)  # held: a prim does not keep its stage alive
    prim = _default_prim_path(stage) if prim is None else prim
    if not (Sdf.Path.IsValidPathString(prim) and Sdf.Path(prim).IsAbsolutePath() and Sdf.Path(prim).IsPrimPath()):
        raise WarpStokesError(f"{prim}: not an absolute prim path (e.g. /Asset/Cage)")
    if stage.GetPrimAtPath(prim).IsValid():
        raise WarpStokesError(f"{asset}: it has a prim {prim} already; name the cage's prim with --cage-prim")
    return prim


def write_cage_layer(path, asset, vertices, faces, prim: str | None = None) -> str:
    """Write a layer at ``path`` over the USD asset ``asset`` that defines the cage as the mesh prim ``prim``.

    The cage's vertices are in world space at the asset's rest; they are written in the prim's local space (the
    inverse of its parent's local-to-world transform at the earliest time code), so the stage places them where they
    were made. Parents that do not exist are defined as plain transforms. Up axis, meters per unit and the default
    prim are those of the asset. Written whole or not at all.

    Parameters
    ----------
    path : str | os.PathLike, a .usd, .usda or .usdc file (not a file of the asset)
    asset : str | os.PathLike, the USD asset the cage was made for
    vertices : (L, 3) float array, world space
    faces : (F, 3) int array
    prim : str, optional, the prim path (default :func:`default_cage_prim`); it must not exist in the asset

    Returns
    -------
    str, the prim path written

    Raises
    ------
    WarpStokesError
        When the output is a file of the asset, the prim path is not absolute or exists, or a parent's transform is
        singular.

    Examples
    --------
    >>> made = make_cage("examples/arm/arm.usda", mesh_prims=["/Arm/Geo/Skin"])  # doctest: +SKIP
    >>> v, f = made.cage.vertices, made.cage.faces                                # doctest: +SKIP
    >>> write_cage_layer("arm_cage.usda", "examples/arm/arm.usda", v, f)           # doctest: +SKIP
    '/Arm/MadeCage'
    """
    from pxr import Sdf, Usd, UsdGeom

    from .asset import open_stage, stage_metadata

    path, asset = os.fspath(path), os.path.abspath(os.fspath(asset))
    ext = os.path.splitext(path)[1].lower()
    prim = check_cage_layer(path, asset, prim)
    stage = open_stage(asset, WarpStokesError)
    parent = Sdf.Path(prim).GetParentPath()  # the nearest ancestor in the asset: those defined here are identities
    while not stage.GetPrimAtPath(parent).IsValid():
        parent = parent.GetParentPath()
    parent = stage.GetPrimAtPath(parent)
    world = np.asarray(vertices, dtype=np.float64)
    local = world
    if not parent.IsPseudoRoot():
        matrix = np.array(UsdGeom.XformCache(Usd.TimeCode.EarliestTime()).GetLocalToWorldTransform(parent))
        try:
            inverse = np.linalg.inv(matrix)
        except np.linalg.LinAlgError:
            raise WarpStokesError(f"{asset}: {parent.GetPath()}'s local-to-world transform is singular: the cage has "
                                  "no place under it; name another prim with --cage-prim") from None
        local = world @ inverse[:3, :3] + inverse[3, :3]
    metadata = stage_metadata(stage)
    relative = os.path.relpath(asset, os.path.dirname(os.path.abspath(path))).replace(os.sep, "/")
    faces = np.asarray(faces, dtype=np.int64)
    with atomic_output(path, ext) as tmp:
        layer, _ = new_stage(tmp, ext)
        layer.subLayerPaths.append(relative)
        over = Usd.Stage.Open(layer)  # composed with the asset; the new prim goes to the new layer
        if metadata["default_prim"]:
            layer.defaultPrim = metadata["default_prim"]
        UsdGeom.SetStageUpAxis(over, metadata["up_axis"])
        UsdGeom.SetStageMetersPerUnit(over, metadata["meters_per_unit"])
        for ancestor in Sdf.Path(prim).GetParentPath().GetPrefixes():
            if not over.GetPrimAtPath(ancestor).IsValid():
                UsdGeom.Xform.Define(over, ancestor)
        define_mesh(over, prim, np.full(len(faces), 3), faces.ravel(), local)
        save_layer(layer, path)
    return prim
