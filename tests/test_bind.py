import dataclasses
import json
import warnings

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, PAIRS, float32_rounding, pair


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_partition_of_unity_and_linear_precision_on_real_pairs(name, bindings):
    b = bindings(name)
    mesh_path, cage_path = pair(name)
    mesh = ws.load_surface(mesh_path)
    cage = ws.check_cage(cage_path)
    w = b.weights.astype(np.float64)
    assert w.shape == (len(mesh.vertices), len(cage.vertices))
    assert b.stats.converged
    # every vertex, including those outside the cage (the ogre has ~90)
    assert np.abs(w.sum(1) - 1).max() <= 1e-5
    assert np.linalg.norm(w @ cage.vertices - mesh.vertices, axis=1).max() <= 1e-5 * cage.diagonal
    assert b.stats.partition_of_unity_error <= 1e-5 and b.stats.linear_precision_error <= 1e-5


def test_vertices_outside_the_cage_are_counted_and_weighted(bindings, device):
    b = bindings("ogre")
    mesh_path, cage_path = pair("ogre")
    inside, _ = ws.classify_points(ws.check_cage(cage_path), ws.load_surface(mesh_path).vertices, device=device)
    assert b.stats.vertices_outside_cage == int((~inside).sum())
    assert 60 <= b.stats.vertices_outside_cage <= 120  # MANIFEST.md: 90 of 26,155
    assert b.stats.vertices_beyond_band == 0  # they are within 0.67% of the diagonal: inside the band


def test_vertex_beyond_the_band_gets_the_boundary_data_and_a_warning(arm_cage, device):
    from warp_stokes.geometry.local_boundary import local_values

    mesh = ws.load_surface(EXAMPLE / "arm.obj")
    far = arm_cage.vertices.max(0) + 0.5 * arm_cage.diagonal
    vertices = np.vstack([mesh.vertices, far])
    # the count and the largest distance, also relative to the cage's diagonal (the vertex is half a diagonal
    # beyond the bounding box's corner on every axis: 1.2 diagonals from the surface)
    with pytest.warns(UserWarning, match=r"1 vertices lie outside .* beyond the grid's band \(up to [\d.]+ from the "
                                         r"cage, 1\.2 of its diagonal\); they get the boundary data"):
        b = ws.bind((vertices, None), arm_cage, resolution=16, device=device)
    grid = ws.voxelize(arm_cage, 16, device=device)
    local = local_values(arm_cage, far[None], grid.spacing, device=device)[0]
    np.testing.assert_allclose(b.weights[-1], local, rtol=1e-5, atol=1e-6)
    assert abs(local.sum() - 1) < 1e-6 and np.linalg.norm(local @ arm_cage.vertices - far) < 1e-6 * arm_cage.diagonal
    assert b.stats.vertices_beyond_band == 1
    with pytest.warns(UserWarning, match="beyond the grid's band"):
        b = ws.bind((vertices, None), arm_cage, resolution=16, device=device, boundary="mvc")
    mvc = ws.mean_value_coordinates(arm_cage, far[None], device=device)[0]
    np.testing.assert_allclose(b.weights[-1], mvc, rtol=1e-5, atol=1e-6)


def test_weights_do_not_jump_where_the_band_ends(arm_cage, device):
    """Along rays out of the cage, the weights of vertices sampled in the band and of those beyond it (the data at
    their position) meet: 0.05-0.11 apart across the band's last cell at n = 16 (the data's own variation), where
    mean value coordinates beyond the band were 0.48-0.49 away (measured on the CPU)."""
    mesh = ws.load_surface(EXAMPLE / "arm.obj")
    spacing = ws.voxelize(arm_cage, 16, device=device).spacing
    for face in (10, 40, 77):
        corners = arm_cage.vertices[arm_cage.faces[face]]
        normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        ray = corners.mean(0) + np.linspace(0.2, 7, 69)[:, None] * spacing * normal / np.linalg.norm(normal)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            b = ws.bind((np.vstack([mesh.vertices, ray]), None), arm_cage, resolution=16, device=device)
        weights = b.weights[-len(ray):]
        edge = len(ray) - b.stats.vertices_beyond_band
        assert 0 < b.stats.vertices_beyond_band < len(ray) - 20
        assert np.abs(weights[edge] - weights[edge - 1]).max() < 0.2, face


