"""Making a cage for a mesh that has none: the mesh's offset surface, simplified to the handles asked for while it
stays a valid cage that keeps every vertex of the mesh inside.

1. The mesh's signed distance on a voxel grid (Warp, on the device): the distance to the nearest face, negative
   where the generalised winding number exceeds 1/2, so open, self-intersecting and many-piece meshes have an inside;
   vertices on no face count by their distance, so that they are enclosed as well.
2. Its level set at ``offset`` by marching cubes (Warp): a closed surface around the mesh at that distance; cavities
   inside it are dropped.
3. Quadric edge collapses down to the handles asked for, each one checked before it is made
   (:func:`~warp_stokes.geometry.simplify.simplify_enclosing`): the surface stays closed, manifold, free of crossings
   and sharp folds, and every mesh vertex stays inside, at least ``margin`` from it.
4. The result goes through the same checks as any cage (:func:`~warp_stokes.geometry.cage.check_cage`) and the
   package's inside test (:func:`~warp_stokes.geometry.inside.classify_points`) over all of the mesh's vertices.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np
import warp as wp

from ..device import Backend
from ..errors import CageError, MeshError
from ..io.scene import load_scene
from ..kernels import cage as cage_kernels
from .cage import Cage, check_cage, signed_volume
from .inside import WINDING_ACCURACY, classify_points
from .simplify import simplify_enclosing
from .topology import bounding_diagonal

__all__ = ["make_cage", "MadeCage", "default_handles", "made_cage_record", "DEFAULT_OFFSET"]

#: the offset surface's distance from the mesh, as a fraction of the mesh's bounding diagonal
DEFAULT_OFFSET = 0.02
#: the default offset's steps (times DEFAULT_OFFSET) where the handles asked are not reached: at the default offset
#: the collapses on most unseen meshes stop well above a count of a few dozen handles; with the steps nearly every
#: one reaches about the count, and a very coarse cage needs the largest steps (room around limbs and ears)
#: (measured: benchmarks/RESULTS.md)
OFFSET_STEPS = (1.0, 2.0, 4.0, 8.0)
#: every mesh vertex stays at least this fraction of the offset inside the cage
#: (a margin of a quarter of the offset or more leaves the collapses less room, and the cages then expressed their
#: artists' deformations worse; and the offset surface that starts the collapses holds every vertex at a smaller
#: margin more often)
MARGIN = 0.15
#: grid cells per offset: marching cubes places the level set well within a cell of the offset, so one cell per
#: offset keeps every vertex at the margin (checked); finer grids start the collapses from more vertices (1.5 cells:
#: 2.3 times the vertices and twice the time, the same quality on the shared pairs and the synthetic shapes)
CELLS_PER_OFFSET = 1.0
#: the grid's largest side, in cells (an offset smaller than such a grid resolves is raised to it, with a note)
MAX_CELLS = 128
#: field values this close to the level (in cells) are moved off it: marching cubes then makes no slivers
SNAP = 0.15


@dataclass(frozen=True)
class MadeCage:
    """A cage made for a mesh, and how it was made.

    Attributes
    ----------
    cage : Cage, checked (closed, outward, manifold, not crossing itself)
    handles : int, the handles asked for (or chosen: see ``chosen``)
    chosen : bool, whether ``handles`` was chosen from the mesh's shape (no count given)
    offset : float, the offset surface's distance from the mesh (absolute)
    margin : float, the least distance kept between a mesh vertex and the cage (absolute)
    grid : (3,) int, the voxel grid's nodes per axis
    distance : (mean, max) distance from the mesh's vertices to the cage, over the mesh's bounding diagonal
    seconds : dict, wall time per stage (``field``, ``surface``, ``simplify``, ``check``)
    notes : list of str
    """

    cage: Cage
    handles: int
    chosen: bool
    offset: float
    margin: float
    grid: tuple
    distance: tuple
    seconds: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def summary(self) -> str:
        """One line: handles, faces, tightness and time."""
        asked = f"chosen from the mesh's shape: {self.handles}" if self.chosen else f"asked {self.handles}"
        return (f"cage of {self.cage.n_handles} handles ({asked}), {len(self.cage.faces)} faces; encloses every "
                f"vertex; distance from the mesh mean {self.distance[0]:.2%}, max {self.distance[1]:.2%} of the "
                f"diagonal; made in {sum(self.seconds.values()):.2f} s")


def default_handles(area: float, volume: float) -> int:
    """Handles for a cage from its offset surface's area and volume: more for shapes with limbs (area large for
    their volume: a ball needs few), between 32 and 400.

    Examples
    --------
    >>> default_handles(4 * np.pi, 4 * np.pi / 3)   # a ball
    68
    """
    roundness = area / max(volume, 1e-300) ** (2.0 / 3.0)  # 4.84 for a ball, larger for limbs and plates
    return int(np.clip(round(14.0 * roundness), 32, 400))


def _components(faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) a label per vertex, equal within each edge-connected component (min-label spreading, pointer jumping)."""
    label = np.arange(n)
    u = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    v = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    while True:
        m = np.minimum(label[u], label[v])
        new = label.copy()
        np.minimum.at(new, u, m)
        np.minimum.at(new, v, m)
        new = new[new]
        if (new == label).all():
            return label
        label = new


