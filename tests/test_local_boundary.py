"""Local boundary data: exact partition of unity and linear precision, locality along the cage, folded edges."""

import re
import warnings

import numpy as np
import pytest
import trimesh
import warp as wp

import warp_stokes as ws
from conftest import EXAMPLE, box_cage, cli, u_cage
from warp_stokes.geometry.cage import Cage, folded_edges, unit_normals
from warp_stokes.geometry.local_data import cage_graph_distances, normal_derivatives
from warp_stokes.kernels import local_boundary as local_boundary_kernels

SETTINGS = [ws.LocalData(), ws.LocalData(fold_radius=0.0), ws.LocalData(model="least-norm"),
            ws.LocalData(radius=3.0, least_norm_share=0.5)]


def test_graph_distances_follow_the_cage_not_space():
    cage = u_cage()
    d = cage_graph_distances(cage)
    assert np.allclose(d, d.T) and (np.diag(d) == 0).all()
    # the prongs' inner tips: 0.2 apart in space, 2 + 0.2 + 2 along the cage
    left = np.flatnonzero(np.all(np.isclose(cage.vertices, [1, 3, 0]), axis=1))[0]
    right = np.flatnonzero(np.all(np.isclose(cage.vertices, [1.2, 3, 0]), axis=1))[0]
    assert np.isclose(np.linalg.norm(cage.vertices[left] - cage.vertices[right]), 0.2)
    assert np.isclose(d[left, right], 4.2)


