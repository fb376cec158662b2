"""What both forms of animated USD share: arrays as USD values, stage timing, and the frames deformed in chunks,
with the layer saved after each (bounded memory)."""

from __future__ import annotations

import re

import numpy as np

from ...errors import WarpStokesError

__all__ = ["FRAMES_PER_CHUNK", "animation_rate", "extent", "vec3f", "define_mesh", "set_timing", "deformed_frames",
           "new_stage", "save_layer", "prim_name"]

#: frames deformed per device launch (bounded so that frames x vertices x 12 bytes stays small)
FRAMES_PER_CHUNK = 64



def prim_name(text, fallback: str, taken: set) -> str:
    """A valid USD prim name from ``text`` (or ``fallback`` where nothing of it is left), not among ``taken`` (then
    added to it): other characters become underscores, a leading digit gets one, a taken name a number.

    Examples
    --------
    >>> taken = set()
    >>> prim_name("arm mesh", "Mesh", taken), prim_name("arm_mesh", "Mesh", taken), prim_name("7", "Mesh", taken)
    ('arm_mesh', 'arm_mesh_2', '_7')
    """
    name = re.sub(r"[^A-Za-z0-9_]", "_", str(text or "")) or fallback
    if name[0].isdigit():
        name = "_" + name
    base, k = name, 1
    while name in taken:
        k += 1
        name = f"{base}_{k}"
    taken.add(name)
    return name

def extent(points: np.ndarray):
    """The (2,) Vec3fArray [min, max] of points."""
    from pxr import Gf, Vt

    lo, hi = points.min(axis=0), points.max(axis=0)
    return Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))])


def vec3f(values: np.ndarray):
    """A Vt.Vec3fArray of an (N, 3) array."""
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(values, dtype=np.float32))


def define_mesh(stage, path: str, counts: np.ndarray, indices: np.ndarray, rest: np.ndarray):
    """A ``UsdGeom.Mesh`` at ``path`` with its polygons and rest points (and extent)."""
    from pxr import UsdGeom, Vt

    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(counts, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(indices, dtype=np.int32)))
    mesh.CreateSubdivisionSchemeAttr("none")
    mesh.CreateOrientationAttr("rightHanded")
    mesh.CreatePointsAttr(vec3f(rest))
    mesh.CreateExtentAttr(extent(rest))
    return mesh


def animation_rate(fps, poses, asset_rate=None) -> float:
    """The time codes per second of a written animation: ``fps`` when given, else the poses' own (a USD stage's),
    else the asset's (``asset_rate``), else 24.

    Examples
    --------
    >>> from warp_stokes.io.poses import Poses
    >>> animation_rate(None, Poses(np.zeros((1, 4, 3)), np.ones(1), "p"), 30.0)
    30.0
    """
    return float(fps or poses.time_codes_per_second or asset_rate or 24.0)


def set_timing(stage, frames: np.ndarray, rate: float) -> None:
    """Start/end time codes from the frames; time codes and frames per second ``rate``."""
    stage.SetTimeCodesPerSecond(float(rate))
    stage.SetFramesPerSecond(float(rate))
    stage.SetStartTimeCode(float(frames.min()))
    stage.SetEndTimeCode(float(frames.max()))


def deformed_frames(binding, positions: np.ndarray, frames: np.ndarray, layer, path: str, ext: str):
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
            save_layer(layer, path)
            layer.Reload()


def new_stage(tmp: str, ext: str):
    """A new layer at ``tmp`` (text for .usda, crate otherwise) and the stage on it."""
    from pxr import Sdf, Usd

    layer = Sdf.Layer.CreateNew(tmp, args={"format": "usda"} if ext == ".usda" else {"format": "usdc"})
    return layer, Usd.Stage.Open(layer)


def save_layer(layer, path) -> None:
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
