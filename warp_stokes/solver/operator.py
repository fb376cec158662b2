"""Applying the compact 19-point coupled operator to every handle's column at once (launch code).

Both the solver (residuals, Krylov steps) and the multigrid's fine level (smoothing) apply the operator through
:func:`apply_operator`; the kernel is ``warp_stokes.kernels.stencil``.
"""

from __future__ import annotations

import warp as wp

from ..device import resolve_device
from ..geometry.grid import Grid
from ..kernels import stencil

__all__ = ["apply_operator"]


def apply_operator(grid: Grid, field: wp.array, out: wp.array, n_rows: int | None = None, device=None,
                   precise: bool = True) -> None:
    """``out = A field`` at the interior rows, for every handle (one launch).

    Parameters
    ----------
    grid : Grid
    field : wp.array2d(vec4f), (rows, handles); rows numbered as ``grid.active_ijk``
    out : wp.array2d(vec4f), (grid.n_interior, handles)
    n_rows : int, rows of ``field`` that are read (others read as zero). Default: all of them.
    device : None | str
    precise : bool, float64 sums (for residuals); float32 sums otherwise (Krylov and smoothing steps)

    Examples
    --------
    >>> out = wp.empty((grid.n_interior, field.shape[1]), dtype=wp.vec4f, device="cpu")  # doctest: +SKIP
    >>> apply_operator(grid, field, out, device="cpu")                                     # doctest: +SKIP
    """
    device = resolve_device(device)
    arrays = grid.device_arrays(device)
    n_rows = field.shape[0] if n_rows is None else n_rows
    patches = arrays["patches"]
    groups = -(-field.shape[1] // stencil.GROUP)
    wp.launch(
        stencil.apply_operator if precise else stencil.apply_operator_fast,
        dim=(groups, patches.shape[0], stencil.GROUP),
        inputs=[field, arrays["index"], patches, int(n_rows)],
        outputs=[out],
        device=device,
        block_dim=stencil.BLOCK_DIM,
    )