@pytest.mark.parametrize("name", ["ellipsoid", "star", "torus", "two_boxes"])
def test_graph_distances_match_scipys_dijkstra_in_groups(name, device, monkeypatch):
    """Against scipy's shortest paths, on cages with uneven edges, a cage in two pieces (inf between them) and
    scratch groups of 7 searches (several launches, a short last one)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import shortest_path

    import shapes
    from warp_stokes.geometry import local_data
    from warp_stokes.geometry.cage import face_edges

    if name == "two_boxes":
        box = shapes.box_pair(extents=(1.0, 2.0, 0.5))
        vertices = np.concatenate([box.cage_vertices, box.cage_vertices + [5.0, 0.0, 0.0]])
        faces = np.concatenate([box.cage_faces, box.cage_faces + len(box.cage_vertices)])
    else:
        pair = {"ellipsoid": lambda: shapes.ellipsoid_pair((1.0, 2.0, 0.5), noise=0.05, subdivisions=3, seed=2),
                "star": lambda: shapes.star_pair(seed=3), "torus": lambda: shapes.torus_pair(seed=1)}[name]()
        vertices, faces = pair.cage
    cage = Cage(vertices, faces, name)
    monkeypatch.setattr(local_data, "GRAPH_SCRATCH_BYTES", 16 * 7 * cage.n_handles)
    d = cage_graph_distances(cage, device=device)
    e = face_edges(cage.faces)
    length = np.linalg.norm(cage.vertices[e[:, 0]] - cage.vertices[e[:, 1]], axis=1)
    graph = coo_matrix((length, (e[:, 0], e[:, 1])), shape=(cage.n_handles,) * 2)
    expected = shortest_path(graph.tocsr(), directed=False)
    assert np.array_equal(np.isinf(d), np.isinf(expected))
    finite = np.isfinite(expected)
    # sums of the same lengths in possibly another order: float64 rounding of a path of < 100 edges
    assert np.abs(d[finite] - expected[finite]).max() <= 1e-13 * expected[finite].max()
    assert (np.isinf(d).any()) == (name == "two_boxes")


@pytest.mark.parametrize("settings", SETTINGS, ids=str)
def test_normal_derivatives_reproduce_zero_and_the_normal(arm_cage, settings, device):
    g = normal_derivatives(arm_cage, settings, device=device)
    assert np.abs(g.sum(axis=1)).max() < 1e-12
    assert np.abs(g @ arm_cage.vertices - unit_normals(arm_cage)).max() < 1e-10


def test_normal_derivatives_are_computed_once_per_cage_and_settings(arm_cage, device, monkeypatch):
    from warp_stokes.geometry import local_data

    calls = []
    compute = local_data._normal_derivatives
    monkeypatch.setattr(local_data, "_normal_derivatives", lambda *a: calls.append(a) or compute(*a))
    monkeypatch.setattr(local_data, "_KEPT_DERIVATIVES", type(local_data._KEPT_DERIVATIVES)())
    first = normal_derivatives(arm_cage, ws.LocalData(), device=device)
    with pytest.raises(ValueError):  # read-only: a caller cannot change the kept array
        first[:] = 0.0
    again = normal_derivatives(arm_cage, ws.LocalData(), device=device)
    assert len(calls) == 1 and np.abs(again.sum(axis=1)).max() < 1e-12 and np.abs(again).max() > 0
    other = normal_derivatives(arm_cage, ws.LocalData(model="least-norm"), device=device)
    assert len(calls) == 2 and not np.allclose(other, again)
    # a float32 copy of the cage is computed from float64 arrays: the same numbers, the same key
    single = ws.geometry.cage.Cage(arm_cage.vertices.astype(np.float32).astype(np.float64), arm_cage.faces, "single")
    as_float32 = ws.geometry.cage.Cage(arm_cage.vertices.astype(np.float32), arm_cage.faces, "float32")
    assert np.array_equal(normal_derivatives(as_float32, device=device), normal_derivatives(single, device=device))
    assert len(calls) == 3
    # the last KEPT_CAGES cages are kept: later ones evict the oldest (the arm's two)
    for shift in range(1, local_data.KEPT_CAGES):
        normal_derivatives(ws.geometry.cage.Cage(arm_cage.vertices + shift, arm_cage.faces, "moved"), device=device)
    normal_derivatives(arm_cage, ws.LocalData(), device=device)
    assert len(calls) == 3 + (local_data.KEPT_CAGES - 1) + 1
    # and no more than KEPT_BYTES past the newest (a cage of thousands of handles holds hundreds of MB)
    monkeypatch.setattr(local_data, "KEPT_BYTES", 0)
    normal_derivatives(ws.geometry.cage.Cage(arm_cage.vertices - 1.0, arm_cage.faces, "moved"), device=device)
    assert len(local_data._KEPT_DERIVATIVES) == 1


@pytest.mark.parametrize("settings", SETTINGS[:2], ids=str)
def test_normal_derivatives_and_slopes_are_the_same_in_groups_of_faces(arm_cage, settings, device, monkeypatch):
    """Thousands of handles are formed a group of faces at a time: the same numbers as all faces at once."""
    from warp_stokes.geometry import local_data

    monkeypatch.setattr(local_data, "_KEPT_DERIVATIVES", type(local_data._KEPT_DERIVATIVES)())
    whole = local_data._normal_derivatives(arm_cage, settings, ws.device.Backend.of(device))
    slopes = local_data.data_slopes(arm_cage, settings, device)
    monkeypatch.setattr(local_data, "_KEPT_DERIVATIVES", type(local_data._KEPT_DERIVATIVES)())
    monkeypatch.setattr(local_data, "_KEPT_SLOPES", {})
    monkeypatch.setattr(local_data, "FACE_GROUP_HANDLES", 7 * arm_cage.n_handles)  # groups of 7 faces
    grouped = local_data._normal_derivatives(arm_cage, settings, ws.device.Backend.of(device))
    assert np.allclose(grouped, whole, rtol=0, atol=1e-13 * np.abs(whole).max())
    assert np.allclose(local_data.data_slopes(arm_cage, settings, device), slopes, rtol=1e-13, atol=0)


def test_normal_derivatives_stay_on_handles_near_the_face_along_the_cage(device):
    cage = u_cage()
    g = normal_derivatives(cage, ws.LocalData(), device=device)
    far = cage_graph_distances(cage)[cage.faces].min(axis=1) > 3.0  # more than 3 mean edges (about 1.3) away
    share = np.abs(g * far).sum(axis=1) / np.abs(g).sum(axis=1)
    assert far.any() and share.max() < 0.05


def test_local_field_reproduces_constants_and_linear_functions(arm_cage, device):
    grid = ws.voxelize(arm_cage, 20, device=device)
    f = ws.boundary_field(grid, arm_cage, device=device, data="local").numpy().astype(np.float64)[grid.n_interior:]
    columns = np.column_stack([np.ones(arm_cage.n_handles), arm_cage.vertices - grid.centre])
    x = grid.node_positions(np.arange(grid.n_interior, grid.n_active))
    scale = arm_cage.diagonal
    assert np.abs(f[..., 0] @ columns[:, 0] - 1).max() < 1e-5
    assert np.abs(f[..., 0] @ columns[:, 1:] - x).max() < 1e-5 * scale
    # gradients G = h grad q: of 1 and of x
    assert np.abs(np.einsum("ncj,c->nj", f[..., 1:], columns[:, 0])).max() < 1e-5
    gradient_of_x = np.einsum("ncj,ca->naj", f[..., 1:], columns[:, 1:]) / grid.spacing
    assert np.abs(gradient_of_x - np.eye(3)).max() < 1e-5


def test_local_data_is_the_hat_function_on_the_cage(device):
    # a node on a face of a box: q = the face's barycentric coordinates (no Taylor term)
    cage = ws.check_cage(box_cage())
    grid = ws.voxelize(cage, 16, device=device)
    field = ws.boundary_field(grid, cage, device=device, data="local").numpy()
    x = grid.node_positions() + grid.centre
    on_top = np.flatnonzero((np.abs(x[:, 2] - 1) < 1e-12) & (np.abs(x[:, :2]) < 1 - 1e-9).all(axis=1))
    assert len(on_top)
    expected = ws.mean_value_coordinates(cage, x[on_top], device=device)  # exact there: the hat functions
    np.testing.assert_allclose(field[on_top, :, 0], expected, atol=1e-6)


def test_folded_edges_are_found_where_the_cage_folds_back(arm_cage):
    # the arm's cage folds back at four edges (the issue measured 152-173 degrees); a box and a sphere have none
    folds = folded_edges(arm_cage)
    assert len(folds) == 4
    n = unit_normals(arm_cage)
    for a, b in folds:
        faces = np.flatnonzero(np.isin(arm_cage.faces, [a, b]).sum(axis=1) == 2)
        assert len(faces) == 2 and np.degrees(np.arccos(np.clip(n[faces[0]] @ n[faces[1]], -1, 1))) > 150
    assert len(folded_edges(ws.check_cage(box_cage()))) == 0
    sphere = trimesh.creation.icosphere(subdivisions=1)
    assert len(folded_edges(ws.check_cage((sphere.vertices, sphere.faces)))) == 0


def test_local_data_decouples_parts_close_in_space_far_along_the_cage(device):
    # vertices in the left prong, next to the gap: the right prong's tip handles hold much less of their weight
    # with local data than with MVC data (MVC is global: across the gap it carries the other prong)
    cage = u_cage()
    points = np.array([[0.9, y, 0.5] for y in np.linspace(1.5, 2.9, 8)])
    tips = np.flatnonzero((cage.vertices[:, 0] > 1.1) & (cage.vertices[:, 1] > 2.9))
    share = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for data in ("mvc", "local"):
            b = ws.bind((points, None), cage, resolution=40, device=device, boundary=data)
            assert b.stats.converged and b.stats.linear_precision_error < 1e-5
            share[data] = np.abs(b.weights[:, tips]).sum(axis=1).max()
    assert share["local"] < 0.7 * share["mvc"], share


def test_the_boundary_data_is_a_bind_and_cli_choice(tmp_path):
    # the command line, in process, on the CPU (the boundary data on every device is tested above, and the bind's
    # refusal comes before any device work)
    out = tmp_path / "arm.npz"
    proc = cli("bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(out), "--resolution", "16",
               "--device", "cpu", "--boundary", "mvc")
    assert proc.returncode == 0, proc.stderr
    assert ws.load_binding(out, device="cpu").settings["boundary"] == "mvc-central-difference"
    proc = cli("bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(out), "--boundary",
               "harmonic")
    assert proc.returncode == 2 and "invalid choice" in proc.stderr
    with pytest.raises(ws.WarpStokesError, match="boundary must be"):
        ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=16, device="cpu", boundary="harmonic")
    with pytest.raises(ValueError, match="model"):
        ws.LocalData(model="nearest")


def test_the_cage_check_notes_folded_edges_and_a_coarse_bind_warns_of_them(device):
    """A folded edge is a note (nothing to do where the grid cuts its wedge off); a bind too coarse for it warns
    once, saying what to do, and both are kept in the stats."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning from the check itself
        cage = ws.check_cage(EXAMPLE / "arm_cage.obj")
    assert any(re.search(r"folds back on itself at 4 edge\(s\).*36-37 \(173 deg\)", note) for note in cage.notes)
    with pytest.warns(UserWarning) as caught:
        b = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=16, device=device)
    texts = [str(w.message) for w in caught if "folded edges" in str(w.message)]  # (and thin parts at 16)
    assert len(texts) == 1 and re.search(r"at resolution 16 the grid does not yet cut off .* from resolution (\d+) on"
                                         r".*give --resolution auto \(the default\) or more", texts[0]), texts
    assert any("folds back" in w for w in b.stats.warnings) and texts[0] in b.stats.warnings