def _outer_shells(v: np.ndarray, f: np.ndarray, device) -> np.ndarray:
    """The faces of the surface's components that bound the solid from outside: cavities (inward, negative
    volume) and pieces inside another piece (a vertex of it inside, by the package's inside test) are dropped."""
    label = _components(f, len(v))[f[:, 0]]
    shells = [np.flatnonzero(label == k) for k in np.unique(label)]
    shells = [s for s in shells if signed_volume(v, f[s]) > 0]
    firsts = v[[f[s[0], 0] for s in shells]]
    enclosed = np.zeros(len(shells), dtype=bool)
    for j, s in enumerate(shells if len(shells) > 1 else []):
        inside, _ = classify_points(Cage(vertices=v, faces=f[s], name="a shell"), firsts, device=device)
        inside[j] = False
        enclosed |= inside
    kept = [s for s, inner in zip(shells, enclosed) if not inner]
    return f[np.concatenate(kept)] if kept else f[:0]


def _marching_cubes(field, spacing: float, origin: np.ndarray):
    """(vertices, faces) of the zero level set of a Warp 3D array (Warp's marching cubes, on the array's device)."""
    shape = np.array(field.shape)
    lower = wp.vec3(*origin.astype(np.float32))
    upper = wp.vec3(*(origin + spacing * (shape - 1)).astype(np.float32))
    try:
        from warp.geometry import IsoSurfaceMarchingCubes
    except ImportError:  # Warp 1.9-1.17: the same marching cubes (CPU and CUDA since 1.9) under its former name
        verts, tris = wp.MarchingCubes.extract_surface_marching_cubes(
            field, threshold=0.0, domain_bounds_lower_corner=lower, domain_bounds_upper_corner=upper)
    else:
        verts, tris = IsoSurfaceMarchingCubes.extract(field, threshold=0.0, lower=lower, upper=upper)
    return verts.numpy().astype(np.float64), tris.numpy().reshape(-1, 3).astype(np.int64)


def make_cage(mesh, handles: int | None = None, offset: float | None = None, device=None,
              mesh_prims=None) -> MadeCage:
    """Make a cage for a mesh: closed, outward, manifold, not crossing itself, every vertex of the mesh inside.

    Parameters
    ----------
    mesh : path | trimesh.Trimesh | (vertices, faces) | Surface
        Anything ``bind`` reads as a mesh: OBJ/PLY/STL/OFF/glTF files, USD assets (all their meshes, in world
        space). Open, self-intersecting and many-piece meshes are fine, and vertices on no face are enclosed too;
        it needs faces (not a point set).
    handles : int, optional
        The cage's vertex count (at least 8). Default: chosen from the shape (:func:`default_handles`), at most
        the mesh's vertex count (and at least 8). Where no further collapse keeps the cage valid it stops above the
        count, with a note.
    offset : float, optional
        How far the cage starts from the mesh, as a fraction of its bounding diagonal. Larger offsets leave the
        simplification more room (fewer handles possible, smoother cages); smaller ones fit tighter. Default:
        0.02, doubled (up to three times) where the cage would stop well above the handles asked, with a note (a try
        with a larger offset still to come gives up early where its valid collapses have grown too rare to reach the
        count); an offset given is kept.
    device : None | str
        The Warp device of the voxel work and the final inside test (default: CUDA when present, else the CPU);
        the collapses are checked on the CPU.
    mesh_prims : list of str, optional
        For a USD asset, the mesh prims to enclose (default: all its meshes; name them to leave a cage prim out).

    Returns
    -------
    MadeCage

    Raises
    ------
    MeshError
        When the mesh cannot be read, has no faces or no extent.
    CageError
        For a handle count below 8 or an offset outside (0, 0.5], and where the offset surface does not hold every
        vertex at the margin (a mesh finer than the grid resolves: a larger offset does).

    Examples
    --------
    >>> import trimesh
    >>> sphere = trimesh.creation.icosphere(subdivisions=3)
    >>> made = make_cage((sphere.vertices, sphere.faces), handles=60, device="cpu")
    >>> made.cage.n_handles, made.distance[1] < 0.03
    (60, True)
    """
    _check_request(handles, offset)
    surface = load_scene(mesh, mesh_prims=mesh_prims, looks=False).surface()
    name = surface.name
    points, faces, stray, diag = _surface_to_enclose(surface)
    device = Backend.of(device).device
    # the default offset is raised where the cage cannot reach the handles asked: a cage of about the count asked
    # matters more to the user than one that hugs the mesh (an offset given is kept, with a note if it stops short)
    fractions = [offset] if offset is not None else [DEFAULT_OFFSET * factor for factor in OFFSET_STEPS]
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    t = time.perf_counter()
    body, strays = _mesh_on_device(surface, faces, stray, centre, device)
    seconds = {"field": time.perf_counter() - t}
    made_at = partial(_made_at, body, strays, centre, points, name, diag, device=device)
    tries, k, first_gave_up, handles = _tightest(made_at, fractions, handles, seconds)
    best = tries[k]
    notes = list(best.notes)
    if k > 0:
        stopped = "the collapses had all but stopped at" if first_gave_up else "the cage stopped at"
        notes.insert(0, f"{name}: at an offset of {fractions[0]:g} of the diagonal {stopped} "
                        f"{tries[0].cage.n_handles} handles (asked {handles}); it was made at {fractions[k]:g} "
                        "instead, which leaves the collapses more room")
    return replace(best, chosen=tries[0].chosen, seconds=seconds, notes=notes)


