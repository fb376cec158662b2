"""The multigrid preconditioner: its parts against exact facts, and level-independent CG iterations."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import warp as wp

import warp_stokes as ws
from conftest import box_cage


def to_scipy(triplets, n_rows, n_cols):
    rows, cols, blocks = triplets
    r = (4 * rows[:, None, None] + np.arange(4)[None, :, None]).repeat(4, axis=2)
    c = (4 * cols[:, None, None] + np.arange(4)[None, None, :]).repeat(4, axis=1)
    return sp.csr_matrix((blocks.astype(np.float64).ravel(), (r.ravel(), c.ravel())), shape=(4 * n_rows, 4 * n_cols))


@pytest.fixture(scope="module")
def arm_hierarchy(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=40, device=device)
    return grid, ws.Multigrid(grid, device=device, coarsest_nodes=60)


def test_levels_shrink_and_coarse_operators_are_galerkin_products(arm_hierarchy):
    grid, mg = arm_hierarchy
    sizes = mg.level_sizes
    assert len(sizes) >= 3 and sizes[0] == grid.n_interior
    assert all(0.08 < b / a < 0.3 for a, b in zip(sizes, sizes[1:])), sizes
    from reference import assemble

    fine = assemble(grid.labels == 1)[0]  # the reference's independent assembly of A_II
    n = mg.level_sizes
    assert abs(to_scipy(mg.operator_triplets(0), n[0], n[0]) - fine).max() == 0
    # every coarse level against P^T A P of the level above, formed with scipy from the reference matrix
    A = fine
    for depth in range(1, len(n)):
        P = to_scipy(mg.prolongation_triplets(depth - 1), n[depth - 1], n[depth])
        expected = (P.T @ A @ P).tocsr()
        A = to_scipy(mg.operator_triplets(depth), n[depth], n[depth])
        assert abs(A - expected).max() <= 2e-6 * abs(expected).max(), depth
        assert abs(A - A.T).max() <= 2e-6 * abs(A).max()
        # the Galerkin stencil of the coarse levels: 27 neighbours at most, all within one lattice step
        rows, cols, _ = mg.operator_triplets(depth)
        lev = mg.levels[depth]
        assert np.abs(lev.ijk[rows] - lev.ijk[cols]).max() <= 1
        assert np.bincount(rows).max() <= 27


def test_the_coarsest_inverse_inverts_the_coarsest_operator(arm_hierarchy):
    grid, mg = arm_hierarchy
    depth = len(mg.levels) - 1
    n = mg.level_sizes[depth]
    dense = to_scipy(mg.operator_triplets(depth), n, n).toarray()
    inverse = mg.coarse_inverse.numpy().astype(np.float64)  # waits for the host thread the first time
    assert inverse.shape == (4 * n, 4 * n) and mg.coarse_inverse is mg.coarse_inverse
    assert np.abs(inverse @ dense - np.eye(4 * n)).max() < 1e-3
    assert mg.seconds["coarsest"] > 0


def test_the_coarsest_inverse_on_a_host_thread_is_the_one_computed_in_turn(arm_hierarchy, device, monkeypatch):
    # GPUs invert on a host thread (the CPU in turn): the same matrix, bit for bit, once the thread is done
    import threading

    from warp_stokes.solver import multigrid

    grid, in_turn = arm_hierarchy
    threads = []
    invert = multigrid.coarsest_inverse
    monkeypatch.setattr(multigrid, "coarsest_inverse", lambda dense: threads.append(threading.current_thread().name)
                        or invert(dense))
    monkeypatch.setattr(multigrid, "_inverts_beside", lambda device: True)
    beside = ws.Multigrid(grid, device=device, coarsest_nodes=60)
    assert np.array_equal(beside.coarse_inverse.numpy(), in_turn.coarse_inverse.numpy())
    assert len(threads) == 1 and threads[0].startswith("warp-stokes-coarsest")
    assert beside.seconds["coarsest"] > 0 and beside.seconds["coarsest_wait"] >= 0


def test_the_smoothers_largest_eigenvalues_are_estimated_from_below_against_scipy(arm_hierarchy):
    # lmax of D^-1 A per level, from the replayed power iteration, against scipy's (D the 4 x 4 diagonal blocks):
    # the estimate approaches it from below (|D^-1 A v| for a unit v may pass it slightly: D^-1 A is not symmetric),
    # and the smoother's end is LMAX_SAFETY above the estimate
    import scipy.sparse.linalg as spla

    from warp_stokes.solver.multigrid import LMAX_SAFETY

    grid, mg = arm_hierarchy
    for depth in (0, 1):
        n = mg.level_sizes[depth]
        A = to_scipy(mg.operator_triplets(depth), n, n)
        inv_diag = mg.levels[depth].inv_diag.numpy().astype(np.float64)
        blocks = np.broadcast_to(inv_diag, (n, 4, 4)) if len(inv_diag) == 1 else inv_diag
        D_inv = sp.block_diag(list(blocks), format="csr")
        exact = abs(spla.eigs(D_inv @ A, k=1, which="LM", return_eigenvectors=False)[0])
        estimate = mg.levels[depth].lmax / LMAX_SAFETY
        assert 0.9 * exact <= estimate <= 1.01 * exact, (depth, estimate, exact)


def test_hierarchy_memory_is_known_before_it_is_formed(arm_hierarchy, device):
    grid, mg = arm_hierarchy
    levels = ws.coarsen(grid, device, coarsest_nodes=60)
    assert [lev.n for lev in levels] == mg.level_sizes
    # the planner's figure, from the level sizes alone, is what the formed hierarchy's arrays hold
    assert ws.solver.multigrid.hierarchy_bytes(levels) == mg.operator_bytes()


def test_a_grid_beyond_the_row_limit_is_refused_naming_a_resolution_that_fits(arm_cage, device):
    # the limit is 2**31 - 1 rows; lowered here so that a small grid meets it
    limit = ws.voxelize(arm_cage, 24, device=device).n_active
    with pytest.raises(ws.ResolutionError, match=r"resolution 32 gives [\d,]+ active grid nodes, more than the "
                       r"[\d,]+ that 32-bit rows can number; resolution (\d+) or less would fit") as e:
        ws.voxelize(arm_cage, 32, device=device, max_rows=limit)
    suggested = int(str(e.value).split("resolution ")[-1].split(" or less")[0])
    assert 8 <= suggested < 32
    assert ws.voxelize(arm_cage, suggested, device=device, max_rows=limit).n_active <= limit


def test_a_recorded_operator_launch_replays_the_product_against_scipy(arm_hierarchy, device):
    # the power iteration replays recorded launches: the replay computes A x like a launch, and follows the arrays'
    # contents (not their values when recorded)
    grid, mg = arm_hierarchy
    rng = np.random.default_rng(7)
    for depth in (0, 1):
        n = mg.level_sizes[depth]
        A = to_scipy(mg.operator_triplets(depth), n, n)
        x = wp.zeros((n, 2), dtype=wp.vec4f, device=device)
        out = wp.empty_like(x)
        launch = mg._apply_A(depth, x, out, record_cmd=True)
        assert isinstance(launch, wp.Launch)
        for _ in range(2):
            x_np = rng.standard_normal((n, 2, 4)).astype(np.float32)
            x.assign(x_np)
            launch.launch()
            expected = (A @ x_np.transpose(0, 2, 1).reshape(4 * n, 2)).reshape(n, 4, 2).transpose(0, 2, 1)
            assert np.abs(out.numpy() - expected).max() <= 1e-4 * np.abs(expected).max()
    with pytest.raises(ValueError, match="two passes"):
        ws.solver.operator.apply_operator(grid, x, out, device=device, rhs=wp.empty_like(out), record_cmd=True)


def test_residuals_in_one_pass_match_the_operator_against_scipy(arm_hierarchy, device):
    # the smoother's r = b - A x in one kernel, on the fine level (the compact scheme, float32 sums) and on a coarse
    # level (the Galerkin blocks), against b - A x with the scipy matrices of operator_triplets (float64)
    grid, mg = arm_hierarchy
    rng = np.random.default_rng(5)
    for depth in (0, 1):
        n = mg.level_sizes[depth]
        x_np = rng.standard_normal((n, 3, 4)).astype(np.float32)
        b_np = rng.standard_normal((n, 3, 4)).astype(np.float32)
        x, b = (wp.array(a, dtype=wp.vec4f, device=device) for a in (x_np, b_np))
        r = wp.empty_like(b)
        mg._residual(depth, b, x, r)
        A = to_scipy(mg.operator_triplets(depth), n, n)
        for h in range(3):
            expected = b_np[:, h].ravel().astype(np.float64) - A @ x_np[:, h].ravel().astype(np.float64)
            scale = np.abs(expected).max()
            assert np.abs(r.numpy()[:, h].ravel() - expected).max() < 1e-5 * scale


def test_chebyshev_steps_in_one_pass_match_the_residual_and_the_step_against_scipy(arm_hierarchy, device):
    # the smoother's step d = ca d + cb D^-1 (b - A x), x_next = x + d in one kernel (fine scheme, coarse blocks):
    # against the same formed in float64 from the scipy matrices and the level's diagonal blocks; and refusing to
    # write the iterate it reads
    grid, mg = arm_hierarchy
    rng = np.random.default_rng(6)
    ca, cb = 0.3, 0.7
    for depth in (0, 1):
        lev, n = mg.levels[depth], mg.level_sizes[depth]
        x_np, b_np, d_np = (rng.standard_normal((n, 3, 4)).astype(np.float32) for _ in range(3))
        x, b, d = (wp.array(a, dtype=wp.vec4f, device=device) for a in (x_np, b_np, d_np))
        x_next = wp.empty_like(x)
        assert mg._chebyshev_step(depth, b, x, d, ca, cb, x_next)  # one pass into x_next
        A = to_scipy(mg.operator_triplets(depth), n, n)
        inv = lev.inv_diag.numpy().astype(np.float64)
        inv = np.broadcast_to(inv, (n, 4, 4)) if len(inv) == 1 else inv
        for h in range(3):
            r = (b_np[:, h].ravel().astype(np.float64) - A @ x_np[:, h].ravel().astype(np.float64)).reshape(n, 4)
            step = ca * d_np[:, h] + cb * np.einsum("nij,nj->ni", inv, r)
            scale = np.abs(step).max()
            assert np.abs(d.numpy()[:, h] - step).max() < 1e-5 * scale
            assert np.abs(x_next.numpy()[:, h] - (x_np[:, h] + step)).max() < 1e-5 * scale
    with pytest.raises(ValueError, match="out must not be field"):
        ws.solver.operator.chebyshev_step(grid, x, b, d, ca, cb, x, n_rows=n, device=device)


def test_the_cpus_row_loops_give_the_bits_of_the_node_handle_launches(arm_hierarchy, device):
    # a CPU smooths the coarse levels by a thread per row looping over the handles, a GPU by a thread per row and
    # handle: the same sums in the same order (the residual and the Chebyshev step), on every coarse level
    # (the CPU's row loops in C++, COLUMNS_PER_PASS = 64 handles a pass: 70 handles take two passes)
    from warp_stokes.kernels import multigrid as mg_kernels
    from warp_stokes.kernels import multigrid_cpu

    if device != "cpu":
        pytest.skip("the row loops run on a CPU only")

    grid, mg = arm_hierarchy
    rng = np.random.default_rng(8)
    for depth in range(1, len(mg.levels) - 1):
        lev, n = mg.levels[depth], mg.level_sizes[depth]
        x, b, d = (wp.array(rng.standard_normal((n, 70, 4)).astype(np.float32), dtype=wp.vec4f, device=device)
                   for _ in range(3))
        out = {}
        for form, by_row in (("gpu", False), ("cpu", True)):
            r, x_next, d_form = wp.empty_like(b), wp.empty_like(x), wp.clone(d)
            wp.launch(multigrid_cpu.stencil_residual_rows if by_row else mg_kernels.stencil_residual,
                      dim=n if by_row else b.shape, inputs=[lev.blocks, lev.rows, b, x], outputs=[r], device=device)
            wp.launch(multigrid_cpu.stencil_chebyshev_step_rows if by_row else mg_kernels.stencil_chebyshev_step,
                      dim=n if by_row else b.shape, inputs=[lev.blocks, lev.rows, b, x, lev.inv_diag, 0.3, 0.7, d_form],
                      outputs=[x_next], device=device)
            out[form] = (r.numpy(), x_next.numpy(), d_form.numpy())
        assert not np.array_equal(out["cpu"][0], b.numpy())  # the operator did something
        for gpu, cpu in zip(out["gpu"], out["cpu"]):
            np.testing.assert_array_equal(cpu, gpu)


def test_hermite_prolongation_is_exact_for_cubics_along_axes(device):
    v, f = box_cage(lo=(-1, -1, -1), hi=(1, 1, 1))
    grid = ws.voxelize(ws.check_cage((v, f)), resolution=24, device=device)
    mg = ws.Multigrid(grid, device=device, coarsest_nodes=50)
    fine, coarse = mg.levels[0], mg.levels[1]

    def field(ijk, spacing):
        x = grid.origin + spacing * ijk
        q = x[:, 0] ** 3 + 2 * x[:, 1] ** 3 - x[:, 2] ** 3 + 0.5 * x[:, 0] - x[:, 2] + 3
        g = np.stack([3 * x[:, 0] ** 2 + 0.5, 6 * x[:, 1] ** 2, -3 * x[:, 2] ** 2 - 1], 1) * spacing
        return np.concatenate([q[:, None], g], 1)

    h = grid.spacing
    exact_fine = field(fine.ijk, h)
    coarse_values = field(coarse.ijk, 2 * h)
    triplets = mg.prolongation_triplets(0)
    P = to_scipy(triplets, fine.n, coarse.n)
    got = (P @ coarse_values.reshape(-1)).reshape(-1, 4)
    # fine nodes all of whose parents are coarse nodes (away from the masked boundary)
    counts = np.bincount(triplets[0], minlength=fine.n)
    parity = fine.ijk % 2
    complete = counts == 2 ** parity.sum(1)
    assert complete.mean() > 0.5
    np.testing.assert_allclose(got[complete], exact_fine[complete], atol=1e-5 * np.abs(exact_fine).max())


def test_a_thin_sheet_keeps_coarsening_on_a_shifted_lattice(device):
    # A sheet of unknowns one node thick at an odd z: no coarse node sits over one on the unshifted lattice (the
    # hierarchy would stop at the fine level, inverted densely), and the rule that kept nodes for the unknowns around
    # them put two coarse layers over the one sheet (singular). The coarse lattice shifts by one finer step along z:
    # every level is P^T A P of the one above with P's shift (formed with scipy), P keeps a diagonal block per coarse
    # node (P^T P >= 1/4), and CG with the cycle reaches the direct solve.
    from reference import assemble, reference_solve

    mask = np.zeros((46, 46, 12), bool)
    mask[5:41, 5:41, 5] = True
    grid = ws.grid_from_mask(mask, spacing=0.1, device=device)
    mg = ws.Multigrid(grid, device=device, coarsest_nodes=40)
    assert len(mg.levels) >= 3 and mg.levels[1].shift == (0, 0, 1), (mg.level_sizes, [lv.shift for lv in mg.levels])
    A = assemble(grid.labels == 1)[0]
    n = mg.level_sizes
    for depth in range(1, len(n)):
        P = to_scipy(mg.prolongation_triplets(depth - 1), n[depth - 1], n[depth])
        assert np.linalg.eigvalsh((P.T @ P).toarray()).min() >= 0.25 - 1e-6, depth
        expected = (P.T @ A @ P).tocsr()
        A = to_scipy(mg.operator_triplets(depth), n[depth], n[depth])
        assert abs(A - expected).max() <= 2e-6 * abs(expected).max(), depth
    assert mg.coarsest["smallest_eigenvalue"] > 1e-4
    # the cycle's own transfers on the shifted lattices are P^T and P
    rng = np.random.default_rng(3)
    from warp_stokes.kernels import multigrid as mg_kernels
    from warp_stokes.kernels import multigrid_cpu

    for depth in range(len(n) - 1):
        fine, coarse = mg.levels[depth], mg.levels[depth + 1]
        P = to_scipy(mg.prolongation_triplets(depth), fine.n, coarse.n)
        r = rng.standard_normal((fine.n, 67, 4)).astype(np.float32)
        xc = rng.standard_normal((coarse.n, 67, 4)).astype(np.float32)
        shift = wp.vec3i(*coarse.shift)
        # the (node, handle) launches a GPU runs, and the CPU's thread per node looping over the handles
        transfers = {}
        for form, by_row in (("gpu", False), ("cpu", True))[: 2 if device == "cpu" else 1]:
            b = wp.zeros((coarse.n, 67), dtype=wp.vec4f, device=device)
            x = wp.array(np.ones((fine.n, 67, 4), np.float32), dtype=wp.vec4f, device=device)  # added to
            wp.launch(multigrid_cpu.restrict_rows if by_row else mg_kernels.restrict,
                      dim=coarse.n if by_row else b.shape, device=device, outputs=[b],
                      inputs=[mg.table32, coarse.ijk_device, fine.index, fine.n, shift,
                              wp.array(r, dtype=wp.vec4f, device=device)])
            wp.launch(multigrid_cpu.prolong_add_rows if by_row else mg_kernels.prolong_add,
                      dim=fine.n if by_row else x.shape, device=device, outputs=[x],
                      inputs=[mg.table32, fine.ijk_device, coarse.index, shift,
                              wp.array(xc, dtype=wp.vec4f, device=device)])
            transfers[form] = b.numpy(), x.numpy() - 1.0
            for h in (0, 1, 66):
                for got, expected in ((b.numpy()[:, h], P.T @ r[:, h].reshape(-1)),
                                      (x.numpy()[:, h] - 1.0, P @ xc[:, h].reshape(-1))):
                    error = np.abs(got.reshape(-1) - expected).max()
                    assert error <= 1e-6 * np.abs(expected).max(), (depth, form, h)
        for gpu, cpu in zip(transfers["gpu"], transfers.get("cpu", ())):
            np.testing.assert_array_equal(cpu, gpu)  # the same sums in the same order
    known = np.zeros(grid.shape + (2, 4))
    ring = grid.labels >= 2
    known[ring] = rng.uniform(-1, 1, size=(ring.sum(), 2, 4))
    reference = reference_solve(grid.labels == 1, known.astype(np.float32).astype(np.float64))
    field = wp.array(known[tuple(grid.active_ijk.T)].astype(np.float32), dtype=wp.vec4f, device=device)
    field_np = field.numpy()
    field_np[: grid.n_interior] = 0.0
    field = wp.array(field_np, dtype=wp.vec4f, device=device)
    report = ws.solve_biharmonic(grid, field, tol=1e-7, device=device, preconditioner=mg)
    assert report.converged and report.iterations <= 12 and not report.recoveries
    got = field.numpy()[: grid.n_interior]
    expected = reference[tuple(grid.active_ijk[: grid.n_interior].T)]
    assert np.abs(got - expected).max() <= 1e-5 * np.abs(expected).max()


def test_v_cycle_is_a_symmetric_positive_preconditioner(arm_hierarchy, device):
    grid, mg = arm_hierarchy
    rng = np.random.default_rng(5)
    a = wp.array(rng.normal(size=(grid.n_interior, 2, 4)).astype(np.float32), dtype=wp.vec4f, device=device)
    b = wp.array(rng.normal(size=(grid.n_interior, 2, 4)).astype(np.float32), dtype=wp.vec4f, device=device)
    ma, mb = wp.empty_like(a), wp.empty_like(b)
    mg.apply(a, ma)
    mg.apply(b, mb)
    a, b, ma, mb = (x.numpy().astype(np.float64) for x in (a, b, ma, mb))
    for h in range(2):
        lhs, rhs = np.sum(ma[:, h] * b[:, h]), np.sum(a[:, h] * mb[:, h])
        assert abs(lhs - rhs) <= 1e-4 * abs(lhs)
        assert np.sum(ma[:, h] * a[:, h]) > 0


def test_cg_iterations_do_not_grow_with_the_resolution(arm_cage, device):
    iterations = {}
    for n in (24, 48, 96):
        grid = ws.voxelize(arm_cage, resolution=n, device=device)
        field = ws.boundary_field(grid, arm_cage, device=device, handles=slice(10, 14))
        report = ws.solve_biharmonic(grid, field, tol=1e-6, device=device)
        assert report.converged
        iterations[n] = report.iterations
    print("multigrid-preconditioned CG iterations by resolution:", iterations)
    assert max(iterations.values()) <= 10
    assert iterations[96] <= iterations[24] + 2


def test_jacobi_iterations_do_grow(arm_cage, device):
    # the contrast that makes the test above meaningful
    its = []
    for n in (16, 32):
        grid = ws.voxelize(arm_cage, resolution=n, device=device)
        field = ws.boundary_field(grid, arm_cage, device=device, handles=slice(10, 12))
        its.append(ws.solve_biharmonic(grid, field, tol=1e-6, preconditioner="jacobi", device=device).iterations)
    assert its[1] > 1.5 * its[0] and its[1] > 40


def test_bench_smoother_solves_and_tabulates_every_variant():
    # the benchmark behind the smoother's degrees, at a tiny size: every variant solves and is tabulated (a
    # subprocess, on the CPU whatever the device under test: the benchmark script is the subject)
    repo = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, str(repo / "benchmarks" / "bench_smoother.py"), "--pair", "arm",
                           "--resolution", "16", "--handles", "4", "--device", "cpu",
                           "--variants", "3,3/12/1.1", "3,3,8/40/1.2"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = [line for line in proc.stdout.splitlines() if line.startswith("| 3,3")]
    assert len(rows) == 2 and all("| True |" in row for row in rows), proc.stdout


def test_bench_speed_tabulates_a_bind_and_a_fresh_process():
    # issue 16's harness at a tiny size on the CPU (a subprocess: the script is the subject): the phase table, the
    # throughput line and the fresh processes, whose bind must succeed without a false compile notice
    repo = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, str(repo / "benchmarks" / "bench_speed.py"), "--device", "cpu", "--pair",
                           "arm", "--resolutions", "16", "--repeats", "1", "--assets", "2"], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout
    row = next(line for line in out.splitlines() if line.startswith("| 16 | 58 |"))
    assert len(row.split("|")) >= 10 and "assets/min" in out
    fresh = [line for line in out.splitlines() if line.startswith("| warp-stokes bind arm n = 16 | warm |")]
    assert len(fresh) == 1 and fresh[0].rstrip().endswith("| 0 | no |"), out


def test_deep_hierarchies_smooth_harder(arm_cage, device, monkeypatch):
    """A hierarchy of DEEP_LEVELS levels or more smooths with DEEP_SMOOTHER_DEGREES; a shallower one does not."""
    from warp_stokes.solver import multigrid

    grid = ws.voxelize(arm_cage, resolution=32, device=device)  # 5 levels down to one node, 2 down to 60
    rng = np.random.default_rng(7)
    r = wp.array(rng.normal(size=(grid.n_interior, 2, 4)).astype(np.float32), dtype=wp.vec4f, device=device)

    def cycle(coarsest_nodes):
        mg = ws.Multigrid(grid, device=device, coarsest_nodes=coarsest_nodes)
        z = wp.zeros_like(r)
        mg.apply(r, z)
        return len(mg.level_sizes), z.numpy()

    monkeypatch.setattr(multigrid, "DEEP_LEVELS", 5)  # the threshold (8 levels) is met beyond n = 512; lowered here
    depth_deep, deep = cycle(1)
    depth_shallow, shallow = cycle(60)
    assert depth_deep >= multigrid.DEEP_LEVELS > depth_shallow
    monkeypatch.setattr(multigrid, "DEEP_SMOOTHER_DEGREES", multigrid.SMOOTHER_DEGREES)
    assert not np.allclose(cycle(1)[1], deep)  # the deep hierarchy used the deep degrees
    np.testing.assert_array_equal(cycle(60)[1], shallow)  # the shallow one never did
