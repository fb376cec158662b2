"""Boundary data: mean value coordinates of the cage at grid nodes, packed with their gradients.

Ring and band nodes keep these values as known data; interior nodes start from them (the MVC field already
has exact partition of unity and linear precision, so the solver only corrects it). Gradients G = h grad q
are the central differences of nodal MVC values with step h: a rule exact for linear functions, so the
discrete solution reproduces constants and linear functions exactly. (The analytic MVC gradient is the
other exact choice; it imposes slightly different Neumann data. We keep the central difference.)
"""

from __future__ import annotations

import warnings

import numpy as np
import warp as wp

from ..device import Backend
from ..kernels import mvc, stencil
from .cage import Cage
from .grid import Grid
from .local_boundary import local_field
from .local_data import MVC_DATA, boundary_settings
from .mean_value import mean_value_coordinates, mvc_on_device

__all__ = ["mean_value_coordinates", "boundary_field", "COMPLEMENT_COLUMNS"]

#: columns that stand for the rest of the cage in a chunk's field (``boundary_field(..., complement=True)``): one,
#: the sum of the other handles' weights, so that each chunk's solve checks partition of unity. (Four, with the
#: moments that check linear precision too, cost 4 of every 7 columns on a bulky cage at n = 512, where 3 handles
#: fit per chunk.)
COMPLEMENT_COLUMNS = 1


def _node_positions(grid: Grid, rows: int, backend: Backend) -> wp.array:
    """The first ``rows`` active nodes' positions relative to the grid's centre (vec3d), formed on the device from
    the nodes' coordinates there (at n = 512, 0.2 s on the host and a 120 MB copy)."""
    device = backend.device
    positions = wp.empty(rows, dtype=wp.vec3d, device=device)
    wp.launch(mvc.node_positions, dim=rows, inputs=[grid.device_arrays(backend)["active_ijk"],
                                                    wp.vec3d(*grid.origin), wp.float64(grid.spacing)],
              outputs=[positions], device=device)
    return positions


def _even_nodes(grid: Grid, rows: int, backend: Backend) -> np.ndarray:
    """The nodes of even coordinates around the first ``rows`` active nodes (those a trilinear interpolation reads:
    the node itself when its coordinates are even, 2, 4 or 8 around it otherwise), as (m, 3) coordinates in a
    lattice of half the nodes per axis, in lattice order."""
    kept = grid.device_arrays(backend)  # once per grid and rows (the memory plan asks for their number first)
    if ("even nodes", rows) in kept:
        return kept[("even nodes", rows)]
    ijk = np.asarray(grid.active_ijk[:rows], dtype=np.int64)
    base, odd = ijk // 2, ijk % 2
    shape = tuple(int(s) for s in base.max(axis=0, initial=0) + 2) if rows else (1, 1, 1)
    needed = np.zeros(shape, dtype=bool)
    for corner in np.ndindex(2, 2, 2):
        o = np.array(corner)
        reads = (o <= odd).all(axis=1)
        needed[tuple((base[reads] + o).T)] = True
    kept[("even nodes", rows)] = np.argwhere(needed)
    return kept[("even nodes", rows)]


def start_lattice_nodes(grid: Grid, data, device=None) -> int:
    """How many nodes of even coordinates a starting guess interpolated from them takes mean value coordinates at
    (with the local data on a CPU: :func:`boundary_field`), 0 where it takes them at its rows themselves: what the
    memory plan counts for their values (8 bytes per node and handle)."""
    data = (getattr(grid, "boundary", None) or MVC_DATA) if data is None else boundary_settings(data)
    backend = Backend.of(device)
    if not data.local or not backend.on_cpu:
        return 0
    return len(_even_nodes(grid, start_rows(grid, data), backend))


def _start_lattice(grid: Grid, rows: int, backend: Backend) -> tuple[wp.array, wp.array]:
    """:func:`_even_nodes`: their positions relative to the grid's centre (vec3d, on the device) and their rows in
    the lattice of half the nodes per axis (-1 elsewhere)."""
    lattice = _even_nodes(grid, rows, backend)
    device = backend.device
    shape = tuple(int(s) for s in lattice.max(axis=0, initial=0) + 1) if len(lattice) else (1, 1, 1)
    index = np.full(shape, -1, dtype=np.int32)
    index[tuple(lattice.T)] = np.arange(len(lattice), dtype=np.int32)
    positions = grid.origin + grid.spacing * (2 * lattice).astype(np.float64)
    return (wp.array(positions, dtype=wp.vec3d, device=device), wp.array(index, dtype=wp.int32, device=device))