def _check_request(handles, offset) -> None:
    """Refuse (:class:`CageError`) a handle count below 8 or an offset outside (0, 0.5]."""
    if handles is not None and (int(handles) != handles or handles < 8):
        raise CageError(f"handles: a made cage needs at least 8 handles, got {handles}")
    if offset is not None and not (np.isfinite(offset) and 0 < offset <= 0.5):
        raise CageError(f"offset: a fraction of the mesh's diagonal in (0, 0.5], got {offset}")


def _surface_to_enclose(surface):
    """The mesh's vertices (float64), faces (int64), vertices on no face, and bounding diagonal; refused
    (:class:`MeshError`) without faces of some area, or with non-finite or coincident vertices."""
    name = surface.name
    points = np.asarray(surface.vertices, dtype=np.float64)
    faces = np.asarray(surface.faces, dtype=np.int64)
    if len(faces) == 0:
        raise MeshError(f"{name}: a cage is made around a surface, and it has no faces")
    if not np.isfinite(points).all():
        raise MeshError(f"{name}: non-finite vertex coordinates")
    # vertices on no face (stray points of a scan or an export) are enclosed too, each in a ball of the offset's
    # radius: a cage must hold every vertex a binding samples
    on_faces = np.zeros(len(points), dtype=bool)
    on_faces[np.unique(faces)] = True
    stray = points[~on_faces]
    diag = bounding_diagonal(points)
    if not diag > 0:
        raise MeshError(f"{name}: all vertices coincide")
    corner = points[faces]
    areas = np.linalg.norm(np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0]), axis=1)
    if not (areas > 1e-12 * diag ** 2).any():  # a distance field needs a surface: lines have no inside or outside
        raise MeshError(f"{name}: every face has zero area (its vertices lie on lines); a cage is made around a "
                        "surface")
    return points, faces, stray, diag


def _mesh_on_device(surface, faces, stray, centre, device):
    """The mesh's BVH (with winding numbers) and its stray vertices' (positions, BVH), or None, on ``device``,
    relative to ``centre``: built once for every offset tried."""
    with wp.ScopedDevice(device):
        body = wp.Mesh(points=wp.array((surface.vertices - centre).astype(np.float32), dtype=wp.vec3),
                       indices=wp.array(faces.astype(np.int32).ravel(), dtype=wp.int32), support_winding_number=True)
        strays = None
        if len(stray):
            rel = wp.array((stray - centre).astype(np.float32), dtype=wp.vec3)
            strays = (rel, wp.Bvh(rel, rel))
    return body, strays


