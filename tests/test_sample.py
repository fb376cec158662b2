"""Sampling the weight field at points: tricubic Hermite (C1, default) and trilinear."""

import warnings

import numpy as np
import pytest
import warp as wp

import warp_stokes as ws
from conftest import EXAMPLE, cli, float32_rounding


@pytest.fixture(scope="module")
def slab_grid(device):
    """A grid whose active nodes fill a box: every point well inside has 8 active corners."""
    mask = np.zeros((16, 16, 16), bool)
    mask[4:12, 4:12, 4:12] = True
    return ws.grid_from_mask(mask, spacing=0.5, origin=(-4.0, -4.0, -4.0), device=device)


def field_of(grid, functions, device):
    """The packed (q, h grad q) field of analytic functions (value, gradient) at the grid's active nodes, on
    `device`."""
    x = grid.node_positions()
    out = np.zeros((grid.n_active, len(functions), 4), np.float32)
    for k, (value, gradient) in enumerate(functions):
        out[:, k, 0] = value(x)
        out[:, k, 1:] = grid.spacing * gradient(x)
    return wp.array(out, dtype=wp.vec4f, device=device)


def inner_points(grid, count=200, seed=0):
    x = grid.node_positions(np.arange(grid.n_interior))
    lo, hi = x.min(0) + grid.spacing, x.max(0) - grid.spacing
    return np.random.default_rng(seed).uniform(lo, hi, size=(count, 3))


LINEAR = (lambda x: 0.3 + x @ [0.5, -1.0, 2.0], lambda x: np.tile([0.5, -1.0, 2.0], (len(x), 1)))
CUBIC = (lambda x: (x**3).sum(1) - x[:, 0] ** 2 + 1, lambda x: 3 * x**2 - np.column_stack([2 * x[:, 0], 0 * x[:, :2]]))
SMOOTH = (lambda x: np.sin(x[:, 0]) * np.cos(0.7 * x[:, 1]) + 0.3 * x[:, 2],
          lambda x: np.column_stack([np.cos(x[:, 0]) * np.cos(0.7 * x[:, 1]),
                                     -0.7 * np.sin(x[:, 0]) * np.sin(0.7 * x[:, 1]), 0.3 + 0 * x[:, 2]]))


def test_hermite_is_exact_for_linear_and_axis_cubic_functions_trilinear_for_linear(slab_grid, device):
    points = inner_points(slab_grid)
    field = field_of(slab_grid, [LINEAR, CUBIC], device)
    w, corners = ws.sample_weights(slab_grid, field, points, device=device, method="hermite")
    assert (corners >= 0).all()
    # float32 sums over 8 corners of values and h-scaled gradients, each about the size of the values (~5): 16 eps
    linear = float32_rounding(np.abs(LINEAR[0](points)).max(), 16)
    np.testing.assert_allclose(w[:, 0], LINEAR[0](points), rtol=0, atol=linear)
    np.testing.assert_allclose(w[:, 1], CUBIC[0](points), atol=1e-4 * np.abs(CUBIC[0](points)).max())
    w, _ = ws.sample_weights(slab_grid, field, points, device=device, method="trilinear")
    np.testing.assert_allclose(w[:, 0], LINEAR[0](points), rtol=0, atol=linear)
    assert np.abs(w[:, 1] - CUBIC[0](points)).max() > 1e-2  # trilinear is not exact for cubics


def test_hermite_is_more_accurate_than_trilinear_on_a_smooth_field(slab_grid, device):
    points = inner_points(slab_grid, 500)
    field = field_of(slab_grid, [SMOOTH], device)
    exact = SMOOTH[0](points)
    sampled = {m: ws.sample_weights(slab_grid, field, points, device=device, method=m)[0][:, 0]
               for m in ("hermite", "trilinear")}
    errors = {m: np.abs(w - exact).max() for m, w in sampled.items()}
    assert errors["hermite"] < 0.2 * errors["trilinear"], errors


def test_hermite_is_c1_across_cell_faces(slab_grid, device):
    # derivatives from either side of a cell face agree (trilinear's jump there); random nodal data
    rng = np.random.default_rng(3)
    data = rng.normal(size=(slab_grid.n_active, 1, 4)).astype(np.float32)
    field = wp.array(data, dtype=wp.vec4f, device=device)
    x = slab_grid.node_positions(np.arange(slab_grid.n_interior))
    face_x = np.unique(x[:, 0])[3]  # a lattice plane x = const well inside
    base = np.column_stack([np.full(50, face_x), rng.uniform(-1.2, 1.2, (50, 2))])
    step = 1e-4 * slab_grid.spacing
    jumps = {}
    for method in ("hermite", "trilinear"):
        def at(dx):
            return ws.sample_weights(slab_grid, field, base + [dx, 0, 0], device=device, method=method)[0][:, 0]
        left = (at(-step) - at(-2 * step)) / step
        right = (at(2 * step) - at(step)) / step
        jumps[method] = np.abs(left - right).max() / np.abs(left).max()
    assert jumps["hermite"] < 1e-2 and jumps["trilinear"] > 0.1, jumps


def test_band_gradients_are_exact_for_linear_data(arm_cage, device):
    # band nodes whose neighbours are not all active use one-sided differences: still exact for linear functions
    grid = ws.voxelize(arm_cage, 16, device=device)
    f = ws.boundary_field(grid, arm_cage, device=device, data="mvc").numpy().astype(np.float64)
    band = f[grid.n_interior + grid.n_ring:]
    assert np.abs(band[..., 1:].sum(axis=1)).max() < 1e-5  # G of the constant 1
    gradient_of_x = np.einsum("ncj,ca->naj", band[..., 1:], arm_cage.vertices - grid.centre) / grid.spacing
    assert np.abs(gradient_of_x - np.eye(3)).max() < 1e-4


def test_binds_sample_with_hermite_by_default_and_trilinear_on_request(tmp_path, device):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hermite = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=16, device=device)
    assert hermite.settings["sampling"] == "hermite"
    assert hermite.stats.partition_of_unity_error <= 1e-5 and hermite.stats.linear_precision_error <= 1e-5
    out = tmp_path / "t.npz"
    # the command line's choice (in process), on the CPU whatever the device under test
    proc = cli("bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(out), "--resolution", "16",
               "--device", "cpu", "--sampling", "trilinear")
    assert proc.returncode == 0, proc.stderr
    trilinear = ws.load_binding(out, device=device)
    assert trilinear.settings["sampling"] == "trilinear"
    assert trilinear.stats.partition_of_unity_error <= 1e-5
    assert 1e-4 < np.abs(trilinear.weights - hermite.weights).max() < 0.5  # the same field, sampled two ways
    proc = cli("bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(out), "--sampling", "cubic")
    assert proc.returncode == 2 and "invalid choice" in proc.stderr
    with pytest.raises(ws.WarpStokesError, match="sampling must be"):
        ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=16, device=device, sampling="cubic")
