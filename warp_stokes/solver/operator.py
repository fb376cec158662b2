"""Applying the fine operator to every handle's column at once (launch code): the compact 19-point coupled
biharmonic scheme (``warp_stokes.kernels.stencil``), or the 7-point Laplace equation of harmonic coordinates in the
same (q, G) layout (``warp_stokes.kernels.laplace``).

Both the solver (residuals, Krylov steps) and the multigrid's fine level (smoothing) apply the operator through
:func:`apply_operator`.
"""

from __future__ import annotations

import warp as wp

from ..device import Backend
from ..geometry.grid import Grid
from ..kernels import cg, laplace, stencil, stencil_cpu
from .equation import equation_of

__all__ = ["apply_operator", "chebyshev_step"]


def apply_operator(grid: Grid, field: wp.array, out: wp.array, n_rows: int | None = None, device=None,
                   precise: bool = True, equation: str = "biharmonic", rhs: wp.array | None = None,
                   record_cmd: bool = False) -> "wp.Launch | None":
    """``out = A field`` (or ``rhs - A field``) at the interior rows, for every handle (one launch).

    Parameters
    ----------
    grid : Grid
    field : wp.array2d(vec4f), (rows, handles); rows numbered as ``grid.active_ijk``
    out : wp.array2d(vec4f), (grid.n_interior, handles)
    n_rows : int, rows of ``field`` that are read (others read as zero). Default: all of them.
    device : None | str | Backend
    precise : bool, float64 sums (for residuals); float32 sums otherwise (Krylov and smoothing steps)
    equation : "biharmonic" (the compact 19-point scheme) | "laplace" (7-point, identity gradient rows) | Equation
    rhs : wp.array2d(vec4f), optional, (grid.n_interior, handles): write ``rhs - A field`` instead; one pass for the
        biharmonic scheme with float32 sums (the smoother's residuals), where ``out`` may be ``rhs``; otherwise two
        passes, and ``out`` must not be ``rhs``
    record_cmd : bool, return the launch as a ``wp.Launch`` to replay (``.launch()``) instead of launching it (one
        pass only)

    Returns
    -------
    wp.Launch with ``record_cmd`` (None when there is nothing to launch: no interior row or no column), else None

    Examples
    --------
    >>> out = wp.empty((grid.n_interior, field.shape[1]), dtype=wp.vec4f, device="cpu")  # doctest: +SKIP
    >>> apply_operator(grid, field, out, device="cpu")                                     # doctest: +SKIP
    """
    backend = Backend.of(device)
    device = backend.device
    arrays = grid.device_arrays(backend)
    equation = equation_of(equation)
    n_rows = field.shape[0] if n_rows is None else n_rows
    fused = rhs is not None and equation.compact and not precise
    if rhs is not None and not fused and rhs.ptr == out.ptr:
        raise ValueError("apply_operator: out may be rhs only for the biharmonic scheme with precise=False")
    if rhs is not None and not fused and record_cmd:
        raise ValueError("apply_operator: a residual in two passes cannot be recorded as one launch")
    if not equation.compact and backend.on_cpu:  # a thread per node looping over the handles
        launch = wp.launch(laplace.apply_laplacian_rows if precise else laplace.apply_laplacian_rows_fast,
                           dim=out.shape[0], inputs=[field, arrays["neighbours"], int(n_rows)], outputs=[out],
                           device=device, record_cmd=record_cmd)
    elif not equation.compact:
        launch = wp.launch(laplace.apply_laplacian if precise else laplace.apply_laplacian_fast, dim=out.shape,
                           inputs=[field, arrays["index"], arrays["active_ijk"], int(n_rows)], outputs=[out],
                           device=device, record_cmd=record_cmd)
    else:
        kernels = backend.pick(cpu=stencil_cpu, gpu=stencil)
        kernel = kernels.residual_operator_fast if fused else (
            kernels.apply_operator if precise else kernels.apply_operator_fast)
        if backend.on_cpu:
            launch = _node_loop(kernel, arrays, field, n_rows, rhs if fused else out, 0.0, 0.0, out, out, device,
                                record_cmd)
        else:
            launch = _walk(kernel, arrays, arrays["patches"], field, n_rows, [rhs] if fused else [], out, device,
                           record_cmd)
    if rhs is not None and not fused:
        wp.launch(cg.residual, dim=out.shape, inputs=[rhs, out], outputs=[out], device=device)
    return launch