def test_a_chunks_local_field_and_its_complement_sum_to_one(arm_cage, device):
    grid = ws.voxelize(arm_cage, 20, device=device)
    chunk = slice(5, 21)
    field = ws.boundary_field(grid, arm_cage, device=device, handles=chunk, complement=True, data="local")
    f = field.numpy().astype(np.float64)[grid.n_interior:]
    whole = ws.boundary_field(grid, arm_cage, device=device, data="local").numpy().astype(np.float64)[grid.n_interior:]
    np.testing.assert_allclose(f[:, :16], whole[:, chunk], atol=1e-6)
    np.testing.assert_allclose(f.sum(1), np.broadcast_to([1.0, 0, 0, 0], (len(f), 4)), atol=1e-5)


@wp.kernel
def _exhaustive_blends(ijk: wp.array(dtype=wp.vec3i), first_row: int, origin: wp.vec3d, spacing: wp.float64,
                       band: wp.float64, cage: wp.array(dtype=wp.vec3d), triangles: wp.array(dtype=wp.vec3i),
                       table: wp.array(dtype=local_boundary_kernels.Blend)):
    i = wp.tid()
    table[i] = local_boundary_kernels.blend_at(local_boundary_kernels.grid_point(ijk, first_row + i, origin, spacing),
                                               band, cage, triangles)


