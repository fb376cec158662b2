"""Binding a mesh to a cage: load -> grid -> solve -> sample, the weights of every vertex in a :class:`Binding`.

Three methods share the loading, the checks and the Binding: Stokes coordinates (the compact biharmonic scheme,
the default), harmonic coordinates (the 7-point Laplace equation on the same grid with the same boundary data, Joshi
et al. 2007, what Blender's Mesh Deform computes) and mean value coordinates evaluated at the vertices (no grid)."""

from __future__ import annotations

import math
import time
import warnings

import numpy as np

from ..device import Backend
from ..errors import ConvergenceError, ResolutionError
from ..geometry import resolution as resolution_policy
from ..geometry.cage import Cage
from ..geometry.local_boundary import local_values
from ..geometry.mean_value import mean_value_coordinates
from ..memory import memory_size
from ..geometry.resolution import AUTO_RESOLUTION, auto_resolution, check_resolution, wedge_resolution
from ..solver.solve import ACCEPTABLE
from ..solver.multigrid import solving
from .bind_inputs import Inputs, load_inputs
from .columns import grid_columns
from .plan import METHODS, GridPlan
from .spread import driver_device, spread_devices
from .stats import (BindStats, ResolutionChoice, grid_stats, identity_errors, mvc_stats, settings_record,
                    solver_stats)
from .store import Binding

__all__ = ["bind", "identity_errors", "METHODS"]

#: vertices per block of mean value coordinates (float64 on the device, float32 in the weights)
MVC_ROWS = 1 << 16
#: resolution "auto" goes no coarser than this to fit the memory budget (the budget's error is raised instead)
AUTO_MEMORY_FLOOR = 16
def _suggest_resolution(resolution: int, spacing: float, distances: np.ndarray) -> int:
    """Resolution at which a feature whose points lie within `distances` of the surface spans ~3 cells."""
    thickness = max(2.0 * float(np.max(distances)), 1e-12)
    return int(min(2048, max(2 * resolution, math.ceil(resolution * 3.0 * spacing / thickness))))


