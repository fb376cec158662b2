"""The batched Warp solver against an independent float64 reference (tests/reference.py) and exact facts."""

import re
import warnings

import numpy as np
import pytest
import warp as wp

import warp_stokes as ws
from conftest import float32_rounding
from reference import reference_solve, residual


def to_field(grid, full, device):
    """Dense (nx, ny, nz, H, 4) -> the solver's (active rows, H) vec4f array on `device`."""
    i, j, k = grid.active_ijk.T
    return wp.array(full[i, j, k].astype(np.float32), dtype=wp.vec4f, device=device)


def to_dense(grid, field, like):
    out = np.zeros_like(like)
    i, j, k = grid.active_ijk.T
    out[i, j, k] = field.numpy()
    return out


def ball_grid(device, n=16, h=0.1, radius=0.42):
    c = (n - 1) / 2
    idx = np.indices((n, n, n)).transpose(1, 2, 3, 0)
    mask = np.linalg.norm(idx - c, axis=-1) * h < radius * n * h / 2 * 1.6
    mask[:5], mask[-5:], mask[:, :5], mask[:, -5:], mask[:, :, :5], mask[:, :, -5:] = (False,) * 6
    mask[8:, 8:, 8:] = False  # an octant removed: a non-convex domain with re-entrant edges and corners
    return ws.grid_from_mask(mask, spacing=h, origin=(-c * h,) * 3, device=device)


def coordinates(grid):
    return grid.origin + grid.spacing * np.indices(grid.shape).transpose(1, 2, 3, 0)


POLYNOMIALS = {
    # q(x, y, z), grad q, bilaplacian of q
    "x^4": (lambda x, y, z: x**4, lambda x, y, z: (4 * x**3, 0 * x, 0 * x), lambda x, y, z: 24 + 0 * x),
    "x^2y^2z^2": (
        lambda x, y, z: x**2 * y**2 * z**2,
        lambda x, y, z: (2 * x * y**2 * z**2, 2 * y * x**2 * z**2, 2 * z * x**2 * y**2),
        lambda x, y, z: 8 * (x**2 + y**2 + z**2),
    ),
    "x^3y^2z": (
        lambda x, y, z: x**3 * y**2 * z,
        lambda x, y, z: (3 * x**2 * y**2 * z, 2 * x**3 * y * z, x**3 * y**2),
        lambda x, y, z: 24 * x * z,
    ),
}


def exact_field(grid, q, grad):
    x, y, z = np.moveaxis(coordinates(grid), -1, 0)
    g = grad(x, y, z)
    return np.stack([q(x, y, z), *(grid.spacing * gi for gi in g)], axis=-1)[:, :, :, None, :]


@pytest.mark.parametrize("name", sorted(POLYNOMIALS))
def test_operator_is_exact_on_polynomials_with_the_source_term(name, device):
    q, grad, bilap = POLYNOMIALS[name]
    grid = ball_grid(device)
    full = exact_field(grid, q, grad)
    field = to_field(grid, full, device)
    out = wp.empty((grid.n_interior, 1), dtype=wp.vec4f, device=device)
    ws.apply_operator(grid, field, out, device=device)
    x, y, z = grid.node_positions(np.arange(grid.n_interior)).T
    expected = np.zeros((grid.n_interior, 4))
    expected[:, 0] = grid.spacing**4 / 2 * bilap(x, y, z)
    got = out.numpy()[:, 0].astype(np.float64)
    scale = 48 * np.abs(full[..., 0]).max()  # size of the terms that cancel
    assert np.abs(got - expected).max() < 1e-6 * scale
    # with the opposite sign of the source term the check would fail
    assert np.abs(got[:, 0] + expected[:, 0]).max() > 100 * np.abs(got - expected).max()


def test_operator_matches_the_assembled_reference_matrix(device):
    grid = ball_grid(device)
    rng = np.random.default_rng(0)
    full = rng.normal(size=grid.shape + (3, 4))
    full[grid.labels == 0] = 0.0
    full = full.astype(np.float32).astype(np.float64)
    out = wp.empty((grid.n_interior, 3), dtype=wp.vec4f, device=device)
    ws.apply_operator(grid, to_field(grid, full, device), out, device=device)
    # the reference orders interior nodes in C order; ours lists them in C order too
    ref = -residual(grid.labels == 1, full)
    np.testing.assert_allclose(out.numpy(), ref, atol=2e-5)


