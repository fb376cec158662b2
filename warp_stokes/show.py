"""Pictures of a binding, headless (matplotlib's Agg backend) and deterministic: a handle's weight on an axis-aligned
slice through the cage (:func:`weight_slice`, drawn by :func:`show_weights`), and the bound mesh, deformed by a cage
pose, coloured per triangle by conformal distortion or by its distance to a reference mesh (:func:`mesh_colours`,
drawn by :func:`show_mesh`): the paper's weight slices and encoding-error maps.

A binding keeps the weights at the mesh's vertices only, so a slice solves the one handle again on the binding's
grid (its resolution, tolerance, solver, boundary data and equation), which on a CPU gives the same numbers every
time. Mean value coordinates have no grid: they are evaluated at the centres of a lattice of pixels over the cage's
bounding box.
"""

from __future__ import annotations

import os
import warnings
from typing import NamedTuple

import numpy as np

from .device import resolve_device
from .errors import WarpStokesError
from .geometry.boundary import boundary_field, mean_value_coordinates
from .geometry.cage import check_cage
from .geometry.grid import voxelize
from .geometry.inside import classify_points
from .geometry.topology import bounding_diagonal
from .io.outputs import atomic_output
from .io.load import load_surface
from .quality import conformal_distortion
from .solver.solve import solve_biharmonic

__all__ = ["WeightSlice", "MeshColours", "weight_slice", "symmetric_scale", "cross_section", "show_weights", "mesh_colours",
           "cage_edges", "view_frame", "show_mesh", "binding_method", "AXES", "VIEWS"]

AXES = "xyz"
VIEWS = ("front", "side", "top")
#: per view, the rows (screen right, screen up, towards the viewer) for a Y-up model: front looks along -z
_Y_UP_VIEWS = {"front": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
               "side": ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
               "top": ((1, 0, 0), (0, 0, -1), (0, 1, 0))}
#: a Z-up model in the Y-up frame: (x, y, z) -> (x, z, -y), so that front looks along +y with +z up
_Z_UP_TO_Y_UP = ((1, 0, 0), (0, 0, 1), (0, -1, 0))
_RC = {"svg.hashsalt": "warp-stokes", "figure.dpi": 100}


class WeightSlice(NamedTuple):
    """One handle's weight on a plane through the cage.

    Attributes
    ----------
    image : (rows, columns) float64, rows along the plane's second axis, columns along its first; NaN outside the cage
    extent : (u0, u1, v0, v1), the image's edges in world units (matplotlib's ``imshow`` extent)
    outline : (S, 2, 2) float64, the cage's cross-section as segments of (u, v) points
    plane_axes : (int, int), the world axes of u and v (the two other than the slice's, in order)
    position : float, the plane's world coordinate along the slice's axis (the lattice plane nearest the fraction)
    method : "stokes" | "harmonic" | "mvc"
    resolution : int or None (mvc)
    mesh_outline : (S, 2, 2) float64, the bound mesh's cross-section (empty for a point set)
    handle : (3,) float64, the handle's position: (u, v) on the plane and its distance off it
    """

    image: np.ndarray
    extent: tuple
    outline: np.ndarray
    plane_axes: tuple
    position: float
    method: str
    resolution: int | None
    mesh_outline: np.ndarray = np.zeros((0, 2, 2))
    handle: tuple = (0.0, 0.0, 0.0)


class MeshColours(NamedTuple):
    """The bound mesh as drawn by :func:`show_mesh`: vertices (V, 3), one value per triangle (F,), and what the
    values are (the colour bar's label)."""

    vertices: np.ndarray
    values: np.ndarray
    label: str


def binding_method(binding) -> str:
    """How the binding's weights were computed: ``settings["method"]``, "stokes" for bindings that do not say."""
    return str(binding.settings.get("method") or "stokes")


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise WarpStokesError('the pictures need matplotlib: pip install "warp-stokes[plot]"') from None
    return plt


def _axis(axis) -> int:
    if axis in (0, 1, 2):
        return int(axis)
    if isinstance(axis, str) and axis.lower() in AXES:
        return AXES.index(axis.lower())
    raise WarpStokesError(f"the slice's axis must be x, y or z, got {axis!r}")