def bind(mesh, cage=None, resolution="auto", device=None, tol: float = 1e-6, max_iterations: int | None = None,
         solver: str = "multigrid", memory_budget: int | None = None, boundary="local",
         sampling: str = "hermite", cage_prim: str | None = None, mesh_prims=None, rest_time=None,
         method: str = "stokes", progress=None, threads: int | None = None) -> Binding:
    """Compute Stokes cage coordinates (or harmonic or mean value coordinates) of a mesh's vertices with respect to a
    cage.

    Load -> voxelise (winding number) -> boundary data (local data by default) -> batched solve of the compact
    biharmonic scheme for all handles (in chunks when memory asks for it) -> sampling at the vertices (tricubic
    Hermite by default). Vertices outside the cage but within the grid's band are sampled too; vertices beyond it
    get the boundary data at their position (warning).

    Parameters
    ----------
    mesh : path | trimesh.Trimesh | (vertices, faces) | Scene
        The mesh to deform; its vertex order is kept. A USD asset (``.usd/.usda/.usdc/.usdz``) or a glTF/GLB
        scene binds all its meshes together, in world space (see :func:`warp_stokes.io.scene.load_scene`).
    cage : path | trimesh.Trimesh | (vertices, faces) | "auto" | MadeCage, optional
        A closed, consistently oriented cage (quads and polygons are triangulated). May be left out when
        ``cage_prim`` names the cage in the mesh's USD stage. ``"auto"``: a cage made for the mesh
        (:func:`warp_stokes.geometry.cage_making.make_cage`, its default handles and offset), recorded in
        ``stats.made_cage``; the binding holds it (``cage_vertices``, ``cage_faces``). A ``MadeCage``
        (``make_cage(mesh, handles=200)``, say) is bound and recorded the same way.
    resolution : "auto" | int
        Grid cells along the cage's longest axis. "auto": 64, or more where the cage's folded edges need a finer
        grid to cut off the thin wedges of outside space there (:func:`warp_stokes.geometry.resolution.auto_resolution`),
        and more again where the cage is too thin for its grid or the mesh has parts thinner than two cells (bound
        once more), at most 96 on a CPU and 256 on a GPU; the choice is in ``stats.resolution``.
    device : None | str | list of str
        ``"cpu"``, ``"cuda"`` or ``"cuda:N"``; default CUDA when present, else CPU. Several devices (a list,
        ``"cuda:0,cuda:1"``, or ``"cuda:all"`` for every GPU of the Ray cluster) spread the handles' solves over
        them as Ray tasks (:mod:`warp_stokes.binding.spread`; the ``ray`` extra).
    tol : float
        Relative (preconditioned) residual per handle, and deviation from partition of unity and linear
        precision at the nodes, at which the solver stops.
    max_iterations : int, optional
        Solver iteration limit.
    solver : "multigrid" | "jacobi"
        The CG preconditioner: the multigrid V-cycle (default), or the inverse diagonal (for comparisons).
    memory_budget : int, optional
        Bytes the bind may allocate on the device (default: 90% of a GPU's free memory, half the free RAM on
        the CPU). Handles are solved in chunks that fit it.
    threads : int, optional
        On a CPU, threads that solve chunks of handles at once (default: every core the process may use; 1 for the
        single-threaded solve). The memory plan counts each thread's chunk. Ignored on a GPU.
    boundary : "local" | "mvc" | LocalData
        The data at ring and band nodes (see :func:`warp_stokes.boundary_field`): the local data of
        :mod:`warp_stokes.geometry.local_boundary` (default, ``LocalData()``), or mean value coordinates.
    sampling : "hermite" | "trilinear"
        How the weights are interpolated at the vertices (see :func:`warp_stokes.sample_weights`): C1 tricubic
        Hermite of the values and gradients (default), or C0 trilinear of the values.
    cage_prim : str, optional
        The cage's ``UsdGeom.Mesh`` prim path, in ``cage`` when that is a USD file, else in the mesh's USD stage
        (then it is not bound as a mesh). Read in world space at its first time sample (or ``rest_time``).
    mesh_prims : list of str, optional
        For a USD asset, the mesh prims to bind (default: all of them but the cage).
    rest_time : float, optional
        For USD inputs, the time code of the rest pose.
    method : "stokes" | "harmonic" | "mvc"
        Stokes coordinates (default); harmonic coordinates: the 7-point Laplace equation on the same grid, with the
        same boundary data, solver and sampling; or mean value coordinates evaluated at the vertices (no grid: the
        grid and solver arguments are not used).
    progress : callable, optional
        ``progress(stage, **info)`` as the bind goes: "voxelising" (resolution), "multigrid" (levels), "boundary
        data", "solving" (iteration, residual: the largest relative residual still iterating) and "sampling", the
        last three with chunk and chunks when the handles are solved in chunks (threads that solve chunks at once
        call it from their threads, "boundary data" first with threads); "spreading" (devices) for a bind over
        several devices. The command line draws it as one line on a terminal.

    Returns
    -------
    Binding

    Raises
    ------
    MeshError, CageError, ResolutionError (all ValueError)

    Examples
    --------
    >>> import warp_stokes as ws
    >>> b = ws.bind("examples/arm/arm.obj", "examples/arm/arm_cage.obj", resolution=32)  # doctest: +SKIP
    >>> b.weights.shape  # doctest: +SKIP
    (2089, 58)
    """
    devices = spread_devices(device)  # several: the handles' solves spread over them (Ray tasks)
    if devices is None and isinstance(device, (list, tuple)):
        device = device[0]  # a list of one device
    plan = GridPlan.of(device if devices is None else driver_device(devices), method, boundary, solver, tol,
                       max_iterations, sampling, memory_budget, threads)
    resolution = check_resolution(resolution)  # arguments first: before the inputs are loaded and checked
    with solving():  # (other binds of this process in threads: no graph recorded meanwhile, see Multigrid.apply)
        return _bind_planned(mesh, cage, cage_prim, mesh_prims, rest_time, resolution, plan, devices, progress)