def _tightest(made_at, fractions, handles, seconds):
    """The cages made by ``made_at(fraction, handles, last)`` (:func:`_made_at`) at the offsets ``fractions`` in
    turn, up to the first that comes down to about the handles asked. Returns (the cages, the index of the first
    with the fewest handles: the tightest, whether the first gave up, the handles asked: where none were given, those
    chosen from the first offset surface, which hold for the larger offsets); ``seconds`` sums their stages' times."""
    tries, gave_up_early = [], []

    def attempt(fraction, last):
        made, gave_up = made_at(fraction, handles, last=last)
        for stage, spent in made.seconds.items():
            seconds[stage] = seconds.get(stage, 0.0) + spent
        return made, gave_up

    for j, fraction in enumerate(fractions):
        made, gave_up = attempt(fraction, last=j == len(fractions) - 1)
        handles = made.handles
        tries.append(made)
        gave_up_early.append(gave_up)
        if made.cage.n_handles <= _about(made.handles):
            break
    k = min(range(len(tries)), key=lambda j: tries[j].cage.n_handles)
    if gave_up_early[k]:  # every larger offset stopped higher than this one gave up at: this one is finished after all
        tries[k], _ = attempt(fractions[k], last=True)
    return tries, k, gave_up_early[0], handles


def _about(handles: int) -> int:
    """The most handles that are still "about" the count asked: within 5 % and one handle.

    Examples
    --------
    >>> _about(30), _about(118)
    (31, 123)
    """
    return handles + max(1, int(0.05 * handles))


def _made_at(body: wp.Mesh, strays, centre, points, name, diag, fraction, handles, device,
             last=True) -> tuple[MadeCage, bool]:
    """The cage made at an offset of ``fraction`` of the diagonal (see :func:`make_cage`), and whether its collapses
    gave up: ``body`` the mesh and ``strays`` (positions, BVH) its vertices on no face, or None, both on ``device``
    relative to ``centre``. Unless it is the ``last`` offset to try, the collapses give up where they could not
    reach about the count soon."""
    seconds, notes = {}, []
    distance = fraction * diag
    lo, hi = points.min(axis=0), points.max(axis=0)
    spacing = distance / CELLS_PER_OFFSET
    if (hi - lo).max() / spacing > MAX_CELLS:  # the grid would be too fine: its cells set the offset instead
        spacing = (hi - lo).max() / MAX_CELLS
        distance = CELLS_PER_OFFSET * spacing
        notes.append(f"{name}: an offset of {fraction:g} of the diagonal needs a grid finer than {MAX_CELLS} cells; "
                     f"the offset is {distance / diag:.3g} of the diagonal")
    pad = distance + 2.0 * spacing
    origin = lo - pad
    shape = tuple(int(s) for s in np.ceil((hi - lo + 2.0 * pad) / spacing).astype(int) + 1)
    t = time.perf_counter()
    with wp.ScopedDevice(device):
        field_d = wp.empty(shape, dtype=float)
        corner = wp.vec3(*(origin - centre).astype(np.float32))
        # beyond the offset and two cells only the side matters: the level set and its neighbours lie within it
        signed_distance_field(body, corner, spacing, distance + 2.0 * spacing, field_d, device)
        if strays is not None:
            rel, stray_bvh = strays
            wp.launch(cage_kernels.distance_to_points, dim=shape,
                      inputs=[stray_bvh.id, rel, corner, float(spacing), float(distance + 2.0 * spacing)],
                      outputs=[field_d])
        level = field_d.numpy() - distance
        snap = SNAP * spacing
        near = np.abs(level) < snap
        level[near] = np.where(level[near] < 0, -snap, snap)
        seconds["field"] = time.perf_counter() - t
        t = time.perf_counter()
        v, f = _marching_cubes(wp.array(level, dtype=float), spacing, origin - centre)
    v += centre
    f = _outer_shells(v, f, device)
    if len(f) == 0:  # nothing at the offset: the grid saw no surface (never for a mesh with faces of some area)
        raise MeshError(f"{name}: no surface at the offset around the mesh")
    seconds["surface"] = time.perf_counter() - t
    if handles is None:
        # never more handles than the mesh has vertices (a tetrahedron's rounded offset surface asked for 97)
        handles = min(default_handles(_area(v, f), signed_volume(v, f)), max(8, len(points)))
        chosen = True
    else:
        handles, chosen = int(handles), False
    t = time.perf_counter()
    margin = MARGIN * distance
    _check_start(v, f, points, margin, name, device)
    # the collapse checks run on the CPU whatever the device: a round holds a few hundred candidates, too few for a
    # GPU, whose copies and launches per round then cost more than the checks (on CUDA a make took over twice as long)
    simplified = simplify_enclosing(v, f, handles, points, margin, device="cpu",
                                    give_up_above=None if last else _about(handles))
    seconds["simplify"] = time.perf_counter() - t
    t = time.perf_counter()
    cage = check_cage((simplified.vertices, simplified.faces), name=f"cage of {name}")
    inside, gap = classify_points(cage, points, device=device)
    seconds["check"] = time.perf_counter() - t
    if not inside.all():  # the collapses keep every vertex inside: this would be a bug, never a cage to return
        raise CageError(f"{name}: the made cage leaves {int((~inside).sum())} vertex(es) outside")
    if cage.n_handles < handles:  # nothing to collapse: the surface is coarser than the count asked
        notes.append(f"{name}: {cage.n_handles} handles (asked {handles}): the offset surface has no more vertices; "
                     "a smaller offset makes a finer one")
    if cage.n_handles > handles:
        refused = ", ".join(f"{why} {count}" for why, count in sorted(simplified.refusals.items(), key=lambda x: -x[1]))
        notes.append(f"{name}: stopped at {cage.n_handles} handles (asked {handles}): no further collapse keeps the "
                     f"cage valid with every vertex inside (collapses refused: {refused}); a larger offset leaves more "
                     "room")
    return MadeCage(cage=cage, handles=handles, chosen=chosen, offset=distance, margin=margin, grid=shape,
                    distance=(float(gap.mean() / diag), float(gap.max() / diag)), seconds=seconds,
                    notes=notes + list(cage.notes)), simplified.gave_up