@pytest.mark.parametrize("name, resolution", [("arm", 24), ("arm", 40), ("icosphere", 8)])
def test_the_blend_table_found_through_the_bvh_is_the_search_over_every_face(name, resolution, arm_cage, device):
    # blend_table finds each ring and band row's faces through the cage's BVH and searches them in index order: the
    # same faces, shares and closest points, bit for bit, as the search over every face (blend_at); a fine cage at a
    # coarse grid gives rows with more boxes in reach than the BVH search collects (its fallback), and rows with fewer
    from warp_stokes.geometry.local_boundary import BLEND_BAND, blend_table

    if name == "arm":
        cage = arm_cage
    else:
        sphere = trimesh.creation.icosphere(subdivisions=3)  # 642 handles, 1,280 faces
        cage = ws.check_cage((sphere.vertices, sphere.faces))
    grid = ws.voxelize(cage, resolution=resolution, device=device)
    rows = slice(grid.n_interior, grid.n_active)
    found = blend_table(grid, cage, rows, device).numpy()
    exhaustive = wp.empty(grid.n_active - grid.n_interior, dtype=local_boundary_kernels.Blend, device=device)
    wp.launch(_exhaustive_blends, dim=exhaustive.shape[0],
              inputs=[grid.device_arrays(device)["active_ijk"], grid.n_interior, wp.vec3d(*grid.origin),
                      wp.float64(grid.spacing), wp.float64(BLEND_BAND * grid.spacing),
                      wp.array(cage.vertices - grid.centre, dtype=wp.vec3d, device=device),
                      wp.array(cage.faces.astype(np.int32), dtype=wp.vec3i, device=device)],
              outputs=[exhaustive], device=device)
    expected = exhaustive.numpy()
    for field in ("count", "faces", "fractions", "points"):
        np.testing.assert_array_equal(found[field], expected[field], err_msg=field)
    assert (expected["count"] >= 1).all() and (expected["count"] > 1).any()
    if name == "icosphere":  # the faces whose boxes meet each row's cube of reach: above and below the BVH list's size
        points = grid.centre + grid.node_positions(np.arange(rows.start, rows.stop))
        _, nearest, _ = trimesh.proximity.closest_point(sphere, points)
        reach = (nearest + BLEND_BAND * grid.spacing)[:, None, None]
        corners = cage.vertices[cage.faces]
        lo, hi = corners.min(axis=1)[None], corners.max(axis=1)[None]
        in_reach = ((lo <= points[:, None] + reach) & (hi >= points[:, None] - reach)).all(axis=2).sum(axis=1)
        assert (in_reach > local_boundary_kernels.MAX_CANDIDATES).any()
        assert (in_reach <= local_boundary_kernels.MAX_CANDIDATES).any()
