"""Thin wedges of outside space where the cage folds back on itself: interior nodes that such a wedge cuts off from a
stencil neighbour take the boundary data (issue 19's folded-edge growth)."""


import numpy as np
import pytest

import warp_stokes as ws
from warp_stokes.geometry import grid as grid_module
from conftest import EXAMPLE, box_cage, cli, slit_cage, write_obj


def points_around_the_slit(rotation, count=3000):
    """Points inside the slit cage, off the slit by a margin, in the cage's rotated frame; and which lie on the slit's
    -x side in its upper part (across the slit from the +x lip)."""
    p = np.random.default_rng(0).uniform(-0.97, 0.97, size=(count, 3))
    in_slit = (p[:, 2] > -0.25) & (np.abs(p[:, 0]) < 0.09 * (p[:, 2] + 0.2) / 1.2 + 0.03)
    p = p[~in_slit]
    return p @ rotation.T, (p[:, 0] < 0) & (p[:, 2] > -0.4)


def test_nodes_a_thin_wedge_cuts_off_join_the_ring():
    cage, rotation, _ = slit_cage()
    grid = ws.voxelize(cage, 24, device="cpu")
    assert grid.n_cut_off > 0
    ring_rows = np.arange(grid.n_interior, grid.n_interior + grid.n_ring)
    positions = grid.node_positions(ring_rows) + grid.centre
    inside, distance = ws.classify_points(cage, positions, device="cpu")
    # exactly the ring nodes inside the cage are the cut-off ones, all within a diagonal link of the slit's walls
    assert inside.sum() == grid.n_cut_off
    # numbered first in the ring: the rows below n_inside are the nodes inside the cage
    assert grid.n_inside == grid.n_interior + grid.n_cut_off and inside[: grid.n_cut_off].all()
    assert (distance[inside] <= 1.5 * grid.spacing).all()
    local = positions[inside] @ rotation  # back in the slit's frame: next to x = 0, above its floor at z = -0.2
    assert (np.abs(local[:, 0]) < 0.09 + 1.5 * grid.spacing).all() and (local[:, 2] > -0.2 - 1.5 * grid.spacing).all()
    # MVC data (global: the same on both sides of the wedge) cuts nothing off; neither does a cage without folds
    assert ws.voxelize(cage, 24, device="cpu", boundary="mvc").n_cut_off == 0
    box = ws.check_cage(tuple(np.asarray(a) for a in (box_cage()[0] @ rotation.T, box_cage()[1])))
    plain, as_mvc = ws.voxelize(box, 24, device="cpu"), ws.voxelize(box, 24, device="cpu", boundary="mvc")
    assert plain.n_cut_off == 0 and np.array_equal(plain.labels, as_mvc.labels)


def test_cut_off_nodes_hold_the_local_data():
    from warp_stokes.geometry.local_boundary import local_values

    cage, _, _ = slit_cage()
    grid = ws.voxelize(cage, 24, device="cpu")
    assert grid.boundary == ws.LocalData()
    field = ws.boundary_field(grid, cage, device="cpu").numpy()  # the grid's own data by default
    np.testing.assert_array_equal(field, ws.boundary_field(grid, cage, device="cpu", data="local").numpy())
    rows = np.arange(grid.n_interior, grid.n_inside)
    expected = local_values(cage, grid.node_positions(rows) + grid.centre, grid.spacing, device="cpu")
    np.testing.assert_allclose(field[rows, :, 0], expected, atol=2e-6)
    # other data than the grid cut its nodes off for is warned of; bad data names are refused by voxelize
    with pytest.warns(UserWarning, match=rf"cut {grid.n_cut_off} nodes off"):
        ws.boundary_field(grid, cage, device="cpu", data="mvc")
    with pytest.raises(ws.WarpStokesError, match="boundary must be 'mvc', 'local' or a LocalData, got 'MVC'"):
        ws.voxelize(cage, 24, device="cpu", boundary="MVC")


@pytest.mark.parametrize("resolution", [32, 48])
def test_the_wedge_no_longer_couples_its_two_sides(resolution, monkeypatch):
    cage, rotation, lip = slit_cage()
    points, across = points_around_the_slit(rotation)
    b = ws.bind((points, None), cage, resolution=resolution, device="cpu")
    w = b.weights
    assert b.stats.grid.cut_off_nodes > 0 and b.stats.converged
    assert b.stats.partition_of_unity_error < 1e-5 and b.stats.linear_precision_error < 1e-5
    # the +x lip's handles hold almost nothing across the slit, and no weight is far below zero
    assert np.abs(w[across][:, lip]).max() < 0.05
    assert w.min() > -0.08
    # without the cut (the stencil coupling the wedge's two sides): both fail, and grow with the resolution
    monkeypatch.setattr(grid_module, "_wedge_cut_off", lambda *args: None)
    coupled = ws.bind((points, None), cage, resolution=resolution, device="cpu").weights
    assert np.abs(coupled[across][:, lip]).max() > 0.15 and coupled.min() < -0.15


def test_a_resolution_too_coarse_for_the_folded_edges_is_warned_of(arm_cage):
    needed = ws.wedge_resolution(arm_cage)
    assert isinstance(needed, int) and needed > 16
    assert ws.wedge_resolution(arm_cage, boundary="mvc") is None
    mesh = ws.load_surface(EXAMPLE / "arm.obj")
    with pytest.warns(UserWarning, match=rf"at resolution 16 the grid does not yet cut off .* from resolution {needed}"):
        b = ws.bind(mesh, arm_cage, resolution=16, device="cpu")
    assert any("does not yet cut off" in note for note in b.stats.warnings)
    # the cut needs the faces to span cells: a finer grid cuts off more nodes of the arm's wedges
    counts = [ws.voxelize(arm_cage, n, device="cpu").n_cut_off for n in (16, 48)]
    assert counts[0] < counts[1]


def test_bind_reports_the_cut_off_nodes(tmp_path):
    cage, rotation, _ = slit_cage()
    points, _ = points_around_the_slit(rotation, 400)
    write_obj(tmp_path / "slit.obj", cage.vertices, cage.faces)
    hull = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    write_obj(tmp_path / "points.obj", points, hull)  # a point cloud with a token face: what bind reads
    proc = cli("bind", str(tmp_path / "points.obj"), str(tmp_path / "slit.obj"), "-o", str(tmp_path / "b.npz"),
               "--resolution", "24", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    line = next(line for line in proc.stdout.splitlines() if line.startswith("nodes"))
    count = ws.load_binding(tmp_path / "b.npz", device="cpu").stats.grid.cut_off_nodes
    assert count > 0 and f"({count} inside, cut off by thin wedges of the cage)" in line