def _bind_planned(mesh, cage, cage_prim, mesh_prims, rest_time, resolution, plan: GridPlan, devices, progress):
    """:func:`bind` once its arguments are checked and its plan made."""
    seconds = {}
    inputs = load_inputs(mesh, cage, cage_prim, mesh_prims, rest_time, plan.backend, seconds)
    choice = _choose_resolution(inputs, resolution, plan, devices, progress)
    resolution = resolution if choice.chosen is None else choice.chosen
    settings = settings_record(resolution, plan, inputs.surface, inputs.cage, inputs.scene, cage_prim)
    if plan.equation is None:
        return _bind_by_mean_value(inputs, settings, plan.backend, seconds)
    part, resolution = _solve_grid(inputs, resolution, choice, plan, devices, progress, seconds)
    settings["resolution"] = resolution
    return _finish_grid(inputs, part, resolution, choice, settings, plan, seconds)


def _choose_resolution(inputs: Inputs, resolution, plan: GridPlan, devices, progress) -> ResolutionChoice:
    """What was ``requested`` and, for "auto", what it stands for on this cage and device (``chosen``, ``needed``,
    ``cap``; the later stages refine it)."""
    if resolution != "auto":
        return ResolutionChoice(resolution)
    if plan.equation is None:
        return ResolutionChoice(resolution, AUTO_RESOLUTION, AUTO_RESOLUTION)
    if progress is not None:
        progress("choosing the resolution")  # the local data, formed here first: seconds for thousands of handles
    kind = None if devices is None else "cpu" if devices[0] == "cpu" else "cuda"
    return ResolutionChoice(resolution, *auto_resolution(inputs.cage, plan.boundary, plan.backend, kind))


def _bind_by_mean_value(inputs: Inputs, settings: dict, backend: Backend, seconds: dict) -> Binding:
    """Mean value coordinates at the vertices: no grid, no solve."""
    points = inputs.surface.vertices
    weights = _mean_value_weights(inputs.cage, points, backend, seconds)
    seconds["total"] = sum(seconds.values())
    pu_error, lp_error = identity_errors(weights, inputs.cage.vertices, points)
    stats = mvc_stats(inputs.cage, inputs.surface, inputs.inside, backend, pu_error, lp_error, seconds)
    return inputs.binding(weights, settings, stats, backend)


def _solve_grid(inputs: Inputs, resolution: int, choice: ResolutionChoice, plan: GridPlan, devices, progress,
                seconds: dict):
    """The grid part of a bind, on one device or spread over ``devices``: the columns at ``resolution`` and the
    resolution they were solved at. Resolution "auto" (``choice.chosen`` set) tries finer where the cage is too
    thin for the grid or the mesh has parts the grid does not resolve, and coarser where the memory asks for it,
    and ``choice`` records what it chose."""
    checked, points = inputs.cage, inputs.surface.vertices

    def columns(resolution):
        if devices is None:
            return grid_columns(checked, points, resolution, plan, progress=progress)
        from .spread import spread_columns

        if progress is not None:
            progress("spreading", devices=len(devices))
        return spread_columns(checked, points, resolution, devices, plan)

    part, resolution = _columns_for(columns, resolution, choice)
    thin = _thin_vertices(part.corners, part.grid, inputs.inside)
    if choice.chosen is not None and thin.any():
        # "auto" resolves the mesh's thin parts too, within the cap and the memory: one more bind at what resolves them
        suggestion = _suggest_resolution(resolution, part.grid.spacing, inputs.distance[thin])
        choice.needed = max(choice.needed, suggestion)
        finer = min(suggestion, choice.cap, choice.memory_fits or suggestion)
        if finer > resolution:
            first = sum(part.seconds.values())
            choice.thin_parts = suggestion
            try:
                part, resolution = _columns_for(columns, finer, choice, floor=resolution)
            except ResolutionError:  # none finer fits the memory: the first bind stands
                choice.memory_fits = resolution
            else:
                seconds["first_resolution"] = first
            choice.chosen = resolution
    return part, resolution