def signed_distance_field(body: wp.Mesh, corner: wp.vec3, spacing: float, cap: float, field: wp.array,
                          device) -> None:
    """``field`` (a 3D array) = the signed distance to ``body`` at the nodes ``corner + spacing (i, j, k)``, negative
    inside (winding number > 1/2), exact where it is within ``cap`` (at least two spacings) of the mesh or beside a
    node of the other side, and of the right sign elsewhere. On a CPU winding numbers only at the nodes of even
    coordinates and where the mesh passes near (``kernels.cage.signed_distance_between_even_nodes``); a GPU takes
    every node's."""
    shape = field.shape
    if device.is_cuda:
        wp.launch(cage_kernels.signed_distance, dim=shape,
                  inputs=[body.id, corner, float(spacing), WINDING_ACCURACY, 1], outputs=[field], device=device)
        return
    even = tuple((s + 1) // 2 for s in shape)
    wp.launch(cage_kernels.signed_distance, dim=even, inputs=[body.id, corner, float(spacing), WINDING_ACCURACY, 2],
              outputs=[field], device=device)
    cap = float(max(cap, 2.0 * spacing))
    wp.launch(cage_kernels.signed_distance_between_even_nodes, dim=shape,
              inputs=[body.id, corner, float(spacing), WINDING_ACCURACY, cap], outputs=[field], device=device)
    wp.launch(cage_kernels.uncap_at_side_changes, dim=shape,
              inputs=[body.id, corner, float(spacing), float(np.float32(cap))], outputs=[field], device=device)


def _check_start(v, f, points, margin, name, device) -> None:
    """The simplification keeps every vertex inside at the margin, so the offset surface it starts from must:
    marching cubes places the surface within a cell of the offset, which is a cell (:data:`CELLS_PER_OFFSET`)."""
    start = Cage(vertices=v, faces=f, name="the offset surface")  # closed and outward by construction
    inside, gap = classify_points(start, points, device=device)
    if not (inside.all() and gap.min() >= margin):
        raise CageError(f"{name}: the offset surface leaves {int((~inside).sum())} vertex(es) outside or within "
                        f"{margin:.3g} of it; a larger --offset resolves the mesh")


def _area(v: np.ndarray, f: np.ndarray) -> float:
    return float(0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())


def made_cage_record(made: MadeCage) -> dict:
    """What a binding records of a cage made for it (``stats.made_cage``): plain numbers and strings.

    Examples
    --------
    >>> import trimesh
    >>> sphere = trimesh.creation.icosphere(subdivisions=2)
    >>> sorted(made_cage_record(make_cage((sphere.vertices, sphere.faces), handles=60, device="cpu")))
    ['chosen', 'distance_max', 'distance_mean', 'handles', 'handles_asked', 'margin', 'notes', 'offset', 'seconds']
    """
    return {"handles": made.cage.n_handles, "handles_asked": made.handles, "chosen": made.chosen,
            "offset": made.offset, "margin": made.margin, "distance_mean": made.distance[0],
            "distance_max": made.distance[1], "seconds": dict(made.seconds), "notes": list(made.notes)}