def cross_section(vertices, faces, axis: int, position: float) -> np.ndarray:
    """The cage's outline on the plane ``x[axis] == position``: one segment per triangle that crosses it.

    Parameters
    ----------
    vertices : (L, 3) array
    faces : (T, 3) int array
    axis : 0, 1 or 2
    position : float

    Returns
    -------
    (S, 2, 2) float64, segments in the plane's coordinates (the two other axes, in order). A vertex on the plane
    counts as above it, so a surface through a vertex gives connected segments.

    Examples
    --------
    >>> v = np.array([[0, 0, -1], [1, 0, 1], [0, 1, 1]], float)
    >>> cross_section(v, np.array([[0, 1, 2]]), 2, 0.0).tolist()
    [[[0.5, 0.0], [0.0, 0.5]]]
    """
    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    d = vertices[:, axis] - position
    above = d >= 0
    starts, ends = faces, np.roll(faces, -1, axis=1)  # edges (0, 1), (1, 2), (2, 0) of every triangle
    crossing = above[starts] != above[ends]
    t = d[starts] / np.where(crossing, d[starts] - d[ends], 1.0)
    points = vertices[starts] + t[..., None] * (vertices[ends] - vertices[starts])
    cut = crossing.sum(axis=1) == 2
    first_two = np.argsort(~crossing[cut], axis=1, kind="stable")[:, :2]
    segments = np.take_along_axis(points[cut], first_two[..., None], axis=1)
    return segments[..., [a for a in range(3) if a != axis]]


def weight_slice(binding, handle: int, axis="z", fraction: float = 0.5, device=None,
                 pixels: int = 256) -> WeightSlice:
    """Handle ``handle``'s weight on the plane at ``fraction`` of the cage's bounding box along ``axis``.

    Grid methods (stokes, harmonic) solve the handle again on the binding's grid and show its nodes on the lattice
    plane nearest the fraction, one pixel per node, nodes inside the cage only (cut-off nodes
    too: they hold known data); ``mvc`` evaluates mean value coordinates at
    the centres of ``pixels`` pixels along the plane's longer side of the cage's bounding box, inside the cage only.

    Parameters
    ----------
    binding : Binding
    handle : int, a handle (cage vertex) of the binding
    axis : "x" | "y" | "z" | 0 | 1 | 2, the axis across the plane
    fraction : float in [0, 1], 0 the cage's bounding box's low face along the axis, 1 its high face
    device : None | str, where to solve
    pixels : int, the mvc image's size along its longer side

    Returns
    -------
    WeightSlice

    Raises
    ------
    WarpStokesError
        A handle out of range, a bad axis or fraction, or a method it does not know.

    Examples
    --------
    >>> s = weight_slice(ws.load_binding("arm.npz"), 5, "z", 0.5, device="cpu")  # doctest: +SKIP
    >>> s.image.shape, s.extent                                                  # doctest: +SKIP
    """
    if isinstance(handle, bool) or not isinstance(handle, (int, np.integer)) or not 0 <= handle < binding.n_handles:
        raise WarpStokesError(f"handle {handle!r} is not one of the binding's handles 0 to {binding.n_handles - 1}")
    a = _axis(axis)
    if not 0.0 <= float(fraction) <= 1.0:
        raise WarpStokesError(f"the slice's fraction must be in [0, 1], got {fraction!r}")
    method = binding_method(binding)
    if method not in ("stokes", "harmonic", "mvc"):
        raise WarpStokesError(f"the binding's method {method!r} is not stokes, harmonic or mvc")
    with warnings.catch_warnings():  # the cage was checked, and its notes shown, when it was bound
        warnings.simplefilter("ignore")
        cage = check_cage((binding.cage_vertices, binding.cage_faces), name="the bound cage")
    device = resolve_device(device)
    lo, hi = cage.vertices.min(axis=0), cage.vertices.max(axis=0)
    position = float(lo[a] + float(fraction) * (hi[a] - lo[a]))
    if method == "mvc":
        image, extent, position = _mvc_slice(cage, handle, a, position, lo, hi, device, pixels)
        resolution = None
    else:
        resolution = int(binding.settings["resolution"])
        image, extent, position = _grid_slice(binding.settings, cage, handle, a, position, lo, hi, device,
                                              method == "harmonic")
    plane = tuple(x for x in range(3) if x != a)
    mesh_outline = (cross_section(binding.mesh_vertices, binding.mesh_faces, a, position)
                    if len(binding.mesh_faces) else np.zeros((0, 2, 2)))
    corner = cage.vertices[handle]
    return WeightSlice(image, extent, cross_section(cage.vertices, cage.faces, a, position), plane, position, method,
                       resolution, mesh_outline, (float(corner[plane[0]]), float(corner[plane[1]]),
                                              float(corner[a] - position)))


