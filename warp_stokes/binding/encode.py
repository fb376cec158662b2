"""Encoding: the cage poses that best reproduce a sequence of meshes with the bound mesh's topology.

For frames P_f (V x 3) and weights W (V x L), the poses C_f (L x 3) minimise

    sum_f ||W C_f - P_f||^2 + smoothness * sum_f ||C_{f+1} - C_f||^2

(the smoothness term in units of the mesh's squared positions, per frame step). The products over the vertices,
W^T W and W^T P_f, are the work (V L^2 and V L F): on a CUDA device they are summed there in float64
(``warp_stokes.kernels.encode``, frames in batches), on the CPU by BLAS. Both matrices of the normal
equations are then symmetric and small: W^T W (L x L) and the frames' second-difference matrix D^T D (F x F), so they
are diagonalised once and every frame (and coordinate) is solved in their joint eigenbasis; without smoothness it is
one factorisation of W^T W shared by all frames. A captured sequence then replays through the cage: a few hundred
numbers per frame instead of the whole mesh (the paper's reuse of captured mesh sequences).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..device import Backend
from ..errors import WarpStokesError
from ..geometry.topology import bounding_diagonal
from ..io.poses import Poses
from ..kernels import encode

__all__ = ["encode_poses", "normal_equations"]

#: vertices summed by one thread of the device products
VERTEX_BLOCK = 2048
#: bytes of frame positions on the device at once (float64, 24 bytes per vertex and frame)
FRAME_BYTES = 1 << 30


def normal_equations(weights: np.ndarray, positions: np.ndarray, device=None,
                     kernels: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """W^T W (L, L) and W^T P_f for every frame (L, F, 3), in float64 sums.

    Parameters
    ----------
    weights : (V, L) array
    positions : (F, V, 3) array
    device : None | str, where the products are summed: a CUDA device (Warp kernels), or the CPU (BLAS)
    kernels : bool, optional, sum with the Warp kernels (True) or BLAS on the host (False); default: kernels on a
        CUDA device (Warp's CPU kernels run on one core, BLAS on all)

    Returns
    -------
    gram : (L, L) float64
    projected : (L, F, 3) float64

    Examples
    --------
    >>> w = np.array([[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]])
    >>> gram, projected = normal_equations(w, np.arange(9.0).reshape(1, 3, 3), device="cpu")
    >>> gram
    array([[1.25, 0.25],
           [0.25, 1.25]])
    >>> projected[:, 0]
    array([[ 1.5,  3. ,  4.5],
           [ 7.5,  9. , 10.5]])
    """
    backend = Backend.of(device)
    weights = np.asarray(weights)
    positions = np.asarray(positions)
    if not (backend.pick(cpu=False, gpu=True) if kernels is None else kernels):
        w = weights.astype(np.float64)
        return w.T @ w, np.matmul(w.T[None], positions.astype(np.float64)).transpose(1, 0, 2)
    n_vertices, n_handles = weights.shape
    blocks = -(-n_vertices // VERTEX_BLOCK)
    # positions relative to their centre in the kernel, float64 throughout: W^T P = W^T (P - c) + (W^T 1) c
    # (any centre near the frames keeps the sums small: the first frame's box centre, without a pass over all frames)
    centre = 0.5 * (positions[0].min(axis=0) + positions[0].max(axis=0)) if positions.size else np.zeros(3)
    column_sums = weights.sum(axis=0, dtype=np.float64)
    batch_frames = max(1, FRAME_BYTES // max(1, 24 * n_vertices))
    with backend.scope():
        w = wp.array(np.ascontiguousarray(weights, dtype=np.float32), dtype=wp.float32)
        gram = wp.zeros((n_handles, n_handles), dtype=wp.float64)
        wp.launch(encode.gram, dim=(blocks, n_handles, n_handles), inputs=[w, VERTEX_BLOCK], outputs=[gram])
        projected = np.empty((n_handles, len(positions), 3))
        for first in range(0, len(positions), batch_frames):
            batch = np.ascontiguousarray(positions[first:first + batch_frames], dtype=np.float64)
            p = wp.array(batch, dtype=wp.vec3d)
            out = wp.zeros((n_handles, 3 * len(batch)), dtype=wp.float64)
            wp.launch(encode.project, dim=(blocks, len(batch), n_handles),
                      inputs=[w, p, wp.vec3d(*centre), VERTEX_BLOCK], outputs=[out])
            projected[:, first:first + len(batch)] = (out.numpy().reshape(n_handles, len(batch), 3)
                                                      + column_sums[:, None, None] * centre)
        upper = gram.numpy()
    return np.triu(upper) + np.triu(upper, 1).T, projected


def encode_poses(binding, frames: Poses, smoothness: float = 0.0, device=None, return_max: bool = False) -> tuple:
    """Cage poses whose deformation of the bound mesh best matches each frame (least squares on the weights).

    Parameters
    ----------
    binding : Binding
    frames : Poses whose positions are (F, V, 3) mesh vertices (:func:`warp_stokes.io.frames.load_mesh_frames`)
    smoothness : float >= 0, weight of the squared change of each handle between consecutive frames
    device : None | str, where the products over the vertices are summed (default: the binding's device)
    return_max : bool, also return each frame's largest vertex distance

    Returns
    -------
    poses : Poses (F, L, 3), at the frames' numbers
    rms : (F,) the RMS distance per frame between the deformed mesh and the frame, over the cage's diagonal
    largest : (F,) with ``return_max``: the largest distance of a vertex from its place in the frame, per frame, over
        the cage's diagonal

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
    gram, rhs = normal_equations(binding.weights, positions, binding.backend if device is None else device)
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
    residual = np.asarray(binding.deform(poses), dtype=np.float64).reshape(positions.shape) - positions
    diagonal = bounding_diagonal(binding.cage_vertices)
    squared = np.sum(residual**2, axis=2)
    rms = np.sqrt(np.mean(squared, axis=1)) / diagonal
    encoded = Poses(poses, np.asarray(frames.frames, dtype=np.float64), f"encoded {frames.name}",
                    frames.time_codes_per_second)
    if return_max:
        return encoded, rms, np.sqrt(squared.max(axis=1)) / diagonal
    return encoded, rms
