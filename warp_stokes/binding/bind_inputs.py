"""What a bind binds, loaded and checked (:func:`load_inputs`): a cage made for the mesh where asked, the mesh's scene,
the cage checked (with a hint where mesh and cage seem swapped), and which vertices lie inside it; a mesh mostly
outside its cage refused before any solve. The record of them makes the :class:`Binding`."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from ..device import Backend
from ..errors import CageError, MeshError
from ..geometry.cage import Cage, check_cage
from ..geometry.inside import classify_points
from ..geometry.cage_making import MadeCage, made_cage_record, make_cage
from ..io.load import Surface, load_surface
from ..io.parts import Scene
from ..io.scene import is_usd, load_scene
from .stats import asset_record, parts_record
from .store import Binding

__all__ = ["Inputs", "load_inputs", "ON_THE_CAGE"]

#: a vertex this close to the cage (a fraction of its diagonal: float32 rounding of the distance, many times over) is
#: on it
ON_THE_CAGE = 1e-5


@dataclass
class Inputs:
    """What a bind binds, loaded and checked: the mesh's scene and its surface, the checked cage (and the cage made
    for it, when one was), which vertices lie inside the cage and how far from it, and the files read."""

    scene: Scene
    surface: Surface
    cage: Cage
    made: MadeCage | None
    inside: np.ndarray
    distance: np.ndarray
    sources: list

    def binding(self, weights: np.ndarray, settings: dict, stats, backend: Backend) -> Binding:
        """The Binding of ``weights`` at the vertices, with what it records of its inputs."""
        if self.made is not None:
            stats.made_cage = made_cage_record(self.made)
        surface, cage = self.surface, self.cage
        return Binding(weights, cage.vertices, cage.faces, surface.vertices, surface.faces, settings, stats,
                       device=backend, mesh_normals=surface.normals, cage_source_index=cage.source_index,
                       mesh_polygons=surface.polygons(), mesh_uvs=surface.uvs, parts=parts_record(self.scene),
                       asset=asset_record(self.scene), sources=self.sources, looks=surface.looks,
                       mesh_face_materials=surface.face_materials)


def load_inputs(mesh, cage, cage_prim, mesh_prims, rest_time, backend: Backend, seconds: dict) -> Inputs:
    """The first stage of a bind: a cage made for the mesh where asked ("auto" or a MadeCage), the mesh's scene
    (the cage's prim left out when it is one of the mesh's stage), the cage checked, and the vertices classified;
    a mesh mostly outside its cage refused. ``seconds`` gets "cage" and "load"."""
    t = time.perf_counter()
    cage_argument = cage
    made = None
    if isinstance(cage, MadeCage) or (isinstance(cage, str) and cage == "auto"):
        if cage_prim is not None:
            raise CageError(f"cage 'auto' and a cage prim ({cage_prim}): give one of them")
        if isinstance(cage, str):
            cage = make_cage(load_scene(mesh, mesh_prims=mesh_prims, rest_time=rest_time, looks=False).surface(),
                             device=backend)
        made = cage
        cage = made.cage
        seconds["cage"] = sum(made.seconds.values())
        t = time.perf_counter()
    cage = _cage_source(mesh, cage, cage_prim, rest_time)
    # the cage's prim is left out of the meshes (and sets the rest time) when it is a prim of the mesh's stage
    in_stage = bool(cage_prim) and is_usd(mesh) and (
        cage_argument is None or not isinstance(cage_argument, (str, os.PathLike))
        or os.path.abspath(os.fspath(cage_argument)) == os.path.abspath(os.fspath(mesh)))
    scene = load_scene(mesh, mesh_prims=mesh_prims, cage_prim=cage_prim if in_stage else None, rest_time=rest_time)
    surface = scene.surface()
    try:
        checked: Cage = check_cage(cage)
    except CageError as error:
        raise _swapped_hint(error, cage, surface) from None
    inside, distance = classify_points(checked, surface.vertices, device=backend)
    _refuse_mesh_outside(surface, checked, inside, distance)
    seconds["load"] = time.perf_counter() - t
    sources = _sources(mesh, cage_argument)
    if surface.looks is not None:  # the images by reference: an output never replaces one either
        sources = sorted(set(sources) | set(surface.looks.files()))
    return Inputs(scene, surface, checked, made, inside, distance, sources)


def _swapped_hint(error: CageError, cage, surface) -> CageError:
    """``error`` with :func:`_order_hint` where the cage has more vertices than the mesh (the mesh, open or dense, is
    refused as a cage first)."""
    try:
        n_cage = len(load_surface(cage).vertices) if not hasattr(cage, "vertices") else len(cage.vertices)
    except Exception:  # the error says what is wrong with the cage; the hint is only a guess
        return error
    hint = _order_hint(len(surface.vertices), n_cage)
    return CageError(f"{error}{hint}") if hint else error


def _order_hint(n_mesh: int, n_cage: int) -> str:
    """Where a bind's inputs are refused and the cage has more vertices than the mesh, the arguments may be the
    wrong way round: the one place that says so, whichever check refused them (the cage's or the mesh's)."""
    if n_cage <= n_mesh:
        return ""
    return (f"; the cage has more vertices ({n_cage}) than the mesh ({n_mesh}): are the mesh and the cage the other "
            "way round? (bind MESH CAGE)")


def _cage_source(mesh, cage, cage_prim, rest_time):
    """What :func:`check_cage` reads: ``cage`` itself (a file or arrays; or a checked Cage, when ``cage_prim`` only
    keeps that prim out of the meshes), or the surface of the prim ``cage_prim`` in ``cage`` when that is a USD file,
    or in the mesh's stage when no cage is given."""
    if cage_prim is not None and (cage is None or is_usd(cage)):
        from ..io.usd.asset import read_cage_prim

        stage_file = mesh if cage is None else cage
        if not is_usd(stage_file):
            raise CageError(f"{stage_file}: a cage prim ({cage_prim}) is named, but it is not a USD file")
        return read_cage_prim(str(stage_file), cage_prim, rest_time)
    if cage is None:
        raise CageError(f"{getattr(mesh, 'name', mesh)}: no cage: give a cage file, 'auto' for a cage made for the "
                        "mesh (`warp-stokes cage MESH -o CAGE.obj` makes one to look at or edit first), or the cage's "
                        "prim in the USD asset (cage_prim, --cage-prim)")
    if cage_prim is not None and isinstance(cage, (str, os.PathLike)):
        raise CageError(f"{cage}: a cage prim ({cage_prim}) is named, but the cage is not a USD file")
    if is_usd(cage):
        raise CageError(f"{cage}: a USD cage needs its prim path (cage_prim, --cage-prim)")
    return cage