@pytest.mark.parametrize("max_length,handles", [(1, 3), (2, 40), (1000, 3)])
@pytest.mark.parametrize("precise", [True, False])
def test_operator_does_not_depend_on_how_patches_are_cut(max_length, handles, precise, device):
    # the kernel walks patches of columns along z keeping three planes' terms in registers: cutting the runs
    # elsewhere (down to one plane per thread) must not change a bit; 40 handles take two thread groups, the
    # second one partly idle
    from warp_stokes.kernels import stencil

    grid = ball_grid(device)
    rng = np.random.default_rng(3)
    field = wp.array(rng.standard_normal((grid.n_active, handles, 4)).astype(np.float32), dtype=wp.vec4f,
                     device=device)
    kernel = stencil.apply_operator if precise else stencil.apply_operator_fast
    expected = walk(grid, kernel, field, device)
    np.testing.assert_array_equal(walk(grid, kernel, field, device, max_length=max_length), expected)
    # ws.apply_operator runs the walk on a GPU, the node loop on a CPU: the same bits either way
    out = wp.empty((grid.n_interior, handles), dtype=wp.vec4f, device=device)
    ws.apply_operator(grid, field, out, device=device, precise=precise)
    np.testing.assert_array_equal(out.numpy(), expected)


def walk(grid, kernel, field, device, patch=None, max_length=64, extra=()):
    """The stencil's patch walk ``kernel`` launched directly on ``device`` (a CPU's bind runs the node loop): its
    output at the interior nodes as a numpy array."""
    from warp_stokes.kernels import stencil

    patch = patch or (stencil.PATCH_I, stencil.PATCH_J)
    patches = wp.array(grid.interior_patches(patch, max_length), dtype=wp.vec4i, device=device)
    out = wp.full((grid.n_interior, field.shape[1]), wp.vec4f(np.nan), dtype=wp.vec4f, device=device)
    wp.launch(kernel, dim=(-(-field.shape[1] // stencil.GROUP), patches.shape[0], stencil.GROUP),
              inputs=[field, grid.device_arrays(device)["index"], patches, grid.n_active, *extra], outputs=[out],
              device=device)
    return out.numpy()


def test_the_one_pass_residual_is_the_difference_to_the_bit(device):
    # rhs - A x in the stencil kernel (the smoother's residuals) rounds exactly as A x followed by the subtraction
    grid = ball_grid(device)
    rng = np.random.default_rng(4)
    field = wp.array(rng.standard_normal((grid.n_interior, 40, 4)).astype(np.float32), dtype=wp.vec4f, device=device)
    rhs = rng.standard_normal((grid.n_interior, 40, 4)).astype(np.float32)
    applied = wp.empty((grid.n_interior, 40), dtype=wp.vec4f, device=device)
    ws.apply_operator(grid, field, applied, device=device, precise=False)
    out = wp.array(rhs, dtype=wp.vec4f, device=device)
    ws.apply_operator(grid, field, out, device=device, precise=False, rhs=out)  # in place, as the smoother may
    np.testing.assert_array_equal(out.numpy(), rhs - applied.numpy())


@pytest.mark.parametrize("rows", ["interior", "active"])
def test_the_cpus_node_loops_are_the_walks_to_the_bit(rows):
    # a CPU applies the operator by a thread per node looping over the handles (kernels/stencil_cpu.py), a GPU by
    # patch walks: the same sums in the same order, so the same bits, in each of the four forms (A x in float32 and
    # float64 sums, b - A x, the Chebyshev step), with rows beyond n_rows read as zero; 70 handles (two passes of the CPU's loop)
    from warp_stokes.kernels import stencil, stencil_cpu
    from warp_stokes.solver.operator import _node_loop

    grid = ball_grid("cpu")
    n_rows = grid.n_interior if rows == "interior" else grid.n_active
    rng = np.random.default_rng(6)
    field = wp.array(rng.standard_normal((grid.n_active, 70, 4)).astype(np.float32), dtype=wp.vec4f, device="cpu")
    rhs, d = (wp.array(rng.standard_normal((grid.n_interior, 70, 4)).astype(np.float32), dtype=wp.vec4f,
                       device="cpu") for _ in range(2))
    arrays = grid.device_arrays("cpu")
    assert arrays["neighbours"].shape == (grid.n_interior, stencil_cpu.NEIGHBOURS)
    patches = wp.array(grid.interior_patches((stencil.PATCH_I, stencil.PATCH_J), 64), dtype=wp.vec4i, device="cpu")
    step_patches = wp.array(grid.interior_patches(stencil.STEP_PATCH, 64), dtype=wp.vec4i, device="cpu")
    forms = [(stencil.apply_operator, stencil_cpu.apply_operator, False, False),
             (stencil.apply_operator_fast, stencil_cpu.apply_operator_fast, False, False),
             (stencil.residual_operator_fast, stencil_cpu.residual_operator_fast, True, False),
             (stencil.chebyshev_step_fast, stencil_cpu.chebyshev_step_fast, True, True)]
    walked_out = {}
    for walked, looped, takes_rhs, steps in forms:
        d_walk, d_loop = wp.clone(d), wp.clone(d)
        out = wp.full((grid.n_interior, 70), wp.vec4f(np.nan), dtype=wp.vec4f, device="cpu")
        extra = ([rhs] if takes_rhs else []) + ([0.3, 0.7, d_walk] if steps else [])
        items = step_patches if steps else patches
        wp.launch(walked, dim=(-(-70 // stencil.GROUP), items.shape[0], stencil.GROUP),
                  inputs=[field, arrays["index"], items, n_rows, *extra], outputs=[out], device="cpu")
        walked_out[looped.key] = out.numpy()
        loop_out = wp.full_like(out, wp.vec4f(np.nan))
        ca, cb = (0.3, 0.7) if steps else (0.0, 0.0)
        _node_loop(looped, arrays, field, n_rows, rhs if takes_rhs else loop_out, ca, cb, d_loop if steps else loop_out,
                   loop_out, wp.get_device("cpu"))
        np.testing.assert_array_equal(loop_out.numpy(), walked_out[looped.key], err_msg=looped.key)
        np.testing.assert_array_equal(d_loop.numpy(), d_walk.numpy(), err_msg=looped.key)
        assert np.isfinite(loop_out.numpy()).all()
    # reading the ring's rows or not changes the result (the test tells the two apart)
    other = wp.empty((grid.n_interior, 70), dtype=wp.vec4f, device="cpu")
    _node_loop(stencil_cpu.apply_operator, arrays, field, grid.n_active + grid.n_interior - n_rows, other, 0.0, 0.0,
               other, other, wp.get_device("cpu"))
    assert not np.array_equal(other.numpy(), walked_out[stencil_cpu.apply_operator.key])


@pytest.mark.parametrize("patch", [(1, 1), (3, 2)])
def test_operator_does_not_depend_on_the_patch_shape(patch, device):
    # each column's terms are summed in the same order whatever patch it sits in: other shapes give the same bits
    from warp_stokes.kernels import stencil

    grid = ball_grid(device)
    rng = np.random.default_rng(5)
    field = wp.array(rng.standard_normal((grid.n_active, 3, 4)).astype(np.float32), dtype=wp.vec4f, device=device)
    expected = wp.empty((grid.n_interior, 3), dtype=wp.vec4f, device=device)
    ws.apply_operator(grid, field, expected, device=device)
    np.testing.assert_array_equal(walk(grid, stencil.operator_kernel(wp.float64, patch), field, device, patch, 7),
                                  expected.numpy())


def test_float32_and_float64_sums_agree_to_rounding(device):
    # the two kernels share their form; the float32 one may differ only by rounding of its sums
    grid = ball_grid(device)
    rng = np.random.default_rng(4)
    field = wp.array(rng.standard_normal((grid.n_active, 5, 4)).astype(np.float32), dtype=wp.vec4f, device=device)
    out = {}
    for p in (True, False):
        out[p] = wp.empty((grid.n_interior, 5), dtype=wp.vec4f, device=device)
        ws.apply_operator(grid, field, out[p], device=device, precise=p)
    scale = np.abs(out[True].numpy()).max()
    diff = np.abs(out[True].numpy() - out[False].numpy()).max()
    assert 0 < diff <= 1e-5 * scale


def make_preconditioner(name, grid, device):
    """'jacobi', or multigrid with a small coarsest level so that even these small grids have 3+ levels."""
    if name == "jacobi":
        return "jacobi"
    mg = ws.Multigrid(grid, device=device, coarsest_nodes=10)
    assert len(mg.levels) >= 3, mg.level_sizes
    return mg


@pytest.mark.parametrize("preconditioner", ["jacobi", "multigrid"])
def test_solver_matches_direct_float64_solve_on_a_masked_domain(preconditioner, device):
    grid = ball_grid(device)
    rng = np.random.default_rng(1)
    # smooth but non-polynomial data on the ring, three handles
    x, y, z = np.moveaxis(coordinates(grid), -1, 0)
    cols = []
    for _ in range(3):
        a, b, c = rng.normal(size=3) * 3
        q = np.sin(a * x + 0.3) * np.cos(b * y) + np.exp(c * z / 3)
        gx = a * np.cos(a * x + 0.3) * np.cos(b * y)
        gy = -b * np.sin(a * x + 0.3) * np.sin(b * y)
        gz = c / 3 * np.exp(c * z / 3)
        cols.append(np.stack([q, grid.spacing * gx, grid.spacing * gy, grid.spacing * gz], -1))
    full = np.stack(cols, axis=3)
    known = full.copy()
    known[grid.labels == 1] = 0.0  # the solver starts from zero inside
    ref = reference_solve(grid.labels == 1, full.astype(np.float32).astype(np.float64))
    field = to_field(grid, known, device)
    report = ws.solve_biharmonic(grid, field, tol=1e-7, device=device,
                                 preconditioner=make_preconditioner(preconditioner, grid, device))
    got = to_dense(grid, field, full)
    inside = grid.labels == 1
    err = np.abs(got[inside] - ref[inside]).max()
    assert err <= 1e-5, f"max |warp - reference| = {err:.2e}"
    assert report.iterations >= 3 and report.residual <= 1e-6


@pytest.mark.parametrize("preconditioner", ["jacobi", "multigrid"])
def test_stokes_weights_match_direct_solve_on_a_real_cage(arm_cage, preconditioner, device):
    grid = ws.voxelize(arm_cage, resolution=18, device=device)
    field = ws.boundary_field(grid, arm_cage, device=device)
    known = to_dense(grid, field, np.zeros(grid.shape + (arm_cage.n_handles, 4)))
    ref = reference_solve(grid.labels == 1, known)
    report = ws.solve_biharmonic(grid, field, tol=1e-6, handles=arm_cage.vertices, device=device,
                                 preconditioner=make_preconditioner(preconditioner, grid, device))
    got = to_dense(grid, field, known)
    inside = grid.labels == 1
    err = np.abs(got[inside] - ref[inside]).max()
    assert report.converged
    assert err <= 1e-5, f"max weight error {err:.2e} against the direct solve"
    # the reference reproduces constants from our (float32-rounded) boundary data: the data is right
    # (each boundary value rounded once to float32: 8 eps of the boundary's sums of magnitudes)
    assert np.abs(ref[inside][..., 0].sum(-1) - 1).max() < float32_rounding(np.abs(known[..., 0]).sum(-1).max())
    print(f"arm, resolution 18, {preconditioner}: {report.iterations} iterations, max weight error {err:.2e} "
          "against the direct solve")


def test_callback_sees_each_iterate_approach_the_direct_solve(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=18, device=device)
    field = ws.boundary_field(grid, arm_cage, device=device)
    known = to_dense(grid, field, np.zeros(grid.shape + (arm_cage.n_handles, 4)))
    ref = reference_solve(grid.labels == 1, known)
    inside = grid.labels == 1
    history = []

    def record(iteration, current):
        history.append((iteration, np.abs(to_dense(grid, current, known)[inside] - ref[inside]).max()))

    report = ws.solve_biharmonic(grid, field, tol=1e-6, handles=arm_cage.vertices, device=device,
                                 preconditioner=make_preconditioner("multigrid", grid, device), callback=record)
    assert [i for i, _ in history] == list(range(report.iterations + 1))
    errors = np.array([e for _, e in history])
    print("max weight error per iteration:", " ".join(f"{e:.1e}" for e in errors))
    assert errors[0] > 1e-3  # the MVC start is not the solution
    assert errors[-1] == np.abs(to_dense(grid, field, known)[inside] - ref[inside]).max() <= 1e-5
    assert errors[5] < 1e-2 * errors[0]  # multigrid CG: two orders of magnitude in five iterations


def test_failing_identity_check_keeps_cg_correct_and_stops_at_stagnation(arm_cage, device):
    # Handle positions that are not the cage's (stretched by 1.2 along y): "linear precision" cannot hold for the
    # solution, so the identity check fails at every iteration. The starting guess at the interior nodes is the
    # mean value coordinates of the stretched cage, which do reproduce those positions: the check's float32 floor,
    # measured on the starting field, stays tiny and the identity tolerance stays at tol. The boundary data is the
    # real cage's, so the solution is not changed by any of this. CG must go on (every handle resuming its own
    # iteration, some after having stopped), stop when the check stagnates, restart, warn, and still return the
    # right weights.
    grid = ws.voxelize(arm_cage, resolution=18, device=device)
    field = ws.boundary_field(grid, arm_cage, device=device)
    known = to_dense(grid, field, np.zeros(grid.shape + (arm_cage.n_handles, 4)))
    ref = reference_solve(grid.labels == 1, known)
    stretched = arm_cage.vertices * np.array([1.0, 1.2, 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the arm cage's folded edges, stretched
        stretched_cage = ws.check_cage((stretched, arm_cage.faces))
    data = field.numpy()
    interior = grid.node_positions(np.arange(grid.n_interior)) + grid.centre
    data[: grid.n_interior, :, 0] = ws.mean_value_coordinates(stretched_cage, interior, device=device)
    field = wp.array(data, dtype=wp.vec4f, device=device)
    n_cols = field.shape[1]
    multigrid = make_preconditioner("multigrid", grid, device)
    # the same solve without the check (no handles): CG stops once every residual is small
    plain = ws.solve_biharmonic(grid, wp.clone(field), tol=1e-6, device=device, preconditioner=multigrid)
    assert plain.converged
    moved, last = [], [data[: grid.n_interior].copy()]

    def record(iteration, current):  # how many handles' weights this iteration changed
        now = current.numpy()[: grid.n_interior].copy()  # (on the CPU, numpy() is a view of the field)
        if iteration > 0:
            moved.append(int((now != last[0]).any(axis=(0, 2)).sum()))
        last[0] = now

    # the data does not reproduce the stretched positions: an error that says so, the field holding the solution
    with pytest.raises(ws.ConvergenceError, match=r"the boundary data does not reproduce constant and linear "
                       "functions") as failure:
        ws.solve_biharmonic(grid, field, tol=1e-6, handles=stretched, device=device, callback=record,
                            preconditioner=multigrid)
    report = failure.value.report
    assert not report.converged and report.identity_error > 1e-3 and report.recoveries == []
    assert all(identity > 1e-3 for _, _, identity in report.rounds)  # it failed in every round
    # stopped by stagnation of the check in every round, not by the iteration limit (200)
    assert report.restarts == ws.solver.solve.MAX_RESTARTS and report.iterations < 120
    assert len(report.rounds) == report.restarts + 1 and len(moved) == report.iterations
    # The first round takes the same iterations as the plain solve (the check does not change the iterates),
    # with some handles stopping on their residual before the others, and then goes on: the check failed, every
    # handle resumed its own iteration, and the check ran after each one until it had not improved three times.
    small = plain.rounds[0][0]
    assert 0 < moved[small - 1] < n_cols, moved
    assert report.rounds[0][0] >= small + 3 and set(moved[small : report.rounds[0][0]]) == {n_cols}, moved
    inside = grid.labels == 1
    err = np.abs(to_dense(grid, field, known)[inside] - ref[inside]).max()
    assert err <= 1e-5, f"max weight error {err:.2e} against the direct solve"


def test_a_chunk_is_checked_through_its_complement_columns(arm_cage, device):
    # A chunk of handles and the column that stands for the rest of the cage: the solver checks the chunk's
    # partition of unity, converges on it, and matches the direct float64 solve.
    grid = ws.voxelize(arm_cage, resolution=18, device=device)
    chunk = slice(10, 30)
    field = ws.boundary_field(grid, arm_cage, device=device, handles=chunk, complement=True)
    known = to_dense(grid, field, np.zeros(grid.shape + (field.shape[1], 4)))
    ref = reference_solve(grid.labels == 1, known)
    report = ws.solve_biharmonic(grid, field, tol=1e-6, handles=arm_cage.vertices, chunk=chunk, device=device,
                                 preconditioner=make_preconditioner("multigrid", grid, device))
    assert report.converged and 0 < report.identity_error <= 1e-6
    inside = grid.labels == 1
    err = np.abs(to_dense(grid, field, known)[inside] - ref[inside]).max()
    assert err <= 1e-5, f"max weight error {err:.2e} against the direct solve"

    # the check can fail: complement data 1% off at the boundary breaks partition of unity for good
    bad = ws.boundary_field(grid, arm_cage, device=device, handles=chunk, complement=True).numpy()
    bad[grid.n_interior :, 20] *= 1.01
    bad = wp.array(bad, dtype=wp.vec4f, device=device)
    with pytest.raises(ws.ConvergenceError, match=r"the boundary data does not reproduce constant and linear "
                       r"functions \(deviation 0\.0\d+ at the ring and band nodes\)"):
        ws.solve_biharmonic(grid, bad, tol=1e-6, handles=arm_cage.vertices, chunk=chunk, device=device,
                            max_iterations=40, preconditioner=make_preconditioner("multigrid", grid, device))

    # a chunk's field without the complement columns is refused, saying what was expected
    plain = ws.boundary_field(grid, arm_cage, device=device, handles=chunk)
    with pytest.raises(ValueError, match=r"has 20 columns; the identity check expects 21 \(20 handles of the chunk"):
        ws.solve_biharmonic(grid, plain, handles=arm_cage.vertices, chunk=chunk, device=device)


def manufactured_error(n, device):
    """Max error in q for q = sin kx sin ky sin kz on the box [0, 1]^3 with k = 2 pi (a full period, so the
    discretisation error stands well above float32 round-off); its bilaplacian is 9 k^4 q."""
    h = 1.0 / n
    m = ws.geometry.grid.MARGIN
    size = n + 1 + 2 * m
    mask = np.zeros((size,) * 3, bool)
    mask[m + 1 : m + n, m + 1 : m + n, m + 1 : m + n] = True
    grid = ws.grid_from_mask(mask, spacing=h, origin=(-m * h,) * 3, device=device)
    k = 2 * np.pi
    x, y, z = np.moveaxis(k * coordinates(grid), -1, 0)
    s, c = np.sin, np.cos
    full = np.stack([s(x) * s(y) * s(z), k * h * c(x) * s(y) * s(z), k * h * s(x) * c(y) * s(z),
                     k * h * s(x) * s(y) * c(z)], -1)[:, :, :, None]
    known = full.copy()
    known[mask] = 0.0
    field = to_field(grid, known, device)
    pos = grid.node_positions(np.arange(grid.n_interior))
    f = 9 * k**4 * np.prod(np.sin(k * pos), axis=1)[:, None]
    with warnings.catch_warnings():  # n=32 ends at float32 round-off, far below the error measured here
        warnings.simplefilter("ignore")
        ws.solve_biharmonic(grid, field, tol=1e-6, source=f, device=device)
    got = to_dense(grid, field, full)
    return np.abs(got[mask][..., 0] - full[mask][..., 0]).max()


def test_manufactured_solution_converges_at_second_order(device):
    errors = {n: manufactured_error(n, device) for n in (8, 16, 32)}
    for n in (16, 32):
        ratio = errors[n // 2] / errors[n]
        print(f"manufactured solution: n={n} max error {errors[n]:.3e}, ratio {ratio:.2f} per halving of h")
        assert 3.4 < ratio < 4.6, f"error ratio {ratio:.2f} from n={n // 2} to n={n} (errors {errors})"


def test_iteration_limit_warns_and_reports(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=12, device=device)
    field = ws.boundary_field(grid, arm_cage, device=device)
    # without the handles (no identity check) the field is what the solver reached, and a warning says why
    with pytest.warns(UserWarning, match="iteration limit reached"):
        report = ws.solve_biharmonic(grid, field, max_iterations=3, device=device, preconditioner="jacobi")
    assert not report.converged and report.iterations == 3
    # cage coordinates that break partition of unity or linear precision are an error, whose advice holds
    field = ws.boundary_field(grid, arm_cage, device=device)
    with pytest.raises(ws.ConvergenceError, match=r"reached its iteration limit \(3\) while still converging "
                       r"\(residual [\d.e+-]+ to [\d.e+-]+\); raise the limit"):
        ws.solve_biharmonic(grid, field, max_iterations=3, handles=arm_cage.vertices, device=device,
                            preconditioner="jacobi")


# -- faults: the watchdog and the preconditioners taken after it ---------------------------------------------------

def bind_arm(device, **options):
    from conftest import EXAMPLE

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # one thread: one solve's ladder (threads' chunks each recover on their own: tests/test_cli.py)
        b = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=24, device=device,
                    **{"threads": 1, **options})
    return b, [str(w.message) for w in caught if "the solver's" in str(w.message)]


@pytest.fixture(scope="module")
def healthy(device):
    return bind_arm(device)[0]


def test_an_underestimated_smoother_bound_is_caught_and_the_bound_guaranteed(healthy, arm_cage, device, monkeypatch):
    # smoothers whose interval ends at 0.3 of the largest eigenvalue amplify the modes above it: the cycle is no
    # longer positive definite, which the first residual shows; the same cycle with row-sum bounds converges
    from warp_stokes.solver import multigrid

    monkeypatch.setattr(multigrid, "LMAX_SAFETY", 0.3)
    b, warned = bind_arm(device)
    s = b.stats
    # a callback numbers the iterations of the whole solve, across the switch
    grid = ws.voxelize(arm_cage, 20, device=device)
    numbers = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        report = ws.solve_biharmonic(grid, ws.boundary_field(grid, arm_cage, device=device), device=device,
                                     handles=arm_cage.vertices, callback=lambda k, field: numbers.append(k))
    assert len(report.recoveries) == 1 and numbers == list(range(report.iterations + 1))
    assert [(e["preconditioner"], e["next"]) for e in s.solver.recoveries] == [
        ("multigrid", "multigrid with guaranteed smoother bounds")]
    # which sign comes first (r^T M r < 0, growth, a residual not finite) depends on the order of float sums
    assert re.match(r"the preconditioner is not positive definite|the residual (grew|is not finite)",
                    s.solver.recoveries[0]["fault"]), s.solver.recoveries
    assert s.converged and s.solver.iterations <= 12 and s.solver.preconditioners == [
        "multigrid with guaranteed smoother bounds"]
    assert len(warned) == 1 and "went on with multigrid with guaranteed smoother bounds" in warned[0]
    assert np.abs(b.weights - healthy.weights).max() <= 1e-5


def test_a_singular_coarsest_inverse_falls_back_to_the_inverse_diagonal(healthy, device, monkeypatch):
    # the fault of issue 29 (an unchecked inverse of a singular coarsest operator, entries of 1e34), forced: no
    # smoother bound helps, the inverse diagonal converges, and the weights are those of a healthy bind
    from warp_stokes.solver import multigrid

    original = multigrid.coarsest_inverse

    def blown_up(dense):
        inverse, seconds, report = original(dense)
        inverse[0, :] = inverse[:, 0] = 1e34
        return inverse, seconds, report

    monkeypatch.setattr(multigrid, "coarsest_inverse", blown_up)
    b, warned = bind_arm(device)
    s = b.stats
    assert [e["preconditioner"] for e in s.solver.recoveries] == ["multigrid", "multigrid with guaranteed smoother bounds"]
    assert s.solver.preconditioners == ["jacobi"] and s.converged and len(warned) == 2
    assert max(s.partition_of_unity_error, s.linear_precision_error) <= 1e-5
    assert np.abs(b.weights - healthy.weights).max() <= 1e-5


def test_a_stagnating_preconditioner_is_caught(healthy, device, monkeypatch):
    # a cycle that does nothing (z = r: plain CG, hundreds of iterations here) stagnates within a few dozen
    from warp_stokes.solver import multigrid

    monkeypatch.setattr(multigrid.Multigrid, "apply", lambda self, r, z: wp.copy(z, r))
    b, warned = bind_arm(device)
    faults = [e["fault"] for e in b.stats.solver.recoveries]
    assert len(faults) == 2 and all(f.startswith("the residual stagnates") for f in faults), faults
    assert b.stats.solver.recoveries[0]["iteration"] <= 30 and b.stats.converged
    assert np.abs(b.weights - healthy.weights).max() <= 1e-5


def test_when_every_preconditioner_fails_no_weights_are_returned(device, monkeypatch):
    from warp_stokes.solver import multigrid, solve

    def broken(r, z):  # negative definite
        wp.launch(ws.kernels.cg.negate, dim=r.shape, inputs=[r], outputs=[z])

    monkeypatch.setattr(multigrid.Multigrid, "apply", lambda self, r, z: broken(r, z))
    monkeypatch.setattr(solve, "jacobi_step", lambda equation, device: broken)
    with pytest.raises(ws.ConvergenceError) as failure:
        bind_arm(device)
    message = str(failure.value)
    assert message.startswith("the solver could not bring partition of unity and linear precision within 1e-05")
    assert ("with multigrid, then multigrid with guaranteed smoother bounds, then jacobi); no weights were "
            "returned: the preconditioner is not positive definite") in message
    assert message.endswith("a fault of the solver on this cage at this resolution; please report it with the cage")
    assert [e["preconditioner"] for e in failure.value.report.recoveries] == [
        "multigrid", "multigrid with guaranteed smoother bounds", "jacobi"]


def test_a_column_that_is_not_finite_is_restarted_alone(arm_cage, device):
    # after a fault that left NaN in one handle's iterate, its residual is NaN and the others' are measured as
    # before (their scales do not take the NaN in): only that column is restarted from zero
    from warp_stokes.solver.krylov import BatchedCG

    grid = ws.voxelize(arm_cage, 16, device=device)
    field = ws.boundary_field(grid, arm_cage, device=device)
    with wp.ScopedDevice(device):  # as the solve runs it (its vectors on its device, not the default one)
        clean = BatchedCG(grid, wp.clone(field), None, ws.solver.preconditioner.jacobi_step("biharmonic", ws.Backend.of(device)),
                          ws.Backend.of(device)).start()
        data = field.numpy()
        data[: grid.n_interior, 7] = np.nan
        broken = BatchedCG(grid, wp.array(data, dtype=wp.vec4f, device=device), None,
                           ws.solver.preconditioner.jacobi_step("biharmonic", ws.Backend.of(device)), ws.Backend.of(device))
        rel = broken.start()
        assert np.isnan(rel[7]) and np.isfinite(np.delete(rel, 7)).all()
        np.testing.assert_allclose(np.delete(rel, 7), np.delete(clean, 7), rtol=1e-6)
        broken.clear(~np.isfinite(rel))
        assert np.isfinite(broken.start()).all()


def test_a_chunked_bind_whose_weights_break_linear_precision_is_refused(monkeypatch):
    # a chunk checks partition of unity alone: linear precision of the sampled weights of all chunks is checked by
    # the bind (forced here)
    from warp_stokes.binding import pipeline

    monkeypatch.setattr(pipeline, "identity_errors", lambda weights, handles, points: (1e-7, 3e-3))
    with pytest.raises(ws.ConvergenceError, match=r"arm_cage.obj: the weights of .*arm.obj break partition of unity "
                       r"\(1e-07\) or linear precision \(0.003 of the diagonal\) beyond 1e-05 although every "
                       r"solve converged \([2-9] chunk\(s\)\); no weights were returned"):
        bind_arm("cpu", memory_budget=9 * 2**20)  # a few chunks on the CPU


@pytest.mark.parametrize("rows, handles, blocks", [(1000, 70, 16), (5, 3, 16), (0, 2, 16), (97, 64, 1)])
def test_the_cpus_column_dots_are_the_float64_sums(rows, handles, blocks):
    # CG's dot products on a CPU (kernels/cg_cpu.py: a thread per block of rows, 64 handles a pass) against float64
    # sums, for more handles than a pass, more blocks than rows, no rows; each handle's sum does not depend on the
    # other handles (threads solving chunks of handles at once give one thread's bits)
    from warp_stokes.kernels import cg_cpu

    rng = np.random.default_rng(rows + handles)
    a, b = (rng.standard_normal((rows, handles, 4)).astype(np.float32) for _ in range(2))

    def dots(a, b):
        out = wp.zeros(a.shape[1], dtype=wp.float64, device="cpu")
        wp.launch(cg_cpu.column_dots_rows, dim=blocks, inputs=[wp.array(a, dtype=wp.vec4f, device="cpu"),
                                                              wp.array(b, dtype=wp.vec4f, device="cpu"), blocks],
                  outputs=[out], device="cpu")
        return out.numpy()

    got = dots(a, b)
    expected = np.einsum("nhk,nhk->h", a.astype(np.float64), b.astype(np.float64))
    # each row's 4-term dot is formed in float32 (as cg.column_dots forms it): at most 4 roundings of its terms' size
    bound = 4 * 2.0**-24 * np.abs(a.astype(np.float64) * b).sum(axis=(0, 2))
    assert (np.abs(got - expected) <= bound).all()
    if handles > 2:
        np.testing.assert_array_equal(dots(a[:, 1:3], b[:, 1:3]), got[1:3])


def test_the_cpus_operator_refuses_columns_that_are_not_consecutive():
    # the CPU's C++ node loop reads a row's handles as consecutive vec4s: a column slice with a step is refused, not
    # read wrong; a slice of the first columns (the multigrid's smaller chunks) is fine
    grid = ball_grid("cpu")
    field = wp.zeros((grid.n_active, 6), dtype=wp.vec4f, device="cpu")
    out = wp.zeros((grid.n_interior, 6), dtype=wp.vec4f, device="cpu")
    ws.apply_operator(grid, field[:, :3], out[:, :3], device="cpu")
    with pytest.raises(ValueError, match="consecutive"):
        ws.apply_operator(grid, field[:, ::2], out[:, :3], device="cpu")
