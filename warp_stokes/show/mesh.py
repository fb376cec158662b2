"""The bound mesh, deformed by a cage pose, coloured per triangle by conformal distortion or by its distance to a
reference mesh (:func:`mesh_colours`), drawn by :func:`show_mesh` with the cage over it where asked: the paper's
encoding-error maps."""

from __future__ import annotations

import os
from typing import NamedTuple

import numpy as np

from ..errors import WarpStokesError
from ..geometry.inside import classify_points
from ..geometry.topology import bounding_diagonal
from ..io.load import load_surface
from ..quality import conformal_distortion
from .common import RC, pyplot, save_picture

__all__ = ["MeshColours", "mesh_colours", "view_frame", "cage_edges", "show_mesh", "VIEWS"]

VIEWS = ("front", "side", "top")
#: per view, the rows (screen right, screen up, towards the viewer) for a Y-up model: front looks along -z
_Y_UP_VIEWS = {"front": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
               "side": ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
               "top": ((1, 0, 0), (0, 0, -1), (0, 1, 0))}
#: a Z-up model in the Y-up frame: (x, y, z) -> (x, z, -y), so that front looks along +y with +z up
_Z_UP_TO_Y_UP = ((1, 0, 0), (0, 0, 1), (0, -1, 0))


class MeshColours(NamedTuple):
    """The bound mesh as drawn by :func:`show_mesh`: vertices (V, 3), one value per triangle (F,), and what the
    values are (the colour bar's label)."""

    vertices: np.ndarray
    values: np.ndarray
    label: str


#: the colour scale of a mesh's distortion or error ends at this percentile of its triangles' values
COLOUR_PERCENTILE = 99


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
        from ..geometry.cage import Cage

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
    from ..io.poses import pose_vertices

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
    dict: ``values`` (per triangle), ``range`` (the colour bar's low and high end, the high one the
    :data:`COLOUR_PERCENTILE` th percentile of the values; None for a plain mesh), ``max`` (the largest finite value),
    ``label``, ``cage_edges`` (drawn; 0 without the cage)

    Examples
    --------
    >>> show_mesh(ws.load_binding("arm.npz"), "deformed.png", pose="arm_bent_cage.obj")  # doctest: +SKIP
    >>> show_mesh(ws.load_binding("arm.npz"), "cage.png", with_cage=True)["cage_edges"]   # doctest: +SKIP
    168
    """
    plt = pyplot()
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import Normalize

    frame = view_frame(view, (binding.asset or {}).get("up_axis", "Y"))
    m = mesh_colours(binding, pose, reference)
    plain = with_cage and pose is None and reference is None
    finite = m.values[np.isfinite(m.values)]
    low = 0.0 if reference is not None else 1.0
    # a few extreme triangles (slivers, a pinched pose) would paint the rest one colour: the scale ends at a
    # percentile, the colour bar says values go beyond it, and the maximum is returned (the CLI prints it)
    largest = float(finite.max()) if finite.size else low
    high = float(np.percentile(finite, COLOUR_PERCENTILE)) if finite.size else low
    high = max(high, low + 1e-6 * max(abs(low), 1.0))
    norm, cmap = Normalize(low, high, clip=True), colormaps["viridis"]
    triangles = (m.vertices @ frame.T)[binding.mesh_faces]  # (F, 3 corners, [right, up, towards the viewer])
    colours = _shaded_colours(triangles, m.values, cmap, norm, low, plain)
    order = np.argsort(triangles[:, :, 2].mean(axis=1), kind="stable")  # the farthest first
    with plt.rc_context(RC):
        figure, axes = plt.subplots(figsize=(6.4, 6.0))
        axes.add_collection(PolyCollection(triangles[order, :, :2], facecolors=colours[order], edgecolors="face",
                                           linewidths=0.2))
        corners = triangles[..., :2].reshape(-1, 2)
        edges = 0
        if with_cage:
            segments = _draw_cage(axes, binding, pose, frame)
            edges = len(segments)
            corners = np.concatenate([corners, segments[..., :2].reshape(-1, 2)])
        _fit_view(axes, corners)
        shape = "rest" if pose is None else "deformed"
        if plain:
            label = f"the mesh ({len(binding.mesh_vertices)} vertices) in its cage ({binding.n_handles} handles)"
            axes.set_title(title or f"{label}, {view} view", fontsize=9)
        else:
            clipped = bool(np.isinf(m.values).any()) or largest > high
            figure.colorbar(ScalarMappable(norm, cmap), ax=axes, label=m.label,
                            extend="max" if clipped else "neither", shrink=0.8)
            label = m.label
            axes.set_title(title or f"{m.label.split(' (')[0]} of the {shape} mesh, {view} view", fontsize=9)
        figure.tight_layout()
        save_picture(figure, path)
    return {"values": m.values, "range": None if plain else (low, high), "max": None if plain else largest,
            "label": label, "cage_edges": edges}


def _shaded_colours(triangles: np.ndarray, values: np.ndarray, cmap, norm, low: float, plain: bool) -> np.ndarray:
    """(F, 4) RGBA per triangle (in view coordinates): its value's colour, darkened where it is seen at a slant (a
    head light), grey for NaN; a ``plain`` mesh all light grey, shaded more."""
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(normals, axis=1)
    facing = np.abs(normals[:, 2]) / np.where(length > 0, length, 1.0)
    colours = cmap(norm(np.where(np.isnan(values), low, values)))
    colours[:, :3] *= (0.6 + 0.4 * np.where(length > 0, facing, 1.0))[:, None]
    colours[np.isnan(values)] = (0.7, 0.7, 0.7, 1.0)
    if plain:
        colours[:] = (0.78, 0.78, 0.78, 1.0)
        colours[:, :3] *= (0.55 + 0.45 * np.where(length > 0, facing, 1.0))[:, None]
    return colours


def _draw_cage(axes, binding, pose, frame: np.ndarray) -> np.ndarray:
    """Draw the cage's edges (:func:`cage_edges`): those on the viewer's side solid, the others dashed and faint.
    Returns their segments (E, 2, 3) in the view."""
    from matplotlib.collections import LineCollection

    segments, front = cage_edges(binding, pose, frame)
    axes.add_collection(LineCollection(segments[~front, :, :2], colors="#1f3b73", linewidths=0.6,
                                       linestyles=(0, (3, 3)), alpha=0.45))
    axes.add_collection(LineCollection(segments[front, :, :2], colors="#1f3b73", linewidths=0.9))
    return segments


def _fit_view(axes, corners: np.ndarray) -> None:
    """Axes that show the points ``corners`` (N, 2) with a margin, at equal scale, without axis lines."""
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    pad = 0.04 * float((hi - lo).max())
    axes.set_xlim(lo[0] - pad, hi[0] + pad)
    axes.set_ylim(lo[1] - pad, hi[1] + pad)
    axes.set_aspect("equal")
    axes.set_axis_off()
