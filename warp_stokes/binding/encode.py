"""Encoding: the cage poses that best reproduce a sequence of meshes with the bound mesh's topology.

For frames P_f (V x 3) and weights W (V x L), the poses C_f (L x 3) minimise

    sum_f ||W C_f - P_f||^2 + smoothness * sum_f ||C_{f+1} - C_f||^2

(the smoothness term in units of the mesh's squared positions, per frame step). Both matrices of the normal
equations are symmetric and small: W^T W (L x L) and the frames' second-difference matrix D^T D (F x F), so they
are diagonalised once and every frame (and coordinate) is solved in their joint eigenbasis; without smoothness it is
one factorisation of W^T W shared by all frames. A captured sequence then replays through the cage: a few hundred
numbers per frame instead of the whole mesh (the paper's reuse of captured mesh sequences).
"""

from __future__ import annotations

import numpy as np

from ..errors import WarpStokesError
from ..geometry.topology import bounding_diagonal
from ..io.poses import Poses

__all__ = ["encode_poses"]


def encode_poses(binding, frames: Poses, smoothness: float = 0.0) -> tuple[Poses, np.ndarray]:
    """Cage poses whose deformation of the bound mesh best matches each frame (least squares on the weights).

    Parameters
    ----------
    binding : Binding
    frames : Poses whose positions are (F, V, 3) mesh vertices (:func:`warp_stokes.io.frames.load_mesh_frames`)
    smoothness : float >= 0, weight of the squared change of each handle between consecutive frames

    Returns
    -------
    poses : Poses (F, L, 3), at the frames' numbers
    rms : (F,) the RMS distance per frame between the deformed mesh and the frame, over the cage's diagonal

    Examples
    --------
    >>> poses, rms = encode_poses(binding, load_mesh_frames("capture/", binding.mesh_faces, binding.n_vertices))  # doctest: +SKIP
    """
    positions = np.asarray(frames.positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[1:] != (binding.n_vertices, 3):
        raise WarpStokesError(f"{frames.name}: frames of shape {positions.shape} do not fit a mesh of "
                              f"{binding.n_vertices} vertices")
    if not (np.isfinite(smoothness) and smoothness >= 0):
        raise WarpStokesError(f"smoothness must be a number >= 0, got {smoothness!r}")
    weights = binding.weights.astype(np.float64)
    gram = weights.T @ weights  # L x L, float64 sums over the vertices
    rhs = np.matmul(weights.T[None], positions).transpose(1, 0, 2)  # W^T P_f for every frame: (L, F, 3)
    n_frames = len(positions)
    if smoothness == 0 or n_frames < 2:
        solution = np.linalg.solve(gram, rhs.reshape(len(gram), -1)).reshape(rhs.shape)
    else:
        steps = np.diff(np.eye(n_frames), axis=0)  # (F - 1, F): consecutive differences
        lam_w, u_w = np.linalg.eigh(gram)
        lam_d, u_d = np.linalg.eigh(steps.T @ steps)
        # (W^T W) C + smoothness C (D^T D) = W^T P, for each coordinate, in the joint eigenbasis
        projected = np.einsum("li,lfd,fj->ijd", u_w, rhs, u_d)
        projected /= (lam_w[:, None] + smoothness * lam_d[None, :])[:, :, None]
        solution = np.einsum("li,ijd,fj->lfd", u_w, projected, u_d)
    poses = np.ascontiguousarray(solution.transpose(1, 0, 2))  # (F, L, 3)
    residual = np.matmul(weights[None], poses) - positions
    rms = np.sqrt(np.mean(np.sum(residual**2, axis=2), axis=1)) / bounding_diagonal(binding.cage_vertices)
    return Poses(poses, np.asarray(frames.frames, dtype=np.float64), f"encoded {frames.name}",
                 frames.time_codes_per_second), rms