def symmetric_scale(image: np.ndarray) -> tuple[float, float]:
    """The colour scale of a weight slice: symmetric about 0, up to the largest |weight| (a weight and its
    negative get colours equally far from white: a stretched negative half made pale blue look as large as pale
    red).

    Examples
    --------
    >>> symmetric_scale(np.array([[0.593, -0.006], [np.nan, 0.1]]))
    (-0.593, 0.593)
    """
    finite = np.abs(image[np.isfinite(image)])
    largest = float(finite.max()) if finite.size and finite.max() > 0 else 1.0
    return -largest, largest


def _boundary_data(settings: dict):
    """The boundary data a binding was made with: "mvc", or its LocalData (bindings that did not record the local
    data's parameters made before they were recorded: the default, with a warning if it said otherwise)."""
    from .geometry.local_data import LocalData

    described = str(settings.get("boundary", ""))
    if described.startswith("mvc"):
        return "mvc"
    if settings.get("boundary_settings"):
        return LocalData(**settings["boundary_settings"])
    if described and described != str(LocalData()):
        warnings.warn(f"the binding's boundary data ({described}) did not record its parameters; the slice uses the "
                      f"default local data ({LocalData()})")
    return "local"


def _grid_slice(settings: dict, cage, handle: int, a: int, position: float, lo, hi, device, harmonic: bool):
    """The handle solved on the binding's grid: (image of the nodes inside the cage on the nearest lattice plane, extent,
    the plane's position)."""
    data = _boundary_data(settings)
    grid = voxelize(cage, int(settings["resolution"]), device=device, boundary=data)
    chunk = slice(handle, handle + 1)
    field = boundary_field(grid, cage, device=device, handles=chunk, complement=True, data=data)
    extra = {"equation": "laplace"} if harmonic else {}
    tol = float(settings.get("tol") or 1e-6)
    report = solve_biharmonic(grid, field, tol=tol, max_iterations=settings.get("max_iterations"),
                              handles=cage.vertices, chunk=chunk, preconditioner=settings.get("solver") or "multigrid",
                              device=device, **extra)
    if not report.converged:
        warnings.warn(f"handle {handle}'s weights did not converge to tol {tol:g} (residual "
                      f"{report.residual:.2e}); the slice shows the last iterate")
    values = field.numpy()[: grid.n_inside, 0, 0].astype(np.float64)
    h = grid.spacing
    nodes = [grid.centre[x] + grid.origin[x] + h * np.arange(grid.shape[x]) for x in range(3)]
    k = int(np.clip(np.rint((position - nodes[a][0]) / h), 0, grid.shape[a] - 1))
    b, c = (x for x in range(3) if x != a)
    # the nodes within a spacing of the cage's bounding box: every interior node, and a pixel of room around them
    kept = [np.flatnonzero((nodes[x] >= lo[x] - 1.001 * h) & (nodes[x] <= hi[x] + 1.001 * h)) for x in (b, c)]
    image = np.full((len(kept[1]), len(kept[0])), np.nan)
    ijk = grid.active_ijk[: grid.n_inside]
    on = ijk[:, a] == k
    image[ijk[on, c] - kept[1][0], ijk[on, b] - kept[0][0]] = values[on]
    extent = (nodes[b][kept[0][0]] - h / 2, nodes[b][kept[0][-1]] + h / 2,
              nodes[c][kept[1][0]] - h / 2, nodes[c][kept[1][-1]] + h / 2)
    return image, tuple(float(e) for e in extent), float(nodes[a][k])


def _mvc_slice(cage, handle: int, a: int, position: float, lo, hi, device, pixels: int):
    """Mean value coordinates at pixel centres over the cage's bounding box, NaN outside the cage."""
    b, c = (x for x in range(3) if x != a)
    step = max(hi[b] - lo[b], hi[c] - lo[c]) / max(int(pixels), 1)
    nu, nv = (max(1, int(round((hi[x] - lo[x]) / step))) for x in (b, c))
    points = np.empty((nv, nu, 3))
    points[..., a] = position
    points[..., b] = (lo[b] + (np.arange(nu) + 0.5) * (hi[b] - lo[b]) / nu)[None, :]
    points[..., c] = (lo[c] + (np.arange(nv) + 0.5) * (hi[c] - lo[c]) / nv)[:, None]
    points = points.reshape(-1, 3)
    inside, _ = classify_points(cage, points, device=device)
    values = np.full(len(points), np.nan)
    values[inside] = mean_value_coordinates(cage, points[inside], device=device)[:, handle]
    return values.reshape(nv, nu), (float(lo[b]), float(hi[b]), float(lo[c]), float(hi[c])), position