def _sources(mesh, cage) -> list[str]:
    """The files a bind read its mesh and cage from (each USD file's whole layer stack), for the binding to record."""
    from ..io.inputs import inputs_of

    return sorted(inputs_of(mesh, cage if isinstance(cage, (str, os.PathLike)) else None).files)


def _refuse_mesh_outside(surface, checked: Cage, inside: np.ndarray, distance: np.ndarray) -> None:
    """A mesh mostly outside its cage is in other units or another place (a transform not applied): refused
    before the solve, instead of weights that extrapolate far beyond [0, 1]."""
    outside = int((~inside).sum())
    on = int((~inside & (distance <= ON_THE_CAGE * checked.diagonal)).sum())
    if outside > 0.5 * len(inside) and on > 0.5 * outside:  # not elsewhere: on the cage (the mesh as its own cage)
        raise MeshError(
            f"{surface.name}: {on} of {len(inside)} vertices ({100 * on / len(inside):.0f}%) lie on {checked.name} "
            "itself; a cage must enclose the mesh with room around it (is the cage the mesh itself? `warp-stokes "
            "cage MESH -o CAGE.obj` makes one)")
    if outside > 0.5 * len(inside):
        hint = _order_hint(len(surface.vertices), len(checked.source_index if checked.source_index is not None
                                                      else checked.vertices))
        raise MeshError(
            f"{surface.name}: {outside} of {len(inside)} vertices ({100 * outside / len(inside):.0f}%) lie outside "
            f"{checked.name}, up to {distance[~inside].max() / checked.diagonal:.3g} cage diagonals away"
            + (hint or "; is the mesh in the cage's units and place?"))
