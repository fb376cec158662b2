"""How much two bindings of the same mesh and cage differ (e.g. two resolutions)."""

from __future__ import annotations

import numpy as np

from .measures import row_chunks

__all__ = ["vertex_weight_difference", "weight_difference"]


def vertex_weight_difference(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex, the largest and the RMS difference over the handles between two sets of weights.

    Parameters
    ----------
    a, b : (V, L) arrays or Bindings (their ``weights``) of the same mesh and cage, e.g. two resolutions

    Returns
    -------
    largest : (V,) float64, max_l |a_l - b_l|
    rms : (V,) float64, sqrt(mean_l (a_l - b_l)^2)

    Examples
    --------
    >>> a = np.array([[0.5, 0.5], [1.0, 0.0]]); b = np.array([[0.5, 0.5], [0.7, 0.3]])
    >>> [np.round(x, 3).tolist() for x in vertex_weight_difference(a, b)]
    [[0.0, 0.3], [0.0, 0.3]]
    """
    a, b = np.asarray(getattr(a, "weights", a)), np.asarray(getattr(b, "weights", b))
    if a.shape != b.shape:
        raise ValueError(f"weights of shapes {a.shape} and {b.shape} cannot be compared")
    largest, rms = np.zeros(len(a)), np.zeros(len(a))
    if a.size:
        for rows in row_chunks(*a.shape):
            d = a[rows].astype(np.float64) - b[rows]
            largest[rows] = np.abs(d).max(axis=1)
            rms[rows] = np.sqrt((d * d).mean(axis=1))
    return largest, rms


def weight_difference(a, b) -> dict:
    """Max and RMS over vertices of the largest per-vertex weight change between two weight sets (V, L).

    Parameters
    ----------
    a, b : (V, L) arrays or Bindings

    Returns
    -------
    dict: ``max`` (over vertices and handles), ``rms`` (over vertices, of each vertex's largest change)

    Examples
    --------
    >>> weight_difference(np.eye(2), np.eye(2))
    {'max': 0.0, 'rms': 0.0}
    """
    largest, _ = vertex_weight_difference(a, b)
    rms = float(np.sqrt(np.mean(largest**2))) if len(largest) else 0.0
    return {"max": float(largest.max(initial=0.0)), "rms": rms}