def _finish_grid(inputs: Inputs, part, resolution: int, choice: ResolutionChoice, settings: dict, plan: GridPlan,
                 seconds: dict) -> Binding:
    """The last stage of a grid bind: vertices beyond the grid's band given the boundary data, the warnings, the
    exactness of the weights checked (an inexact result is refused) and the stats."""
    if choice.memory_fits is not None and resolution < choice.needed:
        choice.memory_budget_bytes = plan.budget()
    seconds.update(part.seconds)
    checked, surface = inputs.cage, inputs.surface
    grid, weights, corners = part.grid, part.weights, part.corners
    t = time.perf_counter()
    notes, beyond, thin = _vertices_off_the_grid(surface, checked, grid, resolution, weights, corners, inputs.inside,
                                                 inputs.distance, plan, choice)
    seconds["sample"] += time.perf_counter() - t
    seconds["total"] = sum(seconds.values())
    pu_error, lp_error = identity_errors(weights, checked.vertices, surface.vertices)
    _refuse_inexact(checked, surface, pu_error, lp_error, part.reports)
    stats = BindStats(
        device=plan.backend.name, method=plan.method, handles=checked.n_handles, vertices=len(surface.vertices),
        vertices_outside_cage=int((~inputs.inside).sum()), vertices_beyond_band=int(beyond.sum()),
        vertices_in_thin_features=int(thin.sum()), grid=grid_stats(grid), resolution=choice,
        solver=solver_stats(part, plan.preconditioner), memory_estimate_bytes=part.memory_estimate,
        partition_of_unity_error=pu_error, linear_precision_error=lp_error, seconds=seconds, warnings=notes)
    return inputs.binding(weights, settings, stats, plan.backend)


def _columns_for(columns, resolution: int, choice: ResolutionChoice, floor: int = 0):
    """``columns(resolution)``, and the resolution it was solved at. For resolution "auto" (``choice.chosen``
    set), a grid the cage is too thin for is tried finer (within the cap and the memory), and one the memory
    budget cannot hold is tried coarser (down to :data:`AUTO_MEMORY_FLOOR`, and above ``floor``: a finer bind tried
    after one that worked never ends coarser than it); ``choice`` records what was chosen. Other resolution errors,
    and every one of an explicit resolution, are raised."""
    while True:
        try:
            return columns(resolution), resolution
        except ResolutionError as error:
            if choice.chosen is None:
                raise
            limit = min(choice.cap, choice.memory_fits or choice.cap)
            finer = min(error.suggested or 0, limit)
            coarser = error.fits or 0
            if finer > resolution:
                choice.needed = max(choice.needed, error.suggested)
                resolution = finer
            elif max(AUTO_MEMORY_FLOOR, floor + 1) <= coarser < resolution:
                resolution = choice.memory_fits = coarser
            else:
                raise
            choice.chosen = resolution


def _thin_vertices(corners: np.ndarray, grid, inside: np.ndarray) -> np.ndarray:
    """Vertices inside the cage whose grid cell has no node inside it: in a part of the cage the grid does not
    resolve."""
    sampled = (corners >= 0).all(axis=1)
    return inside & sampled & ~((corners >= 0) & (corners < grid.n_inside)).any(axis=1)


def _mean_value_weights(checked: Cage, points: np.ndarray, backend: Backend, seconds: dict) -> np.ndarray:
    """Mean value coordinates at the vertices, in blocks of rows (float64 on the device, stored as float32)."""
    t = time.perf_counter()
    weights = np.empty((len(points), checked.n_handles), dtype=np.float32)
    for start in range(0, len(points), MVC_ROWS):
        block = slice(start, start + MVC_ROWS)
        weights[block] = mean_value_coordinates(checked, points[block], device=backend)
    seconds["mvc"] = time.perf_counter() - t
    return weights


def _refuse_inexact(checked: Cage, surface, pu_error: float, lp_error: float, reports) -> None:
    """Weights that break partition of unity or linear precision at the vertices are an error, not a result. Each
    solve checked its own nodes (:data:`warp_stokes.solver.solve.ACCEPTABLE` times its tolerance), but a chunk's
    check is partition of unity alone: linear precision of a bind solved in chunks (or spread over devices) is
    measured here, on the weights of all of them."""
    limit = ACCEPTABLE * max(r.identity_tolerance for r in reports)
    if not (pu_error <= limit and lp_error <= limit):
        raise ConvergenceError(
            f"{checked.name}: the weights of {surface.name} break partition of unity ({pu_error:.2g}) or linear "
            f"precision ({lp_error:.2g} of the diagonal) beyond {limit:.1g} although every solve converged "
            f"({len(reports)} chunk(s)); no weights were returned: a fault of the solver; please report it with the "
            "cage")


