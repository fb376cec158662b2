"""The local data (:mod:`.local_data`) on a grid's ring and band nodes, and at points beyond it: each node takes the
data of the cage faces nearest it, blended where the nearest face changes."""

from __future__ import annotations

import threading

import numpy as np
import warp as wp

from ..device import Backend
from ..kernels import local_boundary
from .cage import Cage, unit_normals
from .grid import Grid
from .local_data import LocalData, cage_key, normal_derivatives, tangent_gradients

__all__ = ["local_field", "local_values", "blend_table", "BLEND_BAND", "BLEND_ROW_BYTES"]

#: a node blends the data of the faces whose distance is within this many grid spacings of the nearest face's, so
#: that the data is continuous where the nearest face changes (and the same on every device: a float32 nearest-face
#: query picked different faces on the CPU and the GPU, 3e-2 apart in the weights)
BLEND_BAND = 0.25
_BLEND_LOCK = threading.Lock()


def local_field(grid: Grid, cage: Cage, field: wp.array, rows: slice, handles: slice = slice(None),
                complement: bool = False, settings: LocalData = LocalData(), device=None,
                threads: int | None = None) -> None:
    """Write the local data (q, G = h grad q) of ``handles`` into ``field``'s active rows ``rows``.

    Parameters
    ----------
    grid : Grid
    cage : Cage
    field : wp.array2d(vec4f), (grid.n_active, columns), written in place at ``rows``
    rows : slice of active rows, e.g. ``slice(grid.n_interior, grid.n_active)`` (ring and band)
    handles : slice, the handles of the field's first columns
    complement : bool, the column after them stands for the rest of the cage (see ``boundary_field``)
    settings : LocalData
    device : None | str | Backend
    threads : int, optional, on a CPU the threads that form the rows' blend table the first time (every core)

    Examples
    --------
    >>> field = boundary_field(grid, cage)                                                    # doctest: +SKIP
    >>> local_field(grid, cage, field, slice(grid.n_interior, grid.n_active))                 # doctest: +SKIP
    """
    backend = Backend.of(device, threads)
    device = backend.device
    first, stop, _ = handles.indices(cage.n_handles)
    start, end, _ = rows.indices(grid.n_active)
    relative = wp.array(cage.vertices - grid.centre, dtype=wp.vec3d, device=device)
    triangles = wp.array(cage.faces.astype(np.int32), dtype=wp.vec3i, device=device)
    ijk = grid.device_arrays(backend)["active_ijk"]
    per_face = [wp.array(unit_normals(cage), dtype=wp.vec3d, device=device),
                wp.array(tangent_gradients(cage), dtype=wp.vec3d, device=device),
                _kept_on(normal_derivatives(cage, settings, backend), backend)]
    handles_args = [first, stop - first, int(complement)]
    with backend.scope():
        if backend.on_cpu:
            # the blend of each row found once, for every chunk of handles (the search over the faces was the
            # boundary data's time, repeated per chunk)
            table = blend_table(grid, cage, slice(start, end), backend)
            wp.launch(local_boundary.local_field_from_table, dim=end - start,
                      inputs=[ijk, start, wp.vec3d(*grid.origin), wp.float64(grid.spacing), relative, triangles,
                              *per_face, table, *handles_args], outputs=[field])
            return
        wp.launch(local_boundary.local_field, dim=end - start,
                  inputs=[ijk, wp.empty(0, dtype=wp.vec3d), start, wp.vec3d(*grid.origin), wp.float64(grid.spacing),
                          wp.float64(BLEND_BAND * grid.spacing), relative, triangles, *per_face, *handles_args],
                  outputs=[field])


#: bytes of a row's entry in :func:`blend_table` (a :class:`warp_stokes.kernels.local_boundary.Blend`)
BLEND_ROW_BYTES = 296