def _save(figure, path) -> None:
    import matplotlib.pyplot as plt

    try:
        with atomic_output(path, ".png") as tmp:
            figure.savefig(tmp, format="png")
    finally:
        plt.close(figure)


def show_weights(binding, handle: int, path, axis="z", fraction: float = 0.5, device=None) -> WeightSlice:
    """Draw :func:`weight_slice` to ``path`` (PNG): the weight in a diverging colour map symmetric about 0
    (:func:`symmetric_scale`: negative weights blue, positive red, outside the cage blank), the cage's cross-section
    (black), the mesh's (dashed grey), the handle's position on the plane (a star), a colour bar and a title; axes
    in world units, equal aspect. Written under a temporary name, renamed when complete. Needs matplotlib.

    Parameters
    ----------
    binding : Binding
    handle : int
    path : str | os.PathLike, a .png file
    axis, fraction, device : as for :func:`weight_slice`

    Returns
    -------
    WeightSlice, what was drawn

    Examples
    --------
    >>> show_weights(ws.load_binding("arm.npz"), 5, "weights.png", "z", 0.5)  # doctest: +SKIP
    """
    plt = _pyplot()
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize

    s = weight_slice(binding, handle, axis, fraction, device=device)
    finite = s.image[np.isfinite(s.image)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    norm = Normalize(*symmetric_scale(s.image))
    u, v = (AXES[x] for x in s.plane_axes)
    a = AXES[_axis(axis)]
    grid = f"resolution {s.resolution}" if s.resolution is not None else "no grid"
    with plt.rc_context(_RC):
        figure, axes = plt.subplots(figsize=(6.4, 5.2))
        picture = axes.imshow(np.ma.masked_invalid(s.image), origin="lower", extent=s.extent, cmap="RdBu_r", norm=norm,
                              interpolation="nearest")
        axes.add_collection(LineCollection(s.outline, colors="black", linewidths=1.0, label="cage"))
        if len(s.mesh_outline):
            axes.add_collection(LineCollection(s.mesh_outline, colors="0.35", linewidths=0.6, linestyles="dashed",
                                               label="mesh"))
        axes.plot(s.handle[0], s.handle[1], marker="*", markersize=11, color="gold", markeredgecolor="black",
                  linestyle="none", label=f"handle {handle} ({s.handle[2]:+.3g} off the plane)")
        axes.legend(loc="best", fontsize=7, framealpha=0.8)
        pad = 0.04 * max(s.extent[1] - s.extent[0], s.extent[3] - s.extent[2])
        axes.set_xlim(s.extent[0] - pad, s.extent[1] + pad)
        axes.set_ylim(s.extent[2] - pad, s.extent[3] + pad)
        axes.set_aspect("equal")
        axes.set_xlabel(u)
        axes.set_ylabel(v)
        figure.colorbar(picture, ax=axes, label=f"weight of handle {handle} (scale symmetric about 0)",
                        ticks=np.linspace(norm.vmin, norm.vmax, 9), format="%.3g")
        axes.set_title(f"handle {handle}, {s.method} ({grid})\nslice {a} = {float(fraction):g} of the cage "
                       f"({a} = {s.position:.4g}); weights {low:.3g} to {high:.3g}", fontsize=9)
        figure.tight_layout()
        _save(figure, path)
    return s


def mesh_colours(binding, pose=None, reference=None) -> MeshColours:
    """The bound mesh, deformed by ``pose`` (rest without one), and a value per triangle: its conformal distortion
    (sigma1 / sigma2 of the rest-to-deformed map, 1 = conformal, inf for a collapsed triangle), or with ``reference``
    the mean over its corners of each vertex's distance to the reference mesh, over the rest cage's bounding
    diagonal (to the corresponding vertex for a reference with as many vertices, else to its closest point).

    Parameters
    ----------
    binding : Binding
    pose : what :meth:`Binding.deform` takes for one pose (a deformed cage file, an (L, 3) array), optional
    reference : a mesh (path or what :func:`warp_stokes.load_surface` takes), optional

    Returns
    -------
    MeshColours

    Examples
    --------
    >>> m = mesh_colours(ws.load_binding("arm.npz"), "arm_bent_cage.obj")  # doctest: +SKIP
    >>> float(np.nanmin(m.values)) >= 1                                   # doctest: +SKIP
    True
    """
    faces = binding.mesh_faces
    if len(faces) == 0:
        raise WarpStokesError("the bound mesh has no faces (a point set): there are no triangles to colour; show a "
                              "handle's weight on a slice instead (--handle)")
    vertices = binding.mesh_vertices if pose is None else np.asarray(binding.deform(pose), dtype=np.float64)
    if reference is None:
        return MeshColours(vertices, conformal_distortion(faces, binding.mesh_vertices, vertices),
                           "conformal distortion \u03c3\u2081/\u03c3\u2082 (1 = conformal)")
    surface = load_surface(reference)
    if len(surface.vertices) == len(vertices):
        distance = np.linalg.norm(vertices - surface.vertices, axis=1)
    elif len(surface.faces):  # each vertex's distance to the reference's closest point (Warp's BVH, no rtree)
        from .geometry.cage import Cage

        reference_mesh = Cage(surface.vertices, surface.faces, surface.name)
        distance = classify_points(reference_mesh, vertices, device=binding.device)[1]
    else:
        raise WarpStokesError(f"{surface.name}: a reference with another vertex count ({len(surface.vertices)}, the "
                              f"mesh has {len(vertices)}) needs faces to measure the distance to")
    values = distance[faces].mean(axis=1) / bounding_diagonal(binding.cage_vertices)
    return MeshColours(vertices, values, f"distance to {os.path.basename(surface.name)} / cage diagonal")


def view_frame(view: str = "front", up_axis: str = "Y") -> np.ndarray:
    """The rows (screen right, screen up, towards the viewer) of an orthographic view: ``front`` looks along -z with
    +y up (a Z-up model: along +y with +z up), ``side`` from +x, ``top`` from above.

    Examples
    --------
    >>> view_frame("front", "Z").astype(int).tolist()
    [[1, 0, 0], [0, 0, 1], [0, -1, 0]]
    """
    if view not in _Y_UP_VIEWS:
        raise WarpStokesError(f"view must be one of {', '.join(VIEWS)}, got {view!r}")
    frame = np.array(_Y_UP_VIEWS[view], dtype=np.float64)
    return frame @ np.array(_Z_UP_TO_Y_UP, dtype=np.float64) if str(up_axis).upper() == "Z" else frame


def cage_edges(binding, pose=None, frame=None) -> tuple[np.ndarray, np.ndarray]:
    """The bound cage's edges, posed by ``pose`` (rest without one), as segments in a view: (E, 2, 3) end points in
    ``frame``'s coordinates (:func:`view_frame`; the model's without one) and (E,) whether each edge is on the
    viewer's side (a face at it faces the viewer).

    Examples
    --------
    >>> segments, front = cage_edges(ws.load_binding("arm.npz"), frame=view_frame("front"))  # doctest: +SKIP
    >>> segments.shape                                                                         # doctest: +SKIP
    (168, 2, 3)
    """
    from .io.poses import pose_vertices

    if pose is None:
        positions = binding.cage_vertices
    elif isinstance(pose, (str, os.PathLike)) or type(pose).__name__ == "Trimesh" or isinstance(pose, tuple):
        surface = load_surface(pose)
        positions = pose_vertices(surface.vertices, surface.faces, binding.cage_faces, binding.cage_source_index,
                                  surface.name)
    else:
        positions = np.asarray(pose, dtype=np.float64).reshape(binding.n_handles, 3)
    positions = np.asarray(positions, dtype=np.float64) @ (np.eye(3) if frame is None else frame).T
    faces = np.asarray(binding.cage_faces)
    corners = positions[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    facing = normals[:, 2] > 0
    half = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])  # each edge twice, once per face
    keys = np.minimum(half[:, 0], half[:, 1]) * len(positions) + np.maximum(half[:, 0], half[:, 1])
    keys, which = np.unique(keys, return_inverse=True)
    front = np.zeros(len(keys), dtype=bool)
    np.logical_or.at(front, which, np.tile(facing, 3))
    ends = np.column_stack([keys // len(positions), keys % len(positions)])
    return positions[ends], front


def show_mesh(binding, path, pose=None, reference=None, view: str = "front", title: str | None = None,
              with_cage: bool = False) -> dict:
    """Draw :func:`mesh_colours` to ``path`` (PNG): filled triangles in an orthographic view, back to front, each in
    its value's colour darkened by simple head-light shading, with a colour bar. Conformal distortion runs from 1 to
    its largest finite value (collapsed triangles are clipped to the top), distances from 0 to their largest; NaN
    (a triangle degenerate at rest) is grey. The view takes the asset's up axis (``binding.asset["up_axis"]``).
    ``with_cage`` draws the cage over it (posed with the mesh): its edges on the viewer's side solid, the others
    dashed; with neither ``pose`` nor ``reference`` the rest mesh is then plain grey (it has no distortion to show).
    Needs matplotlib.

    Parameters
    ----------
    binding : Binding
    path : str | os.PathLike, a .png file
    pose, reference : as for :func:`mesh_colours`
    view : "front" | "side" | "top"
    title : str, optional
    with_cage : bool, draw the cage's edges

    Returns
    -------
    dict: ``values`` (per triangle), ``range`` (the colour bar's low and high end; None for a plain mesh),
    ``label``, ``cage_edges`` (drawn; 0 without the cage)

    Examples
    --------
    >>> show_mesh(ws.load_binding("arm.npz"), "deformed.png", pose="arm_bent_cage.obj")  # doctest: +SKIP
    >>> show_mesh(ws.load_binding("arm.npz"), "cage.png", with_cage=True)["cage_edges"]   # doctest: +SKIP
    168
    """
    plt = _pyplot()
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import Normalize

    from matplotlib.collections import LineCollection

    frame = view_frame(view, (binding.asset or {}).get("up_axis", "Y"))
    m = mesh_colours(binding, pose, reference)
    plain = with_cage and pose is None and reference is None
    finite = m.values[np.isfinite(m.values)]
    low = 0.0 if reference is not None else 1.0
    high = float(finite.max()) if finite.size else low
    high = max(high, low + 1e-6 * max(abs(low), 1.0))
    norm, cmap = Normalize(low, high, clip=True), colormaps["viridis"]
    triangles = (m.vertices @ frame.T)[binding.mesh_faces]  # (F, 3 corners, [right, up, towards the viewer])
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(normals, axis=1)
    facing = np.abs(normals[:, 2]) / np.where(length > 0, length, 1.0)
    colours = cmap(norm(np.where(np.isnan(m.values), low, m.values)))
    colours[:, :3] *= (0.6 + 0.4 * np.where(length > 0, facing, 1.0))[:, None]
    colours[np.isnan(m.values)] = (0.7, 0.7, 0.7, 1.0)
    if plain:
        colours[:] = (0.78, 0.78, 0.78, 1.0)
        colours[:, :3] *= (0.55 + 0.45 * np.where(length > 0, facing, 1.0))[:, None]
    order = np.argsort(triangles[:, :, 2].mean(axis=1), kind="stable")  # the farthest first
    with plt.rc_context(_RC):
        figure, axes = plt.subplots(figsize=(6.4, 6.0))
        axes.add_collection(PolyCollection(triangles[order, :, :2], facecolors=colours[order], edgecolors="face",
                                           linewidths=0.2))
        corners = triangles[..., :2].reshape(-1, 2)
        edges = 0
        if with_cage:
            segments, front = cage_edges(binding, pose, frame)
            edges = len(segments)
            axes.add_collection(LineCollection(segments[~front, :, :2], colors="#1f3b73", linewidths=0.6,
                                               linestyles=(0, (3, 3)), alpha=0.45))
            axes.add_collection(LineCollection(segments[front, :, :2], colors="#1f3b73", linewidths=0.9))
            corners = np.concatenate([corners, segments[..., :2].reshape(-1, 2)])
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        pad = 0.04 * float((hi - lo).max())
        axes.set_xlim(lo[0] - pad, hi[0] + pad)
        axes.set_ylim(lo[1] - pad, hi[1] + pad)
        axes.set_aspect("equal")
        axes.set_axis_off()
        shape = "rest" if pose is None else "deformed"
        if plain:
            label = f"the mesh ({len(binding.mesh_vertices)} vertices) in its cage ({binding.n_handles} handles)"
            axes.set_title(title or f"{label}, {view} view", fontsize=9)
        else:
            clipped = bool(np.isinf(m.values).any())
            figure.colorbar(ScalarMappable(norm, cmap), ax=axes, label=m.label,
                            extend="max" if clipped else "neither", shrink=0.8)
            label = m.label
            axes.set_title(title or f"{m.label.split(' (')[0]} of the {shape} mesh, {view} view", fontsize=9)
        figure.tight_layout()
        _save(figure, path)
    return {"values": m.values, "range": None if plain else (low, high), "label": label, "cage_edges": edges}
