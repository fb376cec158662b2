"""Inside or outside the cage, and how far from it: the cage's generalised winding number on a Warp BVH."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..device import Backend
from ..kernels import voxel
from .cage import Cage

__all__ = ["cage_mesh", "classify_points", "WINDING_ACCURACY"]

#: accuracy of Warp's fast winding number (dipole expansion used beyond this many cluster radii)
WINDING_ACCURACY = 2.0


def cage_mesh(cage: Cage, centre: np.ndarray, device) -> wp.Mesh:
    """The cage as a Warp mesh (BVH with winding-number support), its points relative to ``centre`` (float32 keeps
    its precision near the cage)."""
    points = wp.array((cage.vertices - centre).astype(np.float32), dtype=wp.vec3, device=device)
    indices = wp.array(cage.faces.astype(np.int32).ravel(), dtype=wp.int32, device=device)
    return wp.Mesh(points=points, indices=indices, support_winding_number=True)


def classify_points(cage: Cage, points: np.ndarray, device=None, threads: int | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Which points lie inside the cage (generalised winding number > 1/2), and how far from its surface.

    Parameters
    ----------
    cage : Cage
    points : (N, 3) array of positions
    device : None | str | Backend
    threads : int, optional, on a CPU the threads that share the points out (default: every core)

    Returns
    -------
    inside : (N,) bool
    distance : (N,) float64, unsigned distance to the cage surface

    Examples
    --------
    >>> inside, dist = classify_points(cage, cage.vertices.mean(axis=0)[None])  # doctest: +SKIP
    """
    backend = Backend.of(device, threads)
    centre = 0.5 * (cage.vertices.min(axis=0) + cage.vertices.max(axis=0))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, dtype=bool), np.zeros(0)
    with backend.scope():
        mesh = cage_mesh(cage, centre, backend.device)
        pts = wp.array((points - centre).astype(np.float32), dtype=wp.vec3)
        inside = wp.empty(len(points), dtype=wp.int32)
        distance = wp.empty(len(points), dtype=float)
        backend.in_threads(len(points), lambda a, b: wp.launch(voxel.classify_points, dim=b - a,
                                                               inputs=[mesh.id, pts[a:b], WINDING_ACCURACY],
                                                               outputs=[inside[a:b], distance[a:b]]),
                           modules=("voxel",))
        return inside.numpy().astype(bool), distance.numpy().astype(np.float64)
