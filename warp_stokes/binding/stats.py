"""What a binding records beside its weights: the exactness of the weights, the grid's and the solver's figures, the
settings, and the parts and asset it came from."""

from __future__ import annotations

import dataclasses

import numpy as np
import warp as wp

from .. import __version__
from ..device import device_name
from ..geometry.cage import Cage
from ..geometry.topology import bounding_diagonal
from ..geometry.local_data import LocalData
from ..io.scene import Scene

__all__ = ["identity_errors", "grid_stats", "solver_stats", "mvc_stats", "settings_record", "parts_record",
           "asset_record"]


def identity_errors(weights: np.ndarray, handles: np.ndarray, points: np.ndarray, rows: int = 1 << 16):
    """The largest deviation from partition of unity, max |sum_l w_l - 1|, and from linear precision,
    max |sum_l w_l (c_l - o) - (p - o)| relative to the handles' bounding-box diagonal, o its centre (as the solver
    measures it: weights do not change when cage and mesh move together, and in world coordinates far from the origin
    the float32 weights' rounding times the coordinates would read as an error), in float64 sums over blocks of
    ``rows`` vertices (a float64 copy of all weights would double a large mesh's peak memory).

    Examples
    --------
    >>> c = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> identity_errors(np.array([[0.25, 0.25, 0.25, 0.25]], np.float32), c, np.array([[0.25, 0.25, 0.25]]))
    (0.0, 0.0)
    """
    handles = np.asarray(handles, dtype=np.float64)
    diag = bounding_diagonal(handles)
    centre = 0.5 * (handles.min(axis=0) + handles.max(axis=0))
    handles = handles - centre
    pu = lp = 0.0
    for start in range(0, len(weights), rows):
        w = weights[start : start + rows].astype(np.float64)
        if len(w):
            pu = max(pu, float(np.abs(w.sum(axis=1) - 1.0).max()))
            lp = max(lp, float(np.linalg.norm(w @ handles - (points[start : start + rows] - centre),
                                              axis=1).max()) / diag)
    return pu, lp


def parts_record(scene: Scene) -> list:
    return [{"path": p.path, "vertices": len(p.surface.vertices), "normals": p.normals,
             "to_world": np.asarray(p.to_world, dtype=np.float64).tolist()} for p in scene.parts]


def asset_record(scene: Scene):
    return None if scene.asset is None else {"path": scene.asset, **scene.metadata}


def grid_stats(grid, checked: Cage, surface, inside, beyond, thin, device) -> dict:
    """What the grid and the vertices are, for the binding's stats."""
    return {
        "device": device_name(device),
        "grid_shape": list(grid.shape),
        "spacing": grid.spacing,
        "interior_nodes": grid.n_interior,
        "ring_nodes": grid.n_ring,
        "cut_off_nodes": grid.n_cut_off,
        "band_nodes": grid.n_band,
        "handles": checked.n_handles,
        "vertices": len(surface.vertices),
        "vertices_outside_cage": int((~inside).sum()),
        "vertices_beyond_band": int(beyond.sum()),
        "vertices_in_thin_features": int(thin.sum()),
    }


def mvc_stats(checked: Cage, surface, inside, device, pu_error: float, lp_error: float, seconds: dict) -> dict:
    """The stats of a binding by mean value coordinates: no grid, no solve (the keys a grid binding has, empty)."""
    return {
        "device": device_name(device),
        "method": "mvc",
        "grid_shape": None,
        "handles": checked.n_handles,
        "vertices": len(surface.vertices),
        "vertices_outside_cage": int((~inside).sum()),
        "vertices_beyond_band": 0,
        "vertices_in_thin_features": 0,
        "solver": None,
        "coarsest_operator": None,
        "preconditioners": [],
        "recoveries": [],
        "levels": [],
        "chunks": 0,
        "iterations": 0,
        "residual": 0.0,
        "identity_error": 0.0,
        "converged": True,
        # the float32 weights and one float64 block of rows on the device
        "memory_estimate_bytes": (4 * len(surface.vertices) + 8 * min(len(surface.vertices), 1 << 16))
        * checked.n_handles,
        "partition_of_unity_error": pu_error,
        "linear_precision_error": lp_error,
        "seconds": seconds,
        "warnings": list(checked.notes),
    }


def settings_record(resolution, tol, max_iterations, solver, boundary, sampling, surface, checked: Cage, scene: Scene,
              cage_prim, method: str = "stokes") -> dict:
    """The settings a binding was made with, and where its inputs came from."""
    grid = method != "mvc"
    return {
        "method": method,
        "resolution": int(resolution) if grid else None,
        "tol": float(tol) if grid else None,
        "max_iterations": max_iterations if grid else None,
        "solver": solver if grid else None,
        "boundary": None if not grid else "mvc-central-difference" if boundary == "mvc" else str(
            LocalData() if boundary == "local" else boundary),
        "sampling": sampling if grid else None,
        # the local data's parameters, to rebuild it (warp_stokes.show solves a handle again)
        "boundary_settings": dataclasses.asdict(LocalData() if boundary == "local" else boundary)
        if grid and boundary != "mvc" else None,
        "mesh": surface.name,
        "cage": checked.name,
        "cage_prim": cage_prim,
        "mesh_prims": [p.path for p in scene.parts] if scene.asset else None,
        "rest_time": scene.metadata.get("rest_time"),
        "cage_flipped": checked.flipped,
        "cage_handles": ("the cage's vertices, in its order" if checked.source_index is None else
                         f"{len(checked.source_index)} vertices merged into {checked.n_handles} handles, in order of "
                         "first appearance (map: cage_source_index)"),
        "warp_version": wp.config.version,
        "warp_stokes_version": __version__,
    }


def solver_stats(reports, coarsest: dict | None = None) -> dict:
    """The solve reports of all chunks, summed up for the binding's stats, and the multigrid's coarsest operator:
    ``recoveries`` lists each switch of preconditioner after a fault (with its chunk), ``preconditioners`` what
    ended each chunk's solve."""
    return {
        "coarsest_operator": coarsest,
        "preconditioners": [r.preconditioner for r in reports],
        "recoveries": [{"chunk": k, **event} for k, r in enumerate(reports) for event in (r.recoveries or [])],
        "iterations": max(r.iterations for r in reports),
        "restarts": max(r.restarts for r in reports),
        "solver_rounds": reports[0].rounds,
        "chunk_iterations": [r.iterations for r in reports],
        "chunk_rounds": [r.rounds for r in reports],
        "residual": max(r.residual for r in reports),
        "identity_error": max(r.identity_error for r in reports),
        "converged": all(r.converged for r in reports),
    }