def _vertices_off_the_grid(surface, checked: Cage, grid, resolution: int, weights: np.ndarray, corners: np.ndarray,
                           inside: np.ndarray, distance: np.ndarray, plan: GridPlan, choice: ResolutionChoice):
    """Vertices beyond the grid's band get the boundary data at their own position (in ``weights``): the data
    their neighbours within the band are interpolated from, so that a vertex's weights do not jump when a finer
    grid's band no longer reaches it (MVC there, against the local data within the band, made such weights jump by
    more than refinement changes them elsewhere). Vertices in features thinner than the grid resolves are counted; both
    are warned of, and a resolution too coarse for the cage's folded edges (:func:`wedge_resolution`). Returns
    (notes, beyond, thin): the cage's notes and these warnings, and the two vertex masks."""
    sampled = (corners >= 0).all(axis=1)
    beyond = ~sampled
    notes = list(checked.notes)  # what the user is warned of, kept in the stats
    if beyond.any():
        points = surface.vertices
        if plan.local_data:
            weights[beyond] = local_values(checked, points[beyond], grid.spacing, plan.boundary,
                                           plan.backend).astype(np.float32)
        else:
            weights[beyond] = mean_value_coordinates(checked, points[beyond], device=plan.backend).astype(np.float32)
        notes.append(
            f"{surface.name}: {int(beyond.sum())} vertices lie outside {checked.name} beyond the grid's band "
            f"(up to {distance[beyond].max():.3g} from the cage, {distance[beyond].max() / checked.diagonal:.3g} of its "
            "diagonal); they get the boundary data at their position")
        warnings.warn(notes[-1], stacklevel=4)
    thin = _thin_vertices(corners, grid, inside)
    below = wedge_resolution(checked, plan.boundary, plan.backend)
    folded = below is not None and resolution < below
    if choice.memory_budget_bytes:
        # "auto" stopped short for the memory: one warning says why and what to do
        reasons = [f"{int(thin.sum())} mesh vertices lie in parts thinner than two of its cells"] if thin.any() else []
        reasons += [f"its folded edges need resolution {below}"] if folded else []
        notes.append(
            f"{checked.name}: resolution 'auto' bound at {resolution}, the finest grid that fits the memory budget "
            f"({memory_size(choice.memory_budget_bytes)}); the cage asks for {choice.needed}"
            + (f" ({'; '.join(reasons)})" if reasons else "")
            + ": give more memory (--memory-gb, memory_budget=) or bind on a device with more")
        warnings.warn(notes[-1], stacklevel=4)
        return notes, beyond, thin
    if thin.any():
        capped = choice.cap
        suggestion = _suggest_resolution(resolution, grid.spacing, distance[thin])
        notes.append(
            f"{checked.name}: {int(thin.sum())} mesh vertices lie in parts of the cage thinner than about two grid "
            f"cells at resolution {resolution}; their weights come from the boundary data alone. "
            f"resolution={suggestion} would resolve them"
            + (f" (resolution 'auto' stops at {capped} on this device)" if capped and suggestion > capped else ""))
        warnings.warn(notes[-1], stacklevel=4)
    if folded:
        capped = choice.cap
        caps = resolution_policy.AUTO_RESOLUTION_CAP
        reachable = below <= caps[plan.backend.kind]
        advice = (f"resolution 'auto' stops at {capped} on this device; give --resolution {min(below, 2048)} "
                  "(resolution= in Python) for weights that converge there" if capped else
                  "give --resolution auto (the default) or more" if reachable else
                  f"give --resolution {min(below, 2048)} (resolution= in Python)")
        notes.append(
            f"{checked.name}: at resolution {resolution} the grid does not yet cut off the thin wedges of outside "
            f"space at the cage's folded edges (it does from resolution {below} on"
            f"{', beyond the largest grid' if below > 2048 else ''}); weights within a few cells of those edges "
            f"converge slowly below it: {advice}")
        warnings.warn(notes[-1], stacklevel=4)
    return notes, beyond, thin


