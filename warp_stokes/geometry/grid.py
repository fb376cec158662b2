"""The voxel grid: node spacing and labels (interior, ring, band) from the cage's generalised winding number."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .cage import Cage
from .inside import WINDING_ACCURACY, cage_mesh
from .local_data import boundary_settings, data_slopes
from .resolution import CUT_OFF_MAX_CHANGE, check_resolution
from ..device import Backend
from ..memory import memory_size
from ..errors import ResolutionError
from ..kernels import stencil, stencil_cpu
from ..kernels import voxel

__all__ = ["Grid", "voxelize", "grid_from_mask", "MARGIN", "BAND_WIDTH", "PATCH_LENGTH", "WEDGE_FACING", "MAX_ROWS",
           "VOXELIZE_NODE_BYTES", "DEVICE_NODE_BYTES", "HOST_NODE_BYTES"]

#: nodes of known data kept outside the interior (max-norm distance): the ring plus a sampling band, so that
#: trilinear sampling of vertices slightly outside the cage reads only known corners
BAND_WIDTH = 3
#: empty node layers between the cage's bounding box and the grid's edge (band + one, so every stencil read
#: of a ring node stays on the grid)
MARGIN = BAND_WIDTH + 1
#: active nodes are numbered with 32-bit rows (index arrays, kernel row arguments): a grid with more is refused
MAX_ROWS = 2**31 - 1
#: bytes per lattice node while voxelising: winding labels, labels and row classes on the device (1 + 1 + 1), the row
#: index there (4), the labels' host copy (1) and the index's, made when a caller reads it (4): 11, with a margin
VOXELIZE_NODE_BYTES = 14
#: bytes per lattice node that a grid keeps during the solve, on its device (the row index) and on the host
#: (labels, and the row index once read); the memory plan (warp_stokes.solver.budget) counts these
DEVICE_NODE_BYTES, HOST_NODE_BYTES = 4, 5
#: the stencil kernel walks patches of columns along z in pieces of at most this many planes, so that short
#: and long runs balance across threads (of the lengths tried, 64 was the most even across cages and resolutions)
PATCH_LENGTH = 64
#: two cage faces are the walls of one thin wedge of outside space when their normals' dot product is below this
#: (more than 120 degrees apart) and they are near along the cage (kernels.voxel.near_along_the_cage)
WEDGE_FACING = -0.5


@dataclass
class Grid:
    """A uniform grid of nodes around a cage, with its active nodes (interior, ring, band) numbered.

    Positions are relative to ``centre`` (the centre of the cage's bounding box) so that float32 kernels
    keep their precision for models far from the origin.

    Attributes
    ----------
    centre : (3,) float64, the cage's bounding-box centre
    origin : (3,) float64, position of node (0, 0, 0) relative to ``centre``
    spacing : float, the node spacing h
    resolution : int, cells along the cage's longest axis
    labels : (nx, ny, nz) int8, OUTSIDE / INTERIOR / RING / BAND (see ``warp_stokes.kernels.labels``)
    active_ijk : (N, 3) int32, node coordinates of the active nodes: interior, then ring (its cut-off nodes first),
        then band
    index : (nx, ny, nz) int32, row of each node in ``active_ijk`` or -1 (a property: copied to the host when first
        read)
    n_interior, n_ring, n_band : int
    n_cut_off : int, nodes inside the cage cut off by a thin wedge of outside space: known data, counted in the ring
        and numbered first in it (rows ``n_interior`` to ``n_inside``)
    boundary : LocalData | MeanValueData | None, the boundary data the grid was voxelised for (which nodes are cut off
        depends on it); :func:`warp_stokes.boundary_field` uses it by default. None for :func:`grid_from_mask`.
    """

    centre: np.ndarray
    origin: np.ndarray
    spacing: float
    resolution: int
    labels: np.ndarray
    active_ijk: np.ndarray
    n_interior: int
    n_ring: int
    n_band: int
    n_cut_off: int = 0
    boundary: object = None
    #: the row index on the host, copied from the device where the grid was numbered when first read
    _index: np.ndarray | None = field(default=None, repr=False, compare=False)
    _device_arrays: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def index(self) -> np.ndarray:
        """(nx, ny, nz) int32, row of each node in ``active_ijk`` or -1."""
        if self._index is None:
            numbered = [a["index"] for a in self._device_arrays.values() if "index" in a]
            if not numbered:
                raise ResolutionError("this grid has no row index: make grids with voxelize or grid_from_mask")
            self._index = numbered[0].numpy()
        return self._index

    def __getstate__(self) -> dict:
        # pickled (Ray, multiprocessing) or copied with its host arrays only: device arrays stay where they are
        state = dict(self.__dict__)
        state["_index"] = self.index
        state["_device_arrays"] = {}
        return state

    @property
    def shape(self) -> tuple:
        return tuple(int(s) for s in self.labels.shape)

    @property
    def n_active(self) -> int:
        return len(self.active_ijk)

    @property
    def n_inside(self) -> int:
        """Active nodes inside the cage: the unknowns and the cut-off ring nodes, rows ``0`` to ``n_inside``."""
        return self.n_interior + self.n_cut_off

    def node_positions(self, rows=None) -> np.ndarray:
        """Positions (relative to ``centre``) of active nodes ``rows`` (all when None), float64 (N, 3)."""
        ijk = self.active_ijk if rows is None else self.active_ijk[rows]
        return self.origin + self.spacing * ijk.astype(np.float64)

    def interior_patches(self, patch: tuple = (stencil.PATCH_I, stencil.PATCH_J),
                         max_length: int = PATCH_LENGTH) -> np.ndarray:
        """Runs along z of patches of columns that hold interior nodes: the work items of the stencil kernel.

        Columns are grouped into patches of ``patch`` = (pi, pj) columns, aligned to multiples of (pi, pj); a
        run is a range of z over which at least one column of its patch is interior, cut into pieces of at most
        ``max_length`` planes.

        Parameters
        ----------
        patch : (int, int), columns per patch along x and y
        max_length : int, longer runs are split

        Returns
        -------
        (P, 4) int32 array of (i0, j0, k0, length): the patch's first column and first plane, and its planes.
        Every interior node lies in exactly one item; an item may also cover non-interior nodes.

        Examples
        --------
        >>> grid.interior_patches((2, 2), 64)[:, 3].max() <= 64  # doctest: +SKIP
        True
        """
        pi, pj = (int(p) for p in patch)
        if pi < 1 or pj < 1 or max_length < 1:
            raise ValueError(f"patch {patch} and max_length {max_length} must be positive")
        interior = np.zeros(self.shape, dtype=bool)
        interior[tuple(self.active_ijk[: self.n_interior].T)] = True
        nx, ny, nz = self.shape
        px, py = -(-nx // pi) * pi, -(-ny // pj) * pj
        padded = np.zeros((px, py, nz), dtype=bool)
        padded[:nx, :ny] = interior
        occupied = padded.reshape(px // pi, pi, py // pj, pj, nz).any(axis=(1, 3))
        edges = np.diff(np.pad(occupied, ((0, 0), (0, 0), (1, 1))).astype(np.int8), axis=2)
        si, sj, sk = np.nonzero(edges == 1)
        ek = np.nonzero(edges == -1)[2]  # the same (i, j) order: each run's end follows its start
        pieces = -(-(ek - sk) // max_length)
        piece = np.arange(pieces.sum()) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        first = np.repeat(sk, pieces) + max_length * piece
        lengths = np.minimum(first + max_length, np.repeat(ek, pieces)) - first
        return np.stack([pi * np.repeat(si, pieces), pj * np.repeat(sj, pieces), first, lengths],
                        axis=1).astype(np.int32)

    def device_arrays(self, device) -> dict:
        """``index``, ``active_ijk`` and the stencil's work items on ``device`` (a Backend, or what
        :meth:`Backend.of` takes): on a GPU the patch walk's ``patches`` and the smoother step's ``step_patches``, on a
        CPU the node loop's ``neighbours`` (made there by ``voxelize``; for another device uploaded and made there,
        once)."""
        backend = Backend.of(device)
        d = backend.device
        arrays = self._device_arrays.setdefault(d.alias, {})
        if "index" not in arrays:
            arrays["index"] = wp.array(self.index, dtype=wp.int32, device=d)
            arrays["active_ijk"] = wp.array(self.active_ijk, dtype=wp.vec3i, device=d)
        if "neighbours" not in arrays and "patches" not in arrays:
            labels = wp.array(self.labels, dtype=wp.int8, device=d)
            arrays.update(_stencil_arrays(backend, labels, arrays["index"], arrays["active_ijk"], self.n_interior))
        return arrays


def voxelize(cage: Cage, resolution: int = 64, device=None, max_rows: int = MAX_ROWS, memory_budget: int | None = None,
             boundary="local", threads: int | None = None) -> Grid:
    """Voxelise the inside of a cage: label grid nodes and number the active ones.

    Nodes whose generalised winding number exceeds 1/2 are inside the cage and, unless cut off (below), interior
    (unknowns). Other nodes in the 19-point stencil of an interior node form the ring (known values and gradients);
    exterior nodes within ``BAND_WIDTH`` nodes of the interior form the band (known values, read by sampling).

    With the local boundary data, interior nodes that a wedge of outside space thinner than a cell cuts off from a
    stencil neighbour join the ring (``n_cut_off``): where the cage folds back on itself, the stencil would otherwise
    couple the wedge's two sides, or read ring data that describes the other side (the weights then grew with the
    resolution). A link is cut when it enters and leaves through the wedge's two walls (faces near along the cage whose
    normals are more than 120 degrees apart), or when the closest cage point of an exterior neighbour lies on the far
    wall. Only where the data extended to the node stays within :data:`CUT_OFF_MAX_CHANGE` of its boundary value
    (faces the grid resolves); elsewhere the node stays an unknown.

    Parameters
    ----------
    cage : Cage
        A checked cage (see :func:`warp_stokes.check_cage`).
    resolution : int
        Cells along the longest axis of the cage's bounding box (the grid adds ``MARGIN`` nodes per side).
    device : None | str | Backend
        Warp device; default CUDA when present, else CPU.
    max_rows : int
        Most active nodes a grid may have (rows are 32-bit); a lower value is for tests.
    memory_budget : int, optional
        Bytes the grid's dense arrays may take (default: the device's available memory).
    boundary : "local" | LocalData | "mvc"
        The boundary data the grid's known nodes will take (as in :func:`warp_stokes.bind`): with the local data,
        nodes cut off by thin wedges join the ring; with MVC data (global, the same on both sides) none do.
    threads : int, optional
        On a CPU, threads that classify slabs of nodes at once (default: every core; the same labels).

    Returns
    -------
    Grid

    Raises
    ------
    ResolutionError
        When the resolution is not an integer in [8, 2048], the grid's dense arrays do not fit in memory, it has
        more than ``max_rows`` active nodes, or no node falls inside the cage. The message names a resolution
        that would work.

    Examples
    --------
    >>> grid = voxelize(check_cage("examples/arm/arm_cage.obj"), resolution=16, device="cpu")  # doctest: +SKIP
    >>> grid.n_interior > 0  # doctest: +SKIP
    True
    """
    resolution = check_resolution(resolution)
    boundary = boundary_settings(boundary)
    backend = Backend.of(device, threads)
    lo, hi = cage.vertices.min(axis=0), cage.vertices.max(axis=0)
    centre = 0.5 * (lo + hi)
    extent = hi - lo
    spacing = float(extent.max() / resolution)
    cells = np.ceil(extent / spacing - 1e-9).astype(np.int64)
    counts = cells + 1 + 2 * MARGIN
    # centre the node lattice on the cage so that the margins are equal on both sides
    origin = -0.5 * spacing * (counts - 1).astype(np.float64)

    shape = tuple(int(c) for c in counts)
    # the dense node arrays (VOXELIZE_NODE_BYTES: labels, classes and the row index): fail before allocating
    dense = VOXELIZE_NODE_BYTES * int(np.prod(counts))
    room = backend.available_memory() if memory_budget is None else int(memory_budget)
    if dense > room:
        fits = int(resolution * (room / dense) ** (1.0 / 3.0) * 0.9)
        advice = (f"resolution {fits} or less would fit" if fits >= 8 else
                  "no grid of the coarsest resolution (8) fits; give more memory")
        error = ResolutionError(
            f"{cage.name}: a grid at resolution {resolution} has {int(np.prod(counts)):,} nodes and needs "
            f"{memory_size(dense)} before solving; {memory_size(room)} are available: {advice}"
        )
        error.fits = fits  # what resolution "auto" tries instead
        raise error
    with backend.scope():
        mesh = cage_mesh(cage, centre, backend.device)
        inside = classify_grid_nodes(mesh, shape, origin, spacing, backend)
        cut_off = _wedge_cut_off(cage, mesh, inside, origin, spacing, boundary, backend) if boundary.local else None
    grid = _number_nodes(inside, centre, origin, spacing, resolution, backend, max_rows, cage.name, cut_off)
    grid.boundary = boundary
    if grid.n_interior == 0:
        error = ResolutionError(
            f"{cage.name}: no grid node lies inside the cage at resolution {resolution} "
            f"(spacing {spacing:.4g}); the cage is too thin for this grid, try resolution {4 * resolution}"
        )
        error.suggested = 4 * resolution  # what resolution "auto" tries next
        raise error
    return grid


def classify_grid_nodes(mesh: wp.Mesh, shape: tuple, origin: np.ndarray, spacing: float,
                        backend: Backend) -> wp.array:
    """The nodes of a lattice inside the cage ``mesh`` (INTERIOR) or not (OUTSIDE), as an int8 array of ``shape``:
    node (i, j, k) at origin + spacing (i, j, k), in the mesh's frame (:func:`warp_stokes.kernels.voxel.classify_node`:
    the winding number, and the nodes on the cage outside). A GPU takes a winding number at every node; a CPU (where
    each costs a thread's time) at the nodes of even coordinates, then at the others only where those around them
    disagree or the cage passes near (``classify_between_even_nodes``): the same labels. On a CPU the slabs of
    nodes are shared out between the backend's threads."""
    device = backend.device
    inside = wp.empty(shape, dtype=wp.int8, device=device)
    # the winding numbers' arguments: the cage, the lattice, the accuracy and the tolerance of the surface
    lattice = [mesh.id, wp.vec3(*np.asarray(origin).astype(np.float32)), float(spacing), WINDING_ACCURACY,
               1e-5 * spacing]
    if not backend.on_cpu:
        wp.launch(voxel.classify_nodes, dim=shape, inputs=[*lattice, 0, 1], outputs=[inside], device=device)
        return inside
    even = tuple((n + 1) // 2 for n in shape)
    backend.in_threads(even[0], lambda a, b: wp.launch(voxel.classify_nodes, dim=(b - a, even[1], even[2]),
                                                       inputs=[*lattice, 2 * a, 2], outputs=[inside], device=device),
                       modules=("voxel",))
    backend.in_threads(shape[0], lambda a, b: wp.launch(voxel.classify_between_even_nodes,
                                                        dim=(b - a, shape[1], shape[2]), inputs=[*lattice, a],
                                                        outputs=[inside], device=device),
                       modules=("voxel",))
    return inside


def grid_from_mask(interior, spacing: float = 1.0, origin=(0.0, 0.0, 0.0), device=None) -> Grid:
    """A grid whose interior is given as a boolean mask: for manufactured solutions and research domains.

    Parameters
    ----------
    interior : (nx, ny, nz) bool array; must be False within ``MARGIN`` nodes of the array's edge
    spacing : float, node spacing h
    origin : (3,) position of node (0, 0, 0)
    device : None | str | Backend

    Returns
    -------
    Grid, with ``centre`` at the origin of coordinates and ``resolution`` set to the largest dimension.

    Examples
    --------
    >>> mask = np.zeros((16, 16, 16), bool); mask[5:11, 5:11, 5:11] = True
    >>> grid_from_mask(mask, device="cpu").n_interior
    216
    """
    interior = np.asarray(interior, dtype=bool)
    if interior.ndim != 3:
        raise ResolutionError(f"the interior mask must be 3D, got shape {interior.shape}")
    m = MARGIN
    core = np.zeros_like(interior)
    core[m:-m, m:-m, m:-m] = True
    if (interior & ~core).any():
        raise ResolutionError(f"interior nodes must stay {MARGIN} nodes away from the mask's edge")
    if not interior.any():
        raise ResolutionError("the interior mask is empty")
    backend = Backend.of(device)
    inside = wp.array(interior.astype(np.int8), dtype=wp.int8, device=backend.device)
    resolution = max(interior.shape) - 1 - 2 * MARGIN
    return _number_nodes(inside, np.zeros(3), np.asarray(origin, dtype=np.float64), float(spacing), resolution,
                         backend, MAX_ROWS, "the interior mask")


def _wedge_cut_off(cage: Cage, mesh: wp.Mesh, inside: wp.array, origin, spacing: float, boundary,
                   backend: Backend):
    """The launch that moves interior nodes cut off by thin wedges to the ring (see :func:`voxelize`), as a function
    of the labels array; run after the ring and band are marked (the numbering counts the nodes it moved)."""
    settings = boundary_settings(boundary)
    adjacent = np.eye(cage.n_handles, dtype=np.int8)
    edges = cage.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    adjacent[edges[:, 0], edges[:, 1]] = 1
    adjacent[edges[:, 1], edges[:, 0]] = 1
    device = inside.device
    inputs = [wp.array(cage.faces.astype(np.int32), dtype=wp.int32, device=device),
              wp.array(adjacent, dtype=wp.int8, device=device),
              wp.array(data_slopes(cage, settings, backend).astype(np.float32), dtype=float, device=device), inside,
              wp.vec3(*np.asarray(origin, dtype=np.float32)), float(spacing), WEDGE_FACING, CUT_OFF_MAX_CHANGE]

    def cut_off(labels: wp.array) -> None:
        wp.launch(voxel.cut_off_nodes, dim=labels.shape, inputs=[mesh.id, *inputs], outputs=[labels], device=device)

    return cut_off


def lattice_counts(classes: wp.array) -> tuple[wp.array, np.ndarray]:
    """Nodes of each class (``kernels.voxel.node_class``: 0 to 3, -1 not numbered) in every (i, j) column of a lattice,
    on its device, and their totals per class (int64, on the host)."""
    nx, ny, _ = classes.shape
    counts = wp.empty(voxel.LATTICE_CLASSES * nx * ny, dtype=wp.int32, device=classes.device)
    wp.launch(voxel.count_classes, dim=(nx, ny), inputs=[classes], outputs=[counts], device=classes.device)
    return counts, counts.numpy().reshape(voxel.LATTICE_CLASSES, -1).sum(axis=1, dtype=np.int64)


def lattice_rows(classes: wp.array, counts: wp.array, n_rows: int) -> tuple[wp.array, wp.array]:
    """The rows of a lattice's nodes, numbered on its device by class, then in lattice order (i, j, k; k fastest):
    (index, the (nx, ny, nz) row of each node or -1; ijk, the (n_rows,) node of each row). ``counts`` and ``n_rows``
    come from :func:`lattice_counts`; ``n_rows`` must fit 32-bit rows (the caller checks)."""
    device = classes.device
    first_rows = wp.empty_like(counts)
    wp.utils.array_scan(counts, first_rows, inclusive=False)
    index = wp.empty(classes.shape, dtype=wp.int32, device=device)
    ijk = wp.empty(max(int(n_rows), 1), dtype=wp.vec3i, device=device)[: int(n_rows)]
    wp.launch(voxel.number_classes, dim=classes.shape[:2], inputs=[classes, first_rows], outputs=[index, ijk],
              device=device)
    return index, ijk


def _number_nodes(inside: wp.array, centre, origin, spacing, resolution, backend: Backend, max_rows, name,
                  cut_off=None) -> Grid:
    """Mark the ring and band around the interior nodes of `inside` (and those that ``cut_off`` moves to the ring),
    and number the active nodes: interior, cut off, other ring, band (on the device; the host only reads counts)."""
    shape = inside.shape
    with backend.scope():
        labels = wp.empty(shape, dtype=wp.int8)
        backend.in_threads(shape[0], lambda first, stop: wp.launch(
            voxel.mark_ring_and_band, dim=(stop - first, shape[1], shape[2]), inputs=[inside, BAND_WIDTH, first],
            outputs=[labels]), modules=("voxel",))
        if cut_off is not None:
            cut_off(labels)
        classes = wp.empty(shape, dtype=wp.int8)
        wp.launch(voxel.node_classes, dim=shape, inputs=[labels, inside], outputs=[classes])
        counts, per_class = lattice_counts(classes)
        n_interior, n_cut_off, n_ring, n_band = (int(c) for c in per_class)
        n_active = n_interior + n_cut_off + n_ring + n_band
        if n_active > max_rows:
            # the band and ring grow with the square of the resolution, the interior with its cube: scaling by the
            # square root of the excess is safe for both
            fits = int(resolution * (max_rows / n_active) ** 0.5)
            raise ResolutionError(
                f"{name}: resolution {resolution} gives {n_active:,} active grid nodes, more than the {max_rows:,} "
                f"that 32-bit rows can number; resolution {fits} or less would fit"
            )
        index, active_ijk = lattice_rows(classes, counts, n_active)
        del classes, counts
        work_items = _stencil_arrays(backend, labels, index, active_ijk, n_interior)
        labels_np = labels.numpy()
        grid = Grid(
            centre=np.asarray(centre, dtype=np.float64),
            origin=np.asarray(origin, dtype=np.float64),
            spacing=float(spacing),
            resolution=int(resolution),
            labels=labels_np,
            active_ijk=active_ijk.numpy(),
            n_interior=n_interior,
            n_ring=n_cut_off + n_ring,
            n_band=n_band,
            n_cut_off=n_cut_off,
        )
    # the device's numbering is the grid's (the host copy of the index is made when first read)
    grid._device_arrays[backend.alias] = {"index": index, "active_ijk": active_ijk, **work_items}
    return grid


def _stencil_arrays(backend: Backend, labels: wp.array, index: wp.array, active_ijk: wp.array,
                    n_interior: int) -> dict:
    """The stencil's work items on the labels' device. A GPU's patch walks: the operator's ``patches`` and the
    smoother step's ``step_patches``, made from the labels there (numpy's passes over the lattice in
    :meth:`Grid.interior_patches` took 0.4-0.6 s each at n = 512). A CPU's node loops: each interior node's neighbour
    rows, ``neighbours`` (n_interior, 18) (:mod:`warp_stokes.kernels.stencil_cpu`)."""
    device = labels.device
    if backend.on_cpu:
        neighbours = wp.empty((n_interior, stencil_cpu.NEIGHBOURS), dtype=wp.int32, device=device)
        wp.launch(stencil_cpu.neighbour_rows, dim=neighbours.shape, inputs=[index, active_ijk], outputs=[neighbours],
                  device=device)
        return {"neighbours": neighbours}
    return {"patches": device_patches(labels, (stencil.PATCH_I, stencil.PATCH_J)),
            "step_patches": device_patches(labels, stencil.STEP_PATCH)}


def device_patches(labels: wp.array, patch: tuple, max_length: int = PATCH_LENGTH) -> wp.array:
    """:meth:`Grid.interior_patches` (the same items in the same order) from a grid's labels on their device: a
    count per patch column, a scan, a walk; the host reads the total only.

    Parameters
    ----------
    labels : wp.array3d of int8, the grid's labels
    patch : (int, int), columns per patch along x and y
    max_length : int

    Returns
    -------
    wp.array of vec4i (i0, j0, k0, planes), on the labels' device
    """
    pi, pj = (int(p) for p in patch)
    if pi < 1 or pj < 1 or not 1 <= max_length < 2**30:
        raise ValueError(f"patch {patch} and max_length {max_length} must be positive (max_length below 2^30)")
    device = labels.device
    columns = (-(-labels.shape[0] // pi), -(-labels.shape[1] // pj))
    counts = wp.empty(columns[0] * columns[1], dtype=wp.int32, device=device)
    wp.launch(voxel.count_patch_items, dim=columns, inputs=[labels, pi, pj, int(max_length)], outputs=[counts],
              device=device)
    first = wp.empty_like(counts)
    wp.utils.array_scan(counts, first, inclusive=False)
    total = int(first[-1:].numpy()[0] + counts[-1:].numpy()[0])
    items = wp.empty(max(total, 1), dtype=wp.vec4i, device=device)[:total]
    wp.launch(voxel.write_patch_items, dim=columns, inputs=[labels, pi, pj, int(max_length), first],
              outputs=[items], device=device)
    return items