def _start_on_lattice(grid: Grid, cage: Cage, rows: int, handles: slice, backend: Backend, out: wp.array) -> None:
    """Mean value coordinates of ``handles`` at the first ``rows`` active nodes, interpolated (trilinearly) from
    those at the nodes of even coordinates: the solve's starting guess and the gradients next to it need not be
    exact, only smooth and close (their exact values cost the search over every face at eight times the points:
    most of a small CPU bind's boundary data). Constants and linear functions are interpolated exactly, so the start
    keeps partition of unity and linear precision. On a CPU the lattice is shared out between the backend's
    threads."""
    device = backend.device
    positions, index = _start_lattice(grid, rows, backend)
    first, stop, _ = handles.indices(cage.n_handles)
    lattice_values = wp.empty((positions.shape[0], stop - first), dtype=wp.float64, device=device)
    backend.in_threads(positions.shape[0], lambda a, b: mvc_on_device(cage, grid.centre, positions[a:b], handles,
                                                                         device, out=lattice_values[a:b]),
                       modules=("mvc",))
    ijk = grid.device_arrays(backend)["active_ijk"]
    backend.in_threads(rows, lambda a, b: wp.launch(mvc.lattice_interpolation, dim=(b - a, stop - first),
                                                    inputs=[lattice_values, index, ijk[a:b]], outputs=[out[a:b]],
                                                    device=device), modules=("mvc",))


def start_rows(grid: Grid, data) -> int:
    """The active rows whose mean value coordinates a boundary field needs: all of them for the MVC data, else the
    interior's (the starting guess) and the ring's (the interior's gradients are differences with them)."""
    return grid.n_interior + grid.n_ring if boundary_settings(data).local else grid.n_active


def start_values(grid: Grid, cage: Cage, device=None, threads: int | None = None, data=None) -> wp.array:
    """Mean value coordinates of every handle at the rows :func:`start_rows` (float64, (rows, L)), formed once for
    all the chunks of a bind that threads solve at once on a CPU (each chunk's field copies its columns,
    ``boundary_field(..., start=)``): a chunk's coordinates cost the search over every face whatever its handles, so
    T chunks cost T times one. On a CPU the rows are shared out between ``threads`` threads. With the local data on
    a CPU they are interpolated from the nodes of even coordinates, as :func:`boundary_field` forms them."""
    backend = Backend.of(device, threads)
    data = _data_for(grid, data)
    rows = start_rows(grid, data)
    values = wp.empty((rows, cage.n_handles), dtype=wp.float64, device=backend.device)
    _start_into(grid, cage, rows, slice(None), backend, values, data)
    return values


def _start_into(grid: Grid, cage: Cage, rows: int, handles: slice, backend: Backend, out: wp.array,
                data) -> None:
    """Mean value coordinates of ``handles`` at the first ``rows`` active nodes, into ``out``: exact for the MVC
    data (the boundary data itself) and on a GPU (where the search over the faces costs a small fraction of the
    lattice's numbering on the host), else interpolated from the nodes of even coordinates
    (:func:`_start_on_lattice`)."""
    if data.local and backend.on_cpu:
        _start_on_lattice(grid, cage, rows, handles, backend, out)
        return
    positions = _node_positions(grid, rows, backend)
    backend.in_threads(rows, lambda a, b: mvc_on_device(cage, grid.centre, positions[a:b], handles, backend.device,
                                                        out=out[a:b]), modules=("mvc",))