def test_deform_reproduces_affine_cage_motion(bindings):
    b = bindings("arm")
    rng = np.random.default_rng(3)
    rest = b.cage_vertices
    poses = []
    transforms = []
    for _ in range(3):
        m = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
        t = rng.normal(size=3) * 10
        poses.append(rest @ m.T + t)
        transforms.append((m, t))
    out = b.deform(np.stack(poses))
    assert out.shape == (3, b.n_vertices, 3)
    diag = np.linalg.norm(rest.max(0) - rest.min(0))
    for frame, (m, t) in zip(out, transforms):
        np.testing.assert_allclose(frame, b.mesh_vertices @ m.T + t, atol=2e-5 * diag * 3)
    single = b.deform(poses[0])
    assert single.shape == (b.n_vertices, 3)
    # float32 sums of 58 products, one pose alone and within a batch (other BLAS kernels): 8 eps of their size
    np.testing.assert_allclose(single, out[0], rtol=0,
                               atol=float32_rounding((np.abs(b.weights) @ np.abs(poses[0])).max()))


def test_a_pair_far_from_the_origin_binds_as_at_it(arm_cage, device):
    """World coordinates far from the origin (an asset placed 100 km out, in metres): the same weights as at the
    origin, and linear precision measured about the cage (the float32 weights' rounding times 1e5 once read as a
    linear precision error of 0.0065 of the diagonal, and the bind refused its own weights)."""
    mesh = ws.load_surface(EXAMPLE / "arm.obj")
    shift = np.array([1.0e5, -2.0e5, 5.0e4])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        home = ws.bind(mesh, arm_cage, resolution=16, device=device)
        away = ws.bind((mesh.vertices + shift, mesh.faces), (arm_cage.vertices + shift, arm_cage.faces),
                       resolution=16, device=device)
    assert away.stats.linear_precision_error <= 1e-5 and away.stats.partition_of_unity_error <= 1e-5
    np.testing.assert_allclose(away.weights, home.weights, rtol=0, atol=1e-6)
    # deformed in float32 coordinates: as exact as they can be there
    moved = away.deform(arm_cage.vertices + shift + [0.5, 0.0, 0.0])
    np.testing.assert_allclose(moved, mesh.vertices + shift + [0.5, 0.0, 0.0], rtol=0,
                               atol=float32_rounding(np.abs(shift).max(), factor=1.0))


def test_deform_is_w_times_c(bindings):
    b = bindings("arm")
    pose = b.cage_vertices + np.random.default_rng(4).normal(size=b.cage_vertices.shape)
    # float32 products (the offsets from the pose's centre rounded to float32, then summed) against float64
    np.testing.assert_allclose(b.deform(pose), b.weights.astype(np.float64) @ pose, rtol=0,
                               atol=float32_rounding((np.abs(b.weights) @ np.abs(pose)).max()))


def test_deform_on_the_host_matches_the_kernel(bindings, device):
    import warp as wp

    b = bindings("arm")
    poses = b.cage_vertices + np.random.default_rng(5).normal(size=(4, *b.cage_vertices.shape))
    host = ws.binding.deform.deform_on_host(b.weights, poses)  # what a CPU binding's deform uses
    weights_t = wp.array(np.ascontiguousarray(b.weights.T), dtype=wp.float32, device=device)
    kernel = ws.deform_vertices(weights_t, poses, device=device)
    # float32 sums of 58 products, by BLAS and by a kernel (another order, FMA or not): 8 eps of their size
    sizes = np.array([(np.abs(b.weights) @ np.abs(p)).max() for p in poses])
    np.testing.assert_allclose(host, kernel, rtol=0, atol=float32_rounding(sizes.max()))
    np.testing.assert_allclose(host[2], b.weights.astype(np.float64) @ poses[2], rtol=0,
                               atol=float32_rounding(sizes[2]))
    # one pose alone and within a batch: float32 products summed in another order, so within their rounding
    rounding = 8 * np.finfo(np.float32).eps * (np.abs(b.weights) @ np.abs(poses[1])).max()
    np.testing.assert_allclose(ws.binding.deform.deform_on_host(b.weights, poses[1]), host[1], rtol=0, atol=rounding)


