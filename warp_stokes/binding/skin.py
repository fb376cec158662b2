"""A binding as a linear blend skin: one joint per cage handle, translation only.

With bind transform ``translate(c_l)`` and animated transform ``translate(c'_l)``, linear blend skinning moves a rest
point ``p`` to ``p + sum_l w_l (c'_l - c_l)``, which is ``sum_l w_l c'_l`` (the cage deformation) wherever the
weights have partition of unity and linear precision. Consumers want few influences per vertex (glTF: sets of four,
non-negative); :func:`skin_weights` keeps the K largest and :func:`skin_error` measures, over the poses, how far the
skin then is from :meth:`Binding.deform` — truncation is reported, never silent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arguments import flag, integer, number
from ..errors import WarpStokesError

__all__ = ["SkinWeights", "SkinError", "SkinReport", "skin_weights", "skin_points", "skin_error", "joint_names",
           "write_skin"]

@dataclass
class SkinWeights:
    """Each vertex's K influences.

    Attributes
    ----------
    indices : (V, K) int32, the handles (joints) of each vertex, by decreasing weight magnitude
    weights : (V, K) float32, their weights (each row sums to one)
    n_handles : int, the joints of the skin (the binding's handles)
    non_negative : bool, whether negative weights were removed (``weights >= 0``)
    """

    indices: np.ndarray
    weights: np.ndarray
    n_handles: int
    non_negative: bool = False

    @property
    def influences(self) -> int:
        return self.indices.shape[1]

    @property
    def complete(self) -> bool:
        """Every handle kept with its own weight: the skin is the binding."""
        return self.influences == self.n_handles and not self.non_negative

    def dense(self) -> np.ndarray:
        """The (V, L) float64 weight matrix of the skin."""
        out = np.zeros((len(self.indices), self.n_handles))
        np.put_along_axis(out, self.indices.astype(np.int64), self.weights.astype(np.float64), axis=1)
        return out


@dataclass
class SkinError:
    """How far a skin is from the cage deformation over a set of poses, relative to the rest mesh's diagonal.

    Attributes
    ----------
    max : float, the largest distance of a skinned vertex from its deformed place, over the diagonal
    rms : float, the root mean square distance over all vertices and poses, over the diagonal
    frame : int, the pose (index into the poses) where ``max`` occurs
    """

    max: float
    rms: float
    frame: int

    def __str__(self) -> str:
        return f"max {self.max:.2e}, RMS {self.rms:.2e} of the diagonal"


def joint_names(n_handles: int) -> list[str]:
    """The joints' names, one per handle in cage vertex order: ``handle_000``, ``handle_001``, ...

    Examples
    --------
    >>> joint_names(3)
    ['handle_000', 'handle_001', 'handle_002']
    """
    width = max(3, len(str(n_handles - 1)))
    return [f"handle_{l:0{width}d}" for l in range(n_handles)]


def skin_weights(binding, influences: int | None = None, non_negative: bool = False) -> SkinWeights:
    """Each vertex's ``influences`` largest weights, as a skin takes them.

    Parameters
    ----------
    binding : Binding
    influences : int, optional, the joints per vertex K (default: all handles, which is exact)
    non_negative : bool, drop negative weights first (for consumers that ignore them, and glTF, which forbids them)

    The kept weights are scaled to sum to one. (Fitting them instead to keep linear precision, the nearest weights
    with ``sum_k w_k c_k = p``, was measured on posed test pairs: better at some K, worse at others, so it is not
    offered.)

    Returns
    -------
    SkinWeights

    Examples
    --------
    >>> skin = skin_weights(binding, influences=8, non_negative=True)   # doctest: +SKIP
    >>> skin.weights.shape                                              # doctest: +SKIP
    (26394, 8)
    """
    weights = np.asarray(binding.weights, dtype=np.float64)
    n_vertices, n_handles = weights.shape
    if influences is not None and not (isinstance(influences, (int, np.integer)) and not isinstance(influences, bool)
                                       and 1 <= influences <= n_handles):
        raise WarpStokesError(f"influences must be an integer between 1 and the cage's {n_handles} handles, got "
                              f"{influences!r}")
    k = n_handles if influences is None else int(influences)
    non_negative = flag(non_negative, "non_negative")
    if non_negative:
        weights = np.maximum(weights, 0.0)
    if k == n_handles and not non_negative:
        # every weight as bound: no choice and no rescaling (they sum to one to float32 rounding)
        indices = np.broadcast_to(np.arange(n_handles, dtype=np.int32), (n_vertices, n_handles)).copy()
        return SkinWeights(indices, np.asarray(binding.weights, dtype=np.float32).copy(), n_handles, False)
    if k == n_handles:
        indices = np.broadcast_to(np.arange(n_handles), (n_vertices, n_handles)).copy()
    else:
        indices = np.argpartition(-np.abs(weights), k - 1, axis=1)[:, :k]
    kept = np.take_along_axis(weights, indices, axis=1)
    order = np.argsort(-np.abs(kept), axis=1, kind="stable")
    indices, kept = np.take_along_axis(indices, order, axis=1), np.take_along_axis(kept, order, axis=1)
    total = kept.sum(axis=1, keepdims=True)
    if np.any(total <= 0):
        raise WarpStokesError(f"{int(np.sum(total <= 0))} vertices keep no positive weight among their {k} largest; "
                              "use more influences")
    return SkinWeights(indices.astype(np.int32), (kept / total).astype(np.float32), n_handles, bool(non_negative))


def skin_points(rest: np.ndarray, skin: SkinWeights, rest_cage: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Linear blend skinning with translation-only joints: ``p + sum_k w_k (c'_{i_k} - c_{i_k})``, in float64.

    Parameters
    ----------
    rest : (V, 3) rest points
    skin : SkinWeights
    rest_cage : (L, 3) the joints' bind positions
    poses : (L, 3) or (F, L, 3) the joints' animated positions

    Returns
    -------
    (V, 3) or (F, V, 3) float64

    Examples
    --------
    >>> skin = SkinWeights(np.array([[0, 1]]), np.array([[0.25, 0.75]]), 2)
    >>> skin_points(np.zeros((1, 3)), skin, np.zeros((2, 3)), np.array([[4.0, 0, 0], [0, 4, 0]])).tolist()
    [[1.0, 3.0, 0.0]]
    """
    poses = np.asarray(poses, dtype=np.float64)
    single = poses.ndim == 2
    batch = poses[None] if single else poses
    moves = batch - np.asarray(rest_cage, dtype=np.float64)[None]  # (F, L, 3)
    w = skin.weights.astype(np.float64)[None, ..., None]  # (1, V, K, 1)
    out = np.asarray(rest, dtype=np.float64)[None] + np.sum(w * moves[:, skin.indices.astype(np.int64)], axis=2)
    return out[0] if single else out


def skin_error(binding, skin: SkinWeights, poses, frames_per_chunk: int = 64) -> SkinError:
    """How far the skin's points are from the cage deformation ``sum_l w_l c'_l`` of the binding's weights, over
    the poses, in float64 (what the skin and the deformation are, not their float32 rounding).

    The difference is ``(p - W_s c) + (W_s - W) c'`` with ``W_s`` the skin's weights: the first term is the skin's
    rest error (zero where it keeps linear precision), the second its error on the pose.

    Parameters
    ----------
    binding : Binding
    skin : SkinWeights
    poses : (F, L, 3) or (L, 3) cage poses
    frames_per_chunk : int, poses measured together (bounds memory)

    Returns
    -------
    SkinError, relative to the rest mesh's diagonal

    Examples
    --------
    >>> err = skin_error(binding, skin_weights(binding, 4), poses)   # doctest: +SKIP
    >>> print(err)                                                    # doctest: +SKIP
    max 3.21e-02, RMS 4.10e-03 of the diagonal
    """
    poses = np.asarray(poses, dtype=np.float64)
    batch = poses[None] if poses.ndim == 2 else poses
    rest = np.asarray(binding.mesh_vertices, dtype=np.float64)
    cage = np.asarray(binding.cage_vertices, dtype=np.float64)
    diagonal = float(np.linalg.norm(np.ptp(rest, axis=0))) or 1.0
    dense = skin.dense()
    offset = rest - dense @ cage  # the skin's error at rest
    change = dense - np.asarray(binding.weights, dtype=np.float64)
    if not change.any():  # the binding's own weights: the difference is the rest error, the same in every pose
        squared = np.einsum("vi,vi->v", offset, offset)
        return SkinError(float(np.sqrt(squared.max())) / diagonal, float(np.sqrt(squared.mean())) / diagonal, 0)
    shift = change.sum(axis=1)  # zero to rounding for weights with partition of unity
    worst, worst_frame, squares = -1.0, 0, 0.0
    for start in range(0, len(batch), frames_per_chunk):
        chunk = batch[start : start + frames_per_chunk]
        n = len(chunk)
        # centred poses: the products stay small where the cage sits far from the origin
        centred = chunk - chunk.mean(axis=1, keepdims=True)
        diff = (change @ centred.transpose(1, 0, 2).reshape(len(cage), 3 * n)).reshape(len(rest), n, 3)
        diff += offset[:, None]
        diff += shift[:, None, None] * chunk.mean(axis=1)[None]
        squared = np.einsum("vni,vni->vn", diff, diff)  # (V, n)
        squares += float(squared.sum())
        frame_max = squared.max(axis=0)
        k = int(np.argmax(frame_max))
        if frame_max[k] > worst:
            worst, worst_frame = float(frame_max[k]), start + k
    rms = np.sqrt(squares / (len(rest) * len(batch)))
    return SkinError(float(np.sqrt(worst)) / diagonal, float(rms) / diagonal, worst_frame)


@dataclass
class SkinReport:
    """What :func:`write_skin` wrote.

    Attributes
    ----------
    path : str, the file written
    form : str, ``"UsdSkel stage"``, ``"UsdSkel layer over <asset>"`` or ``"glTF skin"``
    joints : int, one per handle
    influences : int, joints per vertex
    non_negative : bool, negative weights dropped
    frames : int, poses written
    error : SkinError, the skin against the cage deformation over the poses
    without_negatives : SkinError or None, for a skin with negative weights: the same skin as played by consumers
        that drop them and renormalise (Blender's USD importer does), which ``non_negative=True`` would write
    """

    path: str
    form: str
    joints: int
    influences: int
    non_negative: bool
    frames: int
    error: SkinError
    without_negatives: SkinError | None = None

    def __str__(self) -> str:
        kept = "all" if self.influences == self.joints else str(self.influences)
        sign = ", non-negative" if self.non_negative else ""
        text = (f"wrote {self.path} ({self.form}): {self.joints} joints, {kept} influences per vertex{sign}, "
                f"{self.frames} frames; skin against the cage deformation: {self.error}")
        if self.without_negatives is not None:
            text += (f"\nconsumers that drop negative weights (Blender) play it {self.without_negatives.max:.2e} of "
                     "the diagonal from it at most; --non-negative writes that skin and measures it")
        return text


def write_skin(path, binding, poses, influences: int | None = None, non_negative: bool | None = None,
               max_error: float | None = None, fps: float | None = None, with_cage: bool = False,
               up_axis: str | None = None, meters_per_unit: float | None = None, asset=None) -> SkinReport:
    """Write the cage animation as a skin that consumers play live: a UsdSkel rig (``.usd``, ``.usdc``, ``.usda``)
    or a glTF 2.0 skin (``.glb``, ``.gltf``), one joint per handle, translation only.

    The skin's distance from :meth:`Binding.deform` over the poses is measured first (:func:`skin_error`) and
    reported; with ``max_error`` a skin further than that is refused before anything is written.

    Parameters
    ----------
    path : str | os.PathLike, the output; its extension chooses the format
    binding : Binding; over a USD asset's binding the USD form is a layer over the asset (as
        :func:`warp_stokes.write_animation`), the asset's nearest common ancestor of the bound prims becoming the
        ``SkelRoot``
    poses : Poses, or what :func:`warp_stokes.load_poses` reads
    influences : int, optional, joints per vertex (default: all for USD, which is exact; 8 for glTF)
    non_negative : bool, optional, drop negative weights (default: no for USD; glTF requires it)
    max_error : float, optional, the largest distance from the cage deformation allowed, over the rest mesh's
        diagonal
    fps, with_cage, up_axis, meters_per_unit, asset : as :func:`warp_stokes.write_animation` (``with_cage``: the
        cage skinned rigidly to its joints; USD only)

    Returns
    -------
    SkinReport

    Raises
    ------
    WarpStokesError
        For an unknown extension, poses that do not fit, ``influences`` out of range, a negative glTF skin, or an
        error above ``max_error``.

    Examples
    --------
    >>> report = write_skin("arm_rig.usd", binding, "examples/arm/bend_poses.npy")   # doctest: +SKIP
    >>> report = write_skin("arm.glb", binding, poses, influences=4, max_error=0.05)  # doctest: +SKIP
    """
    import os

    from ..io.gltf import GLTF_EXTENSIONS, write_gltf_skin
    from ..io.poses import Poses, load_poses
    from ..io.usd.common import animation_rate
    from ..io.usd.write import check_animation, check_options

    check_options(fps, up_axis, meters_per_unit, with_cage=with_cage)
    _check_skin_options(max_error, influences, non_negative)
    if not isinstance(poses, Poses):
        poses = load_poses(poses, binding.cage_faces, binding.n_handles, binding.cage_source_index)
    ext, positions, frames = check_animation(path, binding, poses, fps,
                                             (".usd", ".usdc", ".usda") + GLTF_EXTENSIONS, asset)
    path = os.fspath(path)
    gltf = ext in GLTF_EXTENSIONS
    if gltf:
        _check_gltf_request(path, non_negative, with_cage, up_axis, meters_per_unit, asset)
    if influences is None:
        influences = min(8, binding.n_handles) if gltf else binding.n_handles
    non_negative = gltf if non_negative is None else bool(non_negative)
    skin, error = _measured_skin(path, binding, positions, influences, non_negative, max_error)
    metadata = {"joints": int(binding.n_handles), "influences": int(skin.influences),
                "nonNegative": bool(non_negative), "maxError": float(error.max), "rmsError": float(error.rms),
                "errorOver": "rest mesh bounding-box diagonal"}
    joints = joint_names(binding.n_handles)
    if gltf:
        rate = animation_rate(fps, poses, (binding.asset or {}).get("time_codes_per_second"))
        write_gltf_skin(path, ext, binding, skin, joints, positions, frames, rate, metadata)
        form = "glTF skin"
    else:
        form = _write_usd_skin(path, ext, binding, skin, error, joints, positions, frames, poses, metadata, fps=fps,
                               with_cage=with_cage, up_axis=up_axis, meters_per_unit=meters_per_unit, asset=asset)
    without_negatives = None
    if np.any(skin.weights < 0):
        without_negatives = skin_error(binding, skin_weights(binding, skin.influences, True), positions)
    return SkinReport(path, form, binding.n_handles, skin.influences, non_negative, len(positions), error,
                      without_negatives)


def _check_skin_options(max_error, influences, non_negative) -> None:
    """Refuse (:class:`WarpStokesError`) a ``max_error`` not above zero, ``influences`` below one or a
    ``non_negative`` that is no flag."""
    if max_error is not None:
        number(max_error, "max_error", 0, low_open=True)
    if influences is not None:
        integer(influences, "influences", 1)
    if non_negative is not None:
        flag(non_negative, "non_negative")


def _check_gltf_request(path: str, non_negative, with_cage, up_axis, meters_per_unit, asset) -> None:
    """Refuse (:class:`WarpStokesError`) what a glTF skin cannot hold: negative weights, a cage, an up axis, units or
    an asset."""
    if non_negative is False:
        raise WarpStokesError(f"{path}: glTF skins take non-negative weights only (leave non_negative unset)")
    if with_cage or up_axis is not None or meters_per_unit is not None or asset is not None:
        raise WarpStokesError(f"{path}: a glTF skin takes no cage, up axis, units or asset (glTF is Y-up in metres; "
                              "a USD asset's own are converted)")


def _measured_skin(path: str, binding, positions, influences: int, non_negative: bool, max_error):
    """The skin (:func:`skin_weights`) and its distance from the cage deformation over the poses
    (:func:`skin_error`); refused (:class:`WarpStokesError`) where that is above ``max_error``."""
    skin = skin_weights(binding, influences, non_negative)
    error = skin_error(binding, skin, positions)
    if max_error is not None and error.max > max_error:
        raise WarpStokesError(
            f"{path}: with {skin.influences} influences per vertex{' (non-negative)' if non_negative else ''} the skin "
            f"is up to {error.max:.2e} of the diagonal from the cage deformation (pose {error.frame + 1} of "
            f"{len(positions)}), above the allowed {max_error:g}; keep more influences")
    return skin, error


def _write_usd_skin(path: str, ext: str, binding, skin: SkinWeights, error: SkinError, joints, positions, frames,
                    poses, metadata: dict, *, fps, with_cage, up_axis, meters_per_unit, asset) -> str:
    """Write the skin as a UsdSkel rig: a layer over the binding's USD asset, else a stage of its own; see
    :func:`write_skin`. Returns the form written (:attr:`SkinReport.form`)."""
    import os

    from ..io.usd.common import animation_rate

    diagonal = float(np.linalg.norm(np.ptp(np.asarray(binding.mesh_vertices), axis=0)))
    # the SkelRoot's extent: the deformed points' box widened by how far the skin may be from them
    pad = (error.max + 1e-6) * diagonal
    if binding.asset is not None:
        from ..io.usd.layer import asset_context
        from ..io.usd.skel import write_layer_skeleton

        asset_path, asset_metadata = asset_context(path, binding, asset, up_axis, meters_per_unit)
        rate = animation_rate(fps, poses, asset_metadata["time_codes_per_second"])
        write_layer_skeleton(path, ext, binding, skin, joints, positions, frames, rate, with_cage, asset_path,
                             asset_metadata, pad, metadata)
        return f"UsdSkel layer over {os.path.relpath(asset_path, os.path.dirname(os.path.abspath(path)))}"
    from ..io.usd.skel import write_standalone_skeleton

    if up_axis not in (None, "Y", "Z"):
        raise WarpStokesError(f"up axis must be 'Y' or 'Z', got {up_axis!r}")
    rate = animation_rate(fps, poses)
    write_standalone_skeleton(path, ext, binding, skin, joints, positions, frames, rate, with_cage,
                              up_axis or "Y", 1.0 if meters_per_unit is None else meters_per_unit, pad, metadata)
    return "UsdSkel stage"