def chebyshev_step(grid: Grid, field: wp.array, rhs: wp.array, d: wp.array, ca: float, cb: float, out: wp.array,
                   n_rows: int, device=None) -> None:
    """One Chebyshev smoothing step of the compact biharmonic scheme at the interior rows, in one pass (float32 sums):
    ``d = ca d + cb D^-1 (rhs - A field)`` and ``out = field + d``, D the scheme's diagonal block. The numbers of the
    one-pass residual (:func:`apply_operator` with ``rhs``) followed by the multigrid's pointwise step, without
    writing the residual and reading it back.

    Parameters
    ----------
    grid : Grid
    field : wp.array2d(vec4f), (rows, handles), the iterate; rows at or beyond ``n_rows`` read as zero
    rhs, d : wp.array2d(vec4f), (grid.n_interior, handles); ``d`` is updated in place
    ca, cb : float, the step's coefficients
    out : wp.array2d(vec4f), (grid.n_interior, handles), the next iterate; not ``field`` (its neighbours are read
        after a node's step is written)
    n_rows : int
    device : None | str | Backend

    Examples
    --------
    >>> chebyshev_step(grid, x, b, d, 0.0, 0.5, x_next, grid.n_interior, device="cpu")  # doctest: +SKIP
    """
    if out.ptr == field.ptr:
        raise ValueError("chebyshev_step: out must not be field")
    backend = Backend.of(device)
    device = backend.device
    arrays = grid.device_arrays(backend)
    if backend.on_cpu:
        _node_loop(stencil_cpu.chebyshev_step_fast, arrays, field, n_rows, rhs, ca, cb, d, out, device)
    else:
        _walk(stencil.chebyshev_step_fast, arrays, arrays["step_patches"], field, n_rows,
              [rhs, float(ca), float(cb), d], out, device)


def _walk(kernel, arrays: dict, patches: wp.array, field: wp.array, n_rows: int, extra: list, out: wp.array,
          device, record_cmd: bool = False) -> "wp.Launch | None":
    """Launch one of the stencil's patch walks (``stencil.operator_kernel``) over ``patches``: (handle groups,
    patches, GROUP) in blocks of BLOCK_DIM, with ``extra`` inputs after the walk's own (or return it recorded)."""
    groups = -(-field.shape[1] // stencil.GROUP)
    return wp.launch(kernel, dim=(groups, patches.shape[0], stencil.GROUP),
                     inputs=[field, arrays["index"], patches, int(n_rows), *extra], outputs=[out], device=device,
                     block_dim=stencil.BLOCK_DIM, record_cmd=record_cmd)


def _node_loop(kernel, arrays: dict, field: wp.array, n_rows: int, rhs: wp.array, ca: float, cb: float, d: wp.array,
               out: wp.array, device, record_cmd: bool = False) -> "wp.Launch | None":
    """Launch one of the CPU's node loops (``stencil_cpu.node_operator_kernel``): a thread per interior node (or
    return it recorded). Its C++ loop reads a row's handles as consecutive vec4s: arrays whose columns are not (a
    slice with a step) are refused."""
    for array in (field, rhs, d, out):
        if array.shape[1] > 1 and array.strides[1] != 16:
            raise ValueError("the CPU's operator needs each row's columns consecutive (a column slice without a step), "
                             f"got strides {array.strides}")
    return wp.launch(kernel, dim=out.shape[0], inputs=[field, arrays["neighbours"], int(n_rows), rhs, float(ca),
                                                       float(cb), d], outputs=[out], device=device,
                     record_cmd=record_cmd)