def test_deform_with_a_cage_file_and_topology_check(bindings, tmp_path):
    b = bindings("ogre")
    mesh_path, cage_path = pair("ogre")
    deformed_path = cage_path.parent / "cage_deformed_tri.obj"
    deformed = ws.load_surface(deformed_path)
    # float32 sums of products W c' of two calls (BLAS need not sum two arrays alike): 8 eps of their size
    size = (np.abs(b.weights) @ np.abs(deformed.vertices)).max()
    np.testing.assert_allclose(b.deform(deformed_path), b.deform(deformed.vertices), rtol=0,
                               atol=float32_rounding(size))
    # the quad original triangulates to the same cage: accepted
    np.testing.assert_allclose(b.deform(cage_path.parent / "Ogre_Cage.obj"), b.deform(b.cage_vertices), rtol=0,
                               atol=float32_rounding((np.abs(b.weights) @ np.abs(b.cage_vertices)).max()))
    smpl_cage = pair("smpl")[1]
    with pytest.raises(ws.BindingError, match="cage_rpose.obj: the pose has 126 vertices, the bound cage has 118"):
        b.deform(smpl_cage)
    wrong = deformed.faces.copy()
    wrong[[0, 1]] = wrong[[1, 0, ]][:, [0, 2, 1]]
    with pytest.raises(ws.BindingError, match="different topology"):
        b.deform((deformed.vertices, wrong))
    with pytest.raises(ws.WarpStokesError, match="poses must have shape"):
        b.deform(np.zeros((5, 3)))


def test_save_and_load_round_trip(bindings, tmp_path, device):
    b = bindings("arm")
    path = tmp_path / "arm.npz"
    b.save(path)
    assert [p.name for p in tmp_path.iterdir()] == ["arm.npz"]  # no temporary left behind
    back = ws.load_binding(path, device=device)
    np.testing.assert_array_equal(back.weights, b.weights)
    np.testing.assert_array_equal(back.cage_faces, b.cage_faces)
    assert back.settings["resolution"] == 24 and back.stats.solver.iterations == b.stats.solver.iterations
    assert back.settings["warp_version"] and json.dumps(back.stats.record())
    pose = b.cage_vertices * 1.1
    # loaded on `device` (a kernel), bound on the CPU (BLAS): float32 sums in other orders, 8 eps of their size
    np.testing.assert_allclose(back.deform(pose), b.deform(pose), rtol=0,
                               atol=float32_rounding((np.abs(b.weights) @ np.abs(pose)).max()))


def test_load_refuses_bad_files(bindings, tmp_path):
    with pytest.raises(ws.BindingError, match="missing.npz: no such file"):
        ws.load_binding(tmp_path / "missing.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ws.BindingError, match="junk.npz: cannot read it as a numpy"):
        ws.load_binding(junk)
    other = tmp_path / "other.npz"
    np.savez(other, weights=np.zeros((2, 2)))
    with pytest.raises(ws.BindingError, match="other.npz: not a warp-stokes binding"):
        ws.load_binding(other)
    b = bindings("arm")
    path = tmp_path / "arm.npz"
    b.save(path)
    data = dict(np.load(path))
    data["cage_vertices"] = data["cage_vertices"] + 1.0
    tampered = tmp_path / "tampered.npz"
    np.savez(tampered, **data)
    with pytest.raises(ws.BindingError, match="tampered.npz: the stored cage or mesh does not match"):
        ws.load_binding(tampered)


def test_save_into_missing_folder_fails_cleanly(bindings, tmp_path):
    with pytest.raises(ws.BindingError, match="does not exist"):
        bindings("arm").save(tmp_path / "nope" / "arm.npz")


def test_bad_inputs_to_bind(arm_cage, tmp_path, device):
    with pytest.raises(ws.MeshError, match="missing.obj: no such file"):
        ws.bind(tmp_path / "missing.obj", EXAMPLE / "arm_cage.obj", device=device)
    with pytest.raises(ws.CageError, match="arm.obj: the cage is not closed"):
        ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm.obj", device=device)
    with pytest.raises(ws.WarpStokesError, match="tol"):
        ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", tol=0, device=device)
    with pytest.raises(ws.WarpStokesError, match="device 'cuda:7' is not available"):
        ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", device="cuda:7")


def test_thin_features_are_detected_with_a_suggested_resolution(device):
    # a slab 1/100 as thick as it is wide: at resolution 16 no node lies inside it
    from conftest import box_cage

    v, f = box_cage(lo=(-1, -1, -0.01), hi=(1, 1, 0.01))
    with pytest.raises(ws.ResolutionError, match="no grid node lies inside the cage at resolution 16"):
        ws.bind((np.zeros((1, 3)), None), (v, f), resolution=16, device=device)
    # the arm's fingers are thinner than two cells at resolution 16, not at 32
    with pytest.warns(UserWarning, match=r"mesh vertices lie in parts of the cage thinner .* resolution=\d+ would"):
        b = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=16, device=device)
    assert b.stats.vertices_in_thin_features > 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        b = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=32, device=device)
    assert not any("parts of the cage thinner" in str(w.message) for w in caught)  # (folded edges are still named)
    assert b.stats.vertices_in_thin_features == 0


