"""A handle's weight on an axis-aligned slice through the cage (:func:`weight_slice`), drawn by :func:`show_weights`.

A binding keeps the weights at the mesh's vertices only, so a slice solves the one handle again on the binding's
grid (its resolution, tolerance, solver, boundary data and equation), which on a CPU gives the same numbers every
time. Mean value coordinates have no grid: they are evaluated at the centres of a lattice of pixels over the cage's
bounding box.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np

from ..device import Backend
from ..errors import WarpStokesError
from ..geometry.boundary import boundary_field
from ..geometry.cage import check_cage
from ..geometry.grid import voxelize
from ..geometry.inside import classify_points
from ..geometry.mean_value import mean_value_coordinates
from ..solver.solve import solve_biharmonic
from .common import AXES, RC, axis_index, binding_method, cross_section, pyplot, save_picture

__all__ = ["WeightSlice", "weight_slice", "symmetric_scale", "show_weights"]


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
    a = axis_index(axis)
    if not 0.0 <= float(fraction) <= 1.0:
        raise WarpStokesError(f"the slice's fraction must be in [0, 1], got {fraction!r}")
    method = binding_method(binding)
    if method not in ("stokes", "harmonic", "mvc"):
        raise WarpStokesError(f"the binding's method {method!r} is not stokes, harmonic or mvc")
    with warnings.catch_warnings():  # the cage was checked, and its notes shown, when it was bound
        warnings.simplefilter("ignore")
        cage = check_cage((binding.cage_vertices, binding.cage_faces), name="the bound cage")
    device = Backend.of(device)
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
    from ..geometry.local_data import LocalData

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
    plt = pyplot()
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize

    s = weight_slice(binding, handle, axis, fraction, device=device)
    finite = s.image[np.isfinite(s.image)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    norm = Normalize(*symmetric_scale(s.image))
    u, v = (AXES[x] for x in s.plane_axes)
    a = AXES[axis_index(axis)]
    grid = f"resolution {s.resolution}" if s.resolution is not None else "no grid"
    with plt.rc_context(RC):
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
        save_picture(figure, path)
    return s


