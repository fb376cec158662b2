"""Animated USD out, written with pxr (usd-core): :func:`write_animation` checks its arguments and writes one of
the two forms.

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

import numpy as np

from ...arguments import choice, flag, number
from ...errors import WarpStokesError
from ..poses import Poses, checked_poses, load_poses
from .layer import write_layer
from .standalone import write_standalone

__all__ = ["write_animation", "check_animation", "check_options"]


def check_options(fps=None, up_axis=None, meters_per_unit=None, **flags) -> None:
    """The options every animation writer takes, checked where they enter: a frame rate and meters per unit that
    are positive numbers within float32's range, an up axis of Y or Z, and flags that are True or False.

    Examples
    --------
    >>> check_options(24, "Z", 0.01, with_cage=True)
    >>> check_options(meters_per_unit=True)
    Traceback (most recent call last):
    ...
    warp_stokes.errors.WarpStokesError: meters_per_unit must be > 0, got True
    """
    if fps is not None:
        number(fps, "fps", 0, low_open=True)
    if up_axis is not None:
        choice(up_axis, "up_axis", ("Y", "Z"))
    if meters_per_unit is not None:
        number(meters_per_unit, "meters_per_unit", 0, low_open=True)
    for name, value in flags.items():
        flag(value, name)


def check_animation(path, binding, poses: Poses, fps, extensions=(".usd", ".usdc", ".usda"),
                    asset=None) -> tuple[str, np.ndarray, np.ndarray]:
    """The output's extension, and the poses' positions and frame numbers, checked against the binding (and an
    ``asset`` to layer over, which only a binding of a USD asset takes)."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in extensions:
        raise WarpStokesError(f"{path}: the output must end in {', '.join(extensions[:-1])} or {extensions[-1]}")
    check_options(fps)
    poses = checked_poses(poses)  # the numbers of poses made in Python too: finite, within float32, distinct frames
    positions, frames = poses.positions, poses.frames
    if positions.shape[1:] != (binding.n_handles, 3):
        raise WarpStokesError(f"{poses.name}: poses of shape {positions.shape} do not fit a cage of "
                              f"{binding.n_handles} vertices")
    if len(binding.mesh_faces) == 0:
        raise WarpStokesError("the bound mesh has no faces: there is nothing to write as a USD mesh")
    order = np.argsort(frames, kind="stable")  # in time: glTF's samplers need it, USD does not mind
    positions, frames = positions[order], frames[order]
    if binding.asset is None and asset is not None:
        raise WarpStokesError(f"{asset}: the binding is not of a USD asset (it was bound from "
                              f"{binding.settings.get('mesh')}); an asset can only be given for a binding of one")
    return ext, positions, frames


def write_animation(path, binding, poses, fps: float | None = None, with_cage: bool = False,
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
    poses : Poses (e.g. from :func:`warp_stokes.load_poses`), or what it reads: an (F, L, 3) or (L, 3) array
        (frames 1, 2, ...), a folder of OBJ frames, a .npy/.npz or USD file
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
    check_options(fps, up_axis, meters_per_unit, with_cage=with_cage, with_weights=with_weights)
    if not isinstance(poses, Poses):
        poses = load_poses(poses, binding.cage_faces, binding.n_handles, binding.cage_source_index)
    ext, positions, frames = check_animation(path, binding, poses, fps, asset=asset)
    path = os.fspath(path)
    if binding.asset is not None:
        if normals is not None:
            raise WarpStokesError("normals: a layer over an asset recomputes the normals the asset authors")
        return write_layer(path, ext, binding, positions, frames, poses, fps, with_cage, with_weights, up_axis,
                            meters_per_unit, asset)
    return write_standalone(path, ext, binding, positions, frames, poses, fps, with_cage, with_weights,
                             up_axis or "Y", 1.0 if meters_per_unit is None else meters_per_unit, normals)
