"""The coarsest level's inverse: dense, in float64, checked (a Cholesky factorisation and a condition bound, else the
eigendecomposition with the modes the float32 cycle cannot resolve left out), formed on a host thread beside a GPU's
work."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["coarsest_inverse", "inverts_beside", "HOST", "COARSEST_CUTOFF"]

#: eigenvalues of the coarsest operator (scaled to a unit diagonal) at most this fraction of its largest are left out
#: of its inverse: the cycle's float32 right-hand sides carry relative errors near 6e-8, which 1 / lambda would
#: amplify beyond the correction itself. The scaled coarsest levels of the convergence sweeps' cages are far from
#: it (their bound of lambda_min / lambda_max stays thousands of times above it); a singular one (a fault) loses
#: its null space instead of blowing up
COARSEST_CUTOFF = 1e-7

#: inverts the coarsest operators on the host (LAPACK releases the GIL), beside the device's work. One worker:
#: hierarchies formed faster than they are inverted wait in turn (each holds its dense matrix, at most 20 MB, until
#: then); a process forked from one that used it must not use it (CUDA forbids forking anyway)
HOST = ThreadPoolExecutor(max_workers=1, thread_name_prefix="warp-stokes-coarsest")


def inverts_beside(device) -> bool:
    """Whether the coarsest inverse is computed on a host thread beside the device's work: for a GPU. On the CPU its
    kernels run on the cores LAPACK would use, and the memory plan counts host memory: there it is computed in turn."""
    return device.is_cuda


def _infinity_norm(matrix: np.ndarray, rows: int = 256) -> float:
    """The largest absolute row sum, a block of rows at a time (no full-size temporary)."""
    return max((float(np.abs(matrix[k : k + rows]).sum(axis=1).max()) for k in range(0, len(matrix), rows)),
               default=0.0)


def coarsest_inverse(dense: np.ndarray, cutoff: float = COARSEST_CUTOFF) -> tuple[np.ndarray, float, dict]:
    """The inverse of a symmetric coarsest operator, never unchecked. With S = diag(A)^-1/2 (the operator's rows are
    scaled like h^-4 and h^-2 for values and gradients), a Cholesky factorisation proves S A S positive definite and
    ||S A S||_inf ||(S A S)^-1||_inf bounds its condition number from above; where either fails (not positive
    definite, or the bound above 1 / ``cutoff``), the pseudo-inverse from the eigendecomposition of S A S in float64,
    eigenvalues at most ``cutoff`` times the largest left out (it cannot blow up on a singular operator). The inverse
    is S (S A S)^-1 S. ``dense`` is overwritten (by S A S).

    Parameters
    ----------
    dense : (m, m) float64, symmetric
    cutoff : float

    Returns
    -------
    inverse : (m, m) float32
    seconds : float, the time it took
    report : dict, of S A S: ``unknowns``, ``condition`` (largest over the smallest kept eigenvalue; on the Cholesky
        path the upper bound), ``smallest_eigenvalue`` (relative to the largest; on the Cholesky path 1 / the bound,
        a lower bound), ``dropped`` (eigenvalues left out) and ``method`` ("cholesky" or "eigen")

    Examples
    --------
    >>> inverse, _, report = coarsest_inverse(np.array([[4.0, 1.0], [1.0, 1.0]]))
    >>> np.round(inverse.astype(float), 5).tolist(), report["method"], round(report["condition"], 6)
    ([[0.33333, -0.33333], [-0.33333, 1.33333]], 'cholesky', 3.0)
    >>> inverse, _, report = coarsest_inverse(np.diag([4.0, 2.0, 0.0]))
    >>> inverse.diagonal().tolist(), report["method"], report["dropped"], round(report["condition"], 6)
    ([0.25, 0.5, 0.0], 'eigen', 1, 1.0)
    """
    start = time.perf_counter()
    report = {"unknowns": int(len(dense)), "dropped": 0}
    diagonal = dense.diagonal().copy()
    # a row without a positive diagonal (no positive definite operator has one) keeps its scale: the eigen path
    scale = 1.0 / np.sqrt(np.where(diagonal > 0, diagonal, 1.0))
    dense *= scale[:, None]
    dense *= scale[None, :]
    try:
        np.linalg.cholesky(dense)  # raises unless positive definite (the coarsening rule makes it so)
        inverse = np.linalg.inv(dense)
        condition = _infinity_norm(dense) * _infinity_norm(inverse)
        if (diagonal > 0).all() and np.isfinite(condition) and condition * cutoff < 1.0:
            report.update(smallest_eigenvalue=1.0 / condition, condition=condition, method="cholesky")
            inverse *= scale[:, None]
            inverse *= scale[None, :]
            return inverse.astype(np.float32), time.perf_counter() - start, report
        del inverse
    except np.linalg.LinAlgError:
        pass
    values, vectors = np.linalg.eigh(dense)
    largest = float(np.abs(values).max()) if values.size else 0.0
    kept = values > cutoff * largest
    inverse = (vectors[:, kept] / values[kept]) @ vectors[:, kept].T
    inverse *= scale[:, None]
    inverse *= scale[None, :]
    report.update(smallest_eigenvalue=float(values.min() / largest) if largest > 0 else 0.0,
                  condition=float(largest / values[kept].min()) if kept.any() else float("inf"),
                  dropped=int((~kept).sum()), method="eigen")
    return inverse.astype(np.float32), time.perf_counter() - start, report
