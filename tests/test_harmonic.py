"""Harmonic coordinates (the 7-point Laplace equation through the same batched CG and multigrid) against an
independent float64 sparse solve, exact facts (harmonic quadratics, partition of unity, linear precision) and the
V-cycle's Galerkin products."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

import warp_stokes as ws
from test_solve import ball_grid, coordinates, to_dense, to_field

FACES = [tuple(s if b == a else 0 for b in range(3)) for a in range(3) for s in (-1, 1)]


def laplace_reference(interior: np.ndarray, known: np.ndarray, f: np.ndarray | None = None, h: float = 1.0):
    """The 7-point Dirichlet problem 6 q_p - sum_face q = h^2 f_p at the interior nodes, values elsewhere from
    ``known`` (nx, ny, nz, H), solved in float64 with scipy (written from the equation, not from the package)."""
    nodes = np.flatnonzero(interior.ravel())
    number = -np.ones(interior.size, dtype=np.int64)
    number[nodes] = np.arange(len(nodes))
    ijk = np.stack(np.unravel_index(nodes, interior.shape), axis=1)
    rows, cols, vals = [np.arange(len(nodes))], [np.arange(len(nodes))], [np.full(len(nodes), 6.0)]
    rhs = np.zeros((len(nodes), known.shape[3]))
    if f is not None:
        rhs += h**2 * f.reshape(-1, f.shape[-1])[nodes]
    for d in FACES:
        nb = ijk + np.array(d)
        flat = np.ravel_multi_index(tuple(nb.T), interior.shape)
        inner = number[flat] >= 0
        rows.append(np.flatnonzero(inner))
        cols.append(number[flat[inner]])
        vals.append(-np.ones(inner.sum()))
        rhs[~inner] += known.reshape(-1, known.shape[3])[flat[~inner]]
    matrix = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                           shape=(len(nodes), len(nodes)))
    out = known.copy()
    out.reshape(-1, known.shape[3])[nodes] = spla.spsolve(matrix.tocsc(), rhs)
    return out


def test_harmonic_solve_matches_a_direct_float64_solve(device):
    grid = ball_grid(device)
    x, y, z = np.moveaxis(coordinates(grid), -1, 0)
    values = np.stack([np.sin(3 * x + 0.3) * np.cos(2 * y) + np.exp(z), x * y - z**2, np.cos(4 * z) * x], axis=3)
    interior = grid.labels == 1
    known = np.where(interior[..., None], 0.0, values.astype(np.float32).astype(np.float64))
    reference = laplace_reference(interior, known)
    full = np.zeros(values.shape + (4,))
    full[..., 0] = known
    field = to_field(grid, full, device)
    mg = ws.Multigrid(grid, device=device, coarsest_nodes=10, equation="laplace")
    assert len(mg.levels) >= 3
    report = ws.solve_biharmonic(grid, field, tol=1e-7, device=device, preconditioner=mg, equation="laplace")
    got = to_dense(grid, field, full)
    err = np.abs(got[interior][..., 0] - reference[interior]).max()
    assert err <= 2e-6, f"max |warp - reference| = {err:.2e}"
    assert report.converged and report.iterations <= 20
    # the interior gradients are the central differences of the solved values
    q = got[..., 0]
    for a in range(3):
        central = 0.5 * (np.roll(q, -1, axis=a) - np.roll(q, 1, axis=a))
        assert np.abs(got[..., 1 + a][interior] - central[interior]).max() <= 1e-6


def test_harmonic_quadratics_are_reproduced_with_a_source(device):
    """q = x^2 + 2 y^2 - 3 z^2 + x y is harmonic, and q = x^2 + y^2 + z^2 solves -Laplace(q) = -6: the 7-point
    operator is exact on quadratics, so the discrete solutions are these polynomials at the nodes."""
    grid = ball_grid(device)
    x, y, z = np.moveaxis(coordinates(grid), -1, 0)
    exact = np.stack([x**2 + 2 * y**2 - 3 * z**2 + x * y, x**2 + y**2 + z**2], axis=3)
    interior = grid.labels == 1
    full = np.zeros(exact.shape + (4,))
    full[..., 0] = np.where(interior[..., None], 0.0, exact)
    field = to_field(grid, full, device)
    source = np.zeros((grid.n_interior, 2))
    source[:, 1] = -6.0
    ws.solve_biharmonic(grid, field, tol=1e-7, device=device, equation="laplace", source=source)
    got = to_dense(grid, field, full)
    assert np.abs(got[interior][..., 0] - exact[interior]).max() <= 1e-5 * np.abs(exact).max()


def test_harmonic_coordinates_are_exact_on_a_real_cage(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=16, device=device)
    field = ws.boundary_field(grid, arm_cage, device=device)
    known = to_dense(grid, field, np.zeros(grid.shape + (arm_cage.n_handles, 4)))[..., 0]
    interior = grid.labels == 1
    reference = laplace_reference(interior, np.where(interior[..., None], 0.0, known))
    report = ws.solve_biharmonic(grid, field, tol=1e-6, handles=arm_cage.vertices, device=device,
                                 equation="laplace")
    got = to_dense(grid, field, np.zeros(grid.shape + (arm_cage.n_handles, 4)))[..., 0]
    assert report.converged and report.identity_error <= 1e-5
    assert np.abs(got[interior] - reference[interior]).max() <= 1e-5
    # harmonic and Stokes coordinates are different fields with the same data
    stokes = ws.boundary_field(grid, arm_cage, device=device)
    ws.solve_biharmonic(grid, stokes, tol=1e-6, handles=arm_cage.vertices, device=device)
    stokes = to_dense(grid, stokes, np.zeros(grid.shape + (arm_cage.n_handles, 4)))[..., 0]
    assert np.abs(stokes[interior] - got[interior]).max() > 1e-2


def test_laplace_coarse_operators_are_galerkin_products(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=16, device=device)
    mg = ws.Multigrid(grid, device=device, equation="laplace")

    def matrix(triplets, n_rows, n_cols):
        rows, cols, blocks = triplets
        r = (4 * rows[:, None, None] + np.arange(4)[None, :, None]).repeat(4, 2)
        c = (4 * cols[:, None, None] + np.arange(4)[None, None, :]).repeat(4, 1)
        return sp.csr_matrix((blocks.astype(np.float64).ravel(), (r.ravel(), c.ravel())),
                             shape=(4 * n_rows, 4 * n_cols))

    sizes = mg.level_sizes
    fine = matrix(mg.operator_triplets(0), sizes[0], sizes[0])
    # the fine level: 6 on the value diagonal, -1 to each interior face neighbour, identity gradient rows
    dense = fine.toarray()
    assert np.allclose(np.diag(dense)[0::4], 6.0) and np.allclose(np.diag(dense)[1::4], 1.0)
    assert set(np.unique(dense[0::4, 0::4])) <= {-1.0, 0.0, 6.0}
    assert np.abs(dense[1::4, 0::4]).max() == 0 and np.abs(dense - dense.T).max() == 0
    for depth in range(len(sizes) - 1):
        p = matrix(mg.prolongation_triplets(depth), sizes[depth], sizes[depth + 1])
        galerkin = (p.T @ matrix(mg.operator_triplets(depth), sizes[depth], sizes[depth]) @ p).toarray()
        coarse = matrix(mg.operator_triplets(depth + 1), sizes[depth + 1], sizes[depth + 1]).toarray()
        assert np.abs(galerkin - coarse).max() <= 1e-5 * np.abs(galerkin).max()


def test_a_multigrid_for_another_equation_is_refused(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=12, device=device)
    field = ws.boundary_field(grid, arm_cage, device=device)
    with pytest.raises(ValueError, match="built for the biharmonic"):
        ws.solve_biharmonic(grid, field, device=device, preconditioner=ws.Multigrid(grid, device=device),
                            equation="laplace")
    with pytest.raises(ws.WarpStokesError, match="equation must be"):
        ws.solve_biharmonic(grid, field, device=device, equation="poisson")


@pytest.mark.parametrize("rows", ["interior", "active"])
def test_the_cpus_laplace_node_loop_is_the_node_handle_launch_to_the_bit(rows):
    # a CPU applies the 7-point operator by a thread per node looping over the handles, a GPU by a thread per node
    # and handle: the same sums in the same order (float32 and float64), rows beyond n_rows read as zero
    from warp_stokes.kernels import laplace

    grid = ball_grid("cpu")
    n_rows = grid.n_interior if rows == "interior" else grid.n_active
    rng = np.random.default_rng(9)
    field = wp.array(rng.standard_normal((grid.n_active, 37, 4)).astype(np.float32), dtype=wp.vec4f, device="cpu")
    arrays = grid.device_arrays("cpu")
    results = []
    for by_node, by_pair in ((laplace.apply_laplacian_rows, laplace.apply_laplacian),
                             (laplace.apply_laplacian_rows_fast, laplace.apply_laplacian_fast)):
        pair_out = wp.full((grid.n_interior, 37), wp.vec4f(np.nan), dtype=wp.vec4f, device="cpu")
        wp.launch(by_pair, dim=pair_out.shape, inputs=[field, arrays["index"], arrays["active_ijk"], n_rows],
                  outputs=[pair_out], device="cpu")
        node_out = wp.full_like(pair_out, wp.vec4f(np.nan))
        wp.launch(by_node, dim=grid.n_interior, inputs=[field, arrays["neighbours"], n_rows], outputs=[node_out],
                  device="cpu")
        np.testing.assert_array_equal(node_out.numpy(), pair_out.numpy())
        results.append(node_out.numpy())
    assert not np.array_equal(*results)  # float32 and float64 sums differ somewhere: the test tells them apart
    # and what a bind calls on a CPU is the node loop
    out = wp.empty((grid.n_interior, 37), dtype=wp.vec4f, device="cpu")
    ws.apply_operator(grid, field, out, n_rows=n_rows, device="cpu", equation="laplace")
    np.testing.assert_array_equal(out.numpy(), results[0])