def boundary_field(grid: Grid, cage: Cage, device=None, handles: slice = slice(None),
                   complement: bool = False, data=None, start: wp.array | None = None,
                   threads: int | None = None) -> wp.array:
    """The packed (q, G) field of every handle at every active node: the boundary data at ring and band nodes.

    Parameters
    ----------
    grid : Grid
    cage : Cage
    device : None | str | Backend
    handles : slice, the handles (columns) to compute, e.g. ``slice(0, 32)`` for a chunk; all by default
    complement : bool
        Append :data:`COMPLEMENT_COLUMNS` (one) column that stands for the rest of the cage: the sum over the
        handles outside ``handles`` of w_l. The chunk and this column sum to one like the whole cage does, so a
        chunked solve can check partition of unity (``solve_biharmonic(..., chunk=handles)``) at the cost of one
        column; linear precision is checked on the sampled weights once every chunk is solved.
    data : None | "mvc" | "local" | LocalData
        Ring and band data: mean value coordinates of the nodes, or the local data of
        :mod:`warp_stokes.geometry.local_boundary` (the hat functions at the closest cage point, Taylor-extended; "local"
        is ``LocalData()``). Both reproduce constants and linear functions exactly. By default the data the grid was
        voxelised for (``grid.boundary``; MVC for a grid from a mask); other data is warned of when the grid has
        nodes cut off for its own (they would take data they were not chosen for).
    start : wp.array, optional
        :func:`start_values` of this grid, cage and data: the chunk's mean value coordinates are copied from it
        instead of computed (the same values).
    threads : int, optional
        On a CPU, threads that form the starting guess and the local data's blend of faces for the grid's rows, the
        first time (default: every core).

    Returns
    -------
    wp.array2d of vec4f, shape (grid.n_active, handles [+ 1]): known data at ring and band rows, the starting
    guess at interior rows: the MVC there (with the local data on a CPU interpolated trilinearly from the nodes of
    even coordinates: eight times fewer searches over the faces, the same iterations on the real pairs). Band rows carry
    G = 0 (never read).

    Examples
    --------
    >>> field = boundary_field(grid, cage, handles=slice(0, 32), complement=True)  # doctest: +SKIP
    >>> field.shape[1]                                                             # doctest: +SKIP
    33
    """
    backend = Backend.of(device, threads)
    device = backend.device
    data = _data_for(grid, data)
    first, stop, _ = handles.indices(cage.n_handles)
    n_columns = stop - first + (COMPLEMENT_COLUMNS if complement else 0)
    if start is None:  # the MVC data at every row, or the interior's starting guess and the ring's values
        rows = start_rows(grid, data)
        values = (wp.empty if rows == grid.n_active else wp.zeros)((grid.n_active, n_columns), dtype=wp.float64,
                                                                    device=device)
        _start_into(grid, cage, rows, handles, backend, values[:rows, 0 : stop - first], data)
    else:
        values = wp.zeros((grid.n_active, n_columns), dtype=wp.float64, device=device)
        wp.launch(mvc.copy_columns, dim=(start.shape[0], stop - first), inputs=[start, first], outputs=[values],
                  device=device)
    # rows beyond the mean value coordinates' (band rows, for the local data) take the local data below: zeros until
    # then
    if complement:
        wp.launch(mvc.complement_column, dim=grid.n_active, inputs=[stop - first], outputs=[values], device=device)
    arrays = grid.device_arrays(backend)
    field = wp.empty(values.shape, dtype=wp.vec4f, device=device)
    wp.launch(
        stencil.pack_nodal_field,
        dim=field.shape,
        inputs=[values, arrays["active_ijk"], arrays["index"], grid.n_interior + grid.n_ring],
        outputs=[field],
        device=device,
    )
    if data.local:
        # ring and band rows take the local data; the interior keeps the MVC field as its starting guess (exact
        # too, and smooth: starting from the local data's Taylor extension took twice the iterations)
        local_field(grid, cage, field, slice(grid.n_interior, grid.n_active), handles, complement, data, backend)
    return field


def _data_for(grid: Grid, data):
    """``data`` as a LocalData or MVC_DATA, the grid's own by default; a warning when the grid cut nodes off for
    other data."""
    grid_data = getattr(grid, "boundary", None)
    if data is None:
        return MVC_DATA if grid_data is None else grid_data
    data = boundary_settings(data)
    if grid_data is not None and data != grid_data and grid.n_cut_off:
        warnings.warn(f"the grid was voxelised for the boundary data {grid_data} and cut {grid.n_cut_off} nodes off "
                      f"for it; they take the data {data} here (voxelize with boundary="
                      f"{repr(data) if data.local else repr('mvc')} to match)",
                      stacklevel=3)
    return data