def _first_format(stats) -> dict:
    """The flat stats a binding of format 1 (warp-stokes 0.2) recorded for ``stats`` (a BindStats)."""
    grid, solver = stats.grid, stats.solver
    flat = {"device": stats.device, "method": stats.method, "handles": stats.handles, "vertices": stats.vertices,
            "vertices_outside_cage": stats.vertices_outside_cage, "vertices_beyond_band": stats.vertices_beyond_band,
            "vertices_in_thin_features": stats.vertices_in_thin_features, "converged": stats.converged,
            "memory_estimate_bytes": stats.memory_estimate_bytes, "seconds": stats.seconds,
            "partition_of_unity_error": stats.partition_of_unity_error, "warnings": stats.warnings,
            "linear_precision_error": stats.linear_precision_error, "grid_shape": grid.shape, "spacing": grid.spacing,
            "interior_nodes": grid.interior_nodes, "ring_nodes": grid.ring_nodes, "band_nodes": grid.band_nodes,
            "cut_off_nodes": grid.cut_off_nodes, "solver": solver.preconditioner, "levels": solver.levels,
            "multigrid_seconds": solver.multigrid_seconds, "chunks": solver.chunks, "threads": solver.threads,
            "coarsest_operator": solver.coarsest_operator, "preconditioners": solver.preconditioners,
            "recoveries": solver.recoveries, "iterations": solver.iterations, "restarts": solver.restarts,
            "solver_rounds": solver.rounds, "chunk_iterations": solver.chunk_iterations,
            "chunk_rounds": solver.chunk_rounds, "residual": solver.residual, "identity_error": solver.identity_error,
            "resolution": {"requested": stats.resolution.requested}}
    return json.loads(json.dumps(flat))


def test_a_binding_reads_back_its_typed_report_and_one_of_the_first_format_too(bindings, tmp_path):
    """The stats are written as a typed record (format 2) and read back equal; a binding of format 1 (flat stats)
    still loads, into the same types; stats of a later format are one error naming it."""
    b = bindings("arm")
    b.save(tmp_path / "b.npz")
    assert ws.load_binding(tmp_path / "b.npz", device="cpu").stats == b.stats
    with np.load(tmp_path / "b.npz") as data:
        arrays = dict(data)
    meta = json.loads(str(arrays["meta"]))
    assert meta["stats"]["format"] == 2 and meta["stats"]["solver"]["iterations"] == b.stats.solver.iterations
    meta["stats"] = _first_format(b.stats)
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "old.npz", **arrays)
    old = ws.load_binding(tmp_path / "old.npz", device="cpu")
    assert old.stats == dataclasses.replace(b.stats, resolution=dataclasses.replace(
        b.stats.resolution, chosen=None, needed=None, cap=None))
    meta["stats"] = {**b.stats.record(), "format": 3}
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "later.npz", **arrays)
    with pytest.raises(ws.BindingError, match=r"later.npz: the binding's stats are of format 3; this version"):
        ws.load_binding(tmp_path / "later.npz")


def test_a_mesh_and_cage_the_other_way_round_are_refused_with_the_same_hint_whichever_check_refuses_them():
    """The cage taken as the mesh lies outside a closed mesh taken as the cage: refused as outside, with the hint that
    the arguments may be swapped (as when the mesh taken as a cage is refused for not being closed); no cage at all
    points to 'auto' and `warp-stokes cage`."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)  # the "cage": closed, dense
    box = trimesh.creation.box(extents=[3.0, 3.0, 3.0])  # the "mesh": the coarse cage around it
    with pytest.raises(ws.MeshError, match=r"8 of 8 vertices .* lie outside .*; the cage has more vertices \(642\) "
                                           r"than the mesh \(8\): are the mesh and the cage the other way round"):
        ws.bind((box.vertices, box.faces), (sphere.vertices, sphere.faces), resolution=16, device="cpu")
    with pytest.raises(ws.CageError, match=r"no cage: give a cage file, 'auto' for a cage made for the mesh "
                                           r"\(`warp-stokes cage MESH -o CAGE.obj`"):
        ws.bind((box.vertices, box.faces), device="cpu")