def blend_table(grid: Grid, cage: Cage, rows: slice, device=None, threads: int | None = None) -> wp.array:
    """Each of the grid's active rows ``rows``: the faces it blends, their shares and closest points
    (:class:`warp_stokes.kernels.local_boundary.Blend`), formed once per grid, cage and rows on ``device`` (on a CPU
    by ``threads`` threads, each a block of rows) and kept with the grid's device arrays.

    Examples
    --------
    >>> table = blend_table(grid, cage, slice(grid.n_interior, grid.n_active), "cpu")  # doctest: +SKIP
    >>> table.shape[0] == grid.n_ring + grid.n_band                                    # doctest: +SKIP
    True
    """
    backend = Backend.of(device, threads)
    device = backend.device
    start, end, _ = rows.indices(grid.n_active)
    _, key = cage_key(cage, LocalData(), backend)
    name = ("blend", start, end, key[2])
    arrays = grid.device_arrays(backend)
    with _BLEND_LOCK:
        table = arrays.get(name)
        if table is None:
            relative = wp.array(cage.vertices - grid.centre, dtype=wp.vec3d, device=device)
            triangles = wp.array(cage.faces.astype(np.int32), dtype=wp.vec3i, device=device)
            table = wp.empty(end - start, dtype=local_boundary.Blend, device=device)
            # the BVH that bounds each row's search (float32, relative to the grid's centre), and more than float32's
            # error in a distance there
            mesh = wp.Mesh(points=wp.array((cage.vertices - grid.centre).astype(np.float32), dtype=wp.vec3,
                                           device=device),
                           indices=wp.array(cage.faces.astype(np.int32).ravel(), dtype=wp.int32, device=device))
            slack = 1e-5 * cage.diagonal + 1e-3 * BLEND_BAND * grid.spacing

            def rows(a: int, b: int) -> None:  # the table's entries a to b (rows start + a to start + b)
                wp.launch(local_boundary.blend_table, dim=b - a,
                          inputs=[arrays["active_ijk"], start + a, wp.vec3d(*grid.origin), wp.float64(grid.spacing),
                                  wp.float64(BLEND_BAND * grid.spacing), relative, triangles, mesh.id, float(slack)],
                          outputs=[table[a:b]], device=device)

            backend.in_threads(end - start, rows, modules=("local_boundary",))
            arrays[name] = table
    return table


def _kept_on(kept: np.ndarray, backend: Backend) -> wp.array:
    """The kept normal derivatives as a Warp array on the backend's device: on the CPU the host array itself
    (threads that form boundary fields at once share it), else a copy."""
    return wp.array(kept, dtype=wp.float64, device=backend.device, copy=backend.pick(cpu=False, gpu=True))


def local_values(cage: Cage, points: np.ndarray, spacing: float, settings: LocalData = LocalData(),
                 device=None) -> np.ndarray:
    """The local data's values q_l at arbitrary points (float32 accuracy): what a grid of node spacing ``spacing``
    would hold at a node there. For mesh vertices beyond a grid's band, so that they get the data their neighbours
    inside the band are interpolated from.

    Parameters
    ----------
    cage : Cage
    points : (N, 3) array, absolute positions
    spacing : float, the grid's node spacing (it sets the faces' blending band)
    settings : LocalData
    device : None | str | Backend

    Returns
    -------
    (N, L) float64; rows sum to one and reproduce the points (to float32 rounding)

    Examples
    --------
    >>> w = local_values(cage, far_points, grid.spacing)     # doctest: +SKIP
    """
    backend = Backend.of(device)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (cage.vertices.min(axis=0) + cage.vertices.max(axis=0))
    with backend.scope():
        out = wp.empty((len(points), cage.n_handles), dtype=wp.vec4f)
        if len(points):
            wp.launch(
                local_boundary.local_field,
                dim=len(points),
                inputs=[wp.empty(0, dtype=wp.vec3i), wp.array(points - centre, dtype=wp.vec3d), 0, wp.vec3d(),
                        wp.float64(spacing), wp.float64(BLEND_BAND * spacing),
                        wp.array(cage.vertices - centre, dtype=wp.vec3d),
                        wp.array(cage.faces.astype(np.int32), dtype=wp.vec3i),
                        wp.array(unit_normals(cage), dtype=wp.vec3d),
                        wp.array(tangent_gradients(cage), dtype=wp.vec3d),
                        _kept_on(normal_derivatives(cage, settings, backend), backend), 0, cage.n_handles, 0],
                outputs=[out],
            )
    return out.numpy()[..., 0].astype(np.float64)
