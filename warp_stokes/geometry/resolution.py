"""The grid's resolution: the range a resolution is taken in, what ``resolution="auto"`` stands for on a device, and
from which resolution the grid cuts off the thin wedges of outside space at the cage's folded edges."""

from __future__ import annotations

import numpy as np

from ..device import Backend
from ..errors import ResolutionError
from .cage import Cage
from .cage_faults import folded_edges
from .local_data import boundary_settings, data_slopes

__all__ = ["AUTO_RESOLUTION", "AUTO_RESOLUTION_CAP", "CUT_OFF_MAX_CHANGE", "check_resolution", "auto_resolution",
           "wedge_resolution"]

#: an interior node cut off by such a wedge takes the boundary data only where that data, extended to it over a
#: diagonal link, changes by at most this much (in weight units): beyond it the grid does not resolve the faces and
#: the extension means nothing; a smaller gate switches sharp folds on late, itself a jump in the weights from one
#: resolution to the next (measured: benchmarks/RESULTS.md)
CUT_OFF_MAX_CHANGE = 1.0

#: ``resolution="auto"`` picks at least this many cells, more where the cage's folded edges need them
#: (:func:`wedge_resolution`), and at most the cap of the device's kind: a CPU bind stays within tens of seconds
AUTO_RESOLUTION = 64
AUTO_RESOLUTION_CAP = {"cpu": 96, "cuda": 256}


def check_resolution(resolution) -> "int | str":
    """The resolution as an int, or "auto"; a ResolutionError when it is neither "auto" nor an integer in [8, 2048].

    Examples
    --------
    >>> check_resolution(64), check_resolution("auto")
    (64, 'auto')
    """
    if isinstance(resolution, str) and resolution == "auto":
        return resolution
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        raise ResolutionError(f"resolution must be 'auto' or an integer number of cells, got {resolution!r}")
    if not 8 <= int(resolution) <= 2048:
        raise ResolutionError(f"resolution must be between 8 and 2048 cells, got {resolution}")
    return int(resolution)


def auto_resolution(cage: Cage, boundary="local", device=None, kind: str | None = None) -> tuple[int, int, int]:
    """The resolution ``"auto"`` stands for: :data:`AUTO_RESOLUTION`, or the resolution from which the grid cuts off
    the thin wedges at the cage's folded edges where that is more, capped per device kind
    (:data:`AUTO_RESOLUTION_CAP`).

    Parameters
    ----------
    cage : Cage
    boundary : "local" | LocalData | "mvc"
    device : None | str | Backend, where the local data is evaluated
    kind : "cpu" | "cuda", optional: the kind of the devices that solve, when it is not ``device``'s (a bind spread
        over GPUs from a host without one)

    Returns
    -------
    chosen : int
    needed : int, what the cage asks for (more than ``chosen`` where the cap stopped it)
    cap : int

    Examples
    --------
    >>> import trimesh
    >>> from warp_stokes.geometry.cage import check_cage
    >>> box = trimesh.creation.box(extents=[2, 2, 2])
    >>> auto_resolution(check_cage((box.vertices, box.faces)), device="cpu")
    (64, 64, 96)
    """
    backend = Backend.of(device)
    cap = AUTO_RESOLUTION_CAP[kind or backend.kind]
    needed = max(AUTO_RESOLUTION, wedge_resolution(cage, boundary, backend) or 0)
    return min(needed, cap), needed, cap


def wedge_resolution(cage: Cage, boundary="local", device=None) -> int | None:
    """The resolution from which the grid cuts off the thin wedges of outside space at every folded cage edge (faces
    whose normals are more than 150 degrees apart): below it, nodes next to some of them stay unknowns, coupled
    across the wedge, and the weights within a few cells of the edge converge slowly.

    Parameters
    ----------
    cage : Cage
    boundary : "local" | LocalData | "mvc"
    device : None | str | Backend, where the local data's MVC normal derivatives are evaluated

    Returns
    -------
    int, or None when the cage has no folded edge or the data is MVC's (no node is cut off)

    Examples
    --------
    >>> import trimesh
    >>> from warp_stokes.geometry.cage import check_cage
    >>> box = trimesh.creation.box(extents=[2, 2, 2])
    >>> wedge_resolution(check_cage((box.vertices, box.faces))) is None
    True
    """
    boundary = boundary_settings(boundary)
    folds = folded_edges(cage)
    if not boundary.local or not len(folds):
        return None
    slopes = data_slopes(cage, boundary, Backend.of(device))
    at_fold = cage.faces[np.isin(cage.faces, np.unique(folds)).any(axis=1)]  # the faces around folded edges
    extent = float((cage.vertices.max(axis=0) - cage.vertices.min(axis=0)).max())
    # the kernel's test, 1.5 h slope <= CUT_OFF_MAX_CHANGE, with h = extent / resolution
    return int(np.ceil(1.5 * slopes[at_fold].max() * extent / CUT_OFF_MAX_CHANGE))
