import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, PAIRS, box_cage, float32_rounding, pair
from shapes import latitude_longitude_sphere


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_real_cages_pass(name):
    _, cage_path = pair(name)
    cage = ws.check_cage(cage_path)
    assert not cage.flipped
    assert ws.signed_volume(cage.vertices, cage.faces) > 0


def test_inward_cage_is_flipped_with_a_warning(arm_cage):
    inward = (arm_cage.vertices, arm_cage.faces[:, ::-1])
    with pytest.warns(UserWarning, match="oriented inward"):
        cage = ws.check_cage(inward, name="inward.obj")
    assert cage.flipped
    np.testing.assert_array_equal(cage.faces, arm_cage.faces)


def _cage_error(source, match):
    with pytest.raises(ws.CageError, match=match):
        ws.check_cage(source, name="bad_cage.obj")


def test_open_cage(arm_cage):
    _cage_error((arm_cage.vertices, arm_cage.faces[1:]), "bad_cage.obj: the cage is not closed")


def test_inconsistent_orientation(arm_cage):
    f = arm_cage.faces.copy()
    f[5] = f[5, ::-1]
    _cage_error((arm_cage.vertices, f), "bad_cage.obj: inconsistent face orientation")


def test_degenerate_face():
    v, f = box_cage()
    v = np.vstack([v, v[0] + [1e-15, 0, 0]])
    f = np.vstack([f, [[0, 1, 8]]])
    _cage_error((v, f), "degenerate")
    _cage_error((box_cage()[0], np.vstack([box_cage()[1], [[0, 0, 1]]])), "degenerate")


def test_duplicate_face():
    v, f = box_cage()
    _cage_error((v, np.vstack([f, f[3:4]])), "duplicate faces")


def test_too_few_vertices_and_non_finite():
    _cage_error((np.eye(3), [[0, 1, 2], [0, 2, 1]]), "at least 4 vertices")
    v, f = box_cage()
    v[2, 1] = np.inf
    _cage_error((v, f), "non-finite")


def test_unused_vertex():
    v, f = box_cage()
    _cage_error((np.vstack([v, [[0, 0, 0]]]), f), "not used by any face")


def test_errors_are_value_errors():
    assert issubclass(ws.CageError, ValueError) and issubclass(ws.MeshError, ValueError)


def _stl(path, vertices, faces):
    import trimesh

    trimesh.Trimesh(vertices, faces, process=False).export(path)  # binary STL: one vertex per face corner
    return path


def test_a_triangle_soup_cage_is_merged_and_binds_like_the_original(tmp_path):
    from conftest import EXAMPLE, cli, warp_stokes

    original = ws.load_surface(EXAMPLE / "arm_cage.obj")
    stl = _stl(tmp_path / "arm_cage.stl", original.vertices, original.faces)
    assert len(ws.load_surface(stl).vertices) == 3 * len(original.faces)  # a soup as stored
    cage = ws.check_cage(stl)
    assert cage.n_handles == 58 and any("merged into 58 handles" in n for n in cage.notes)
    # handles in order of first appearance; the map sends every soup vertex to its handle's position
    # an STL holds float32: at most one rounding (half an eps) between copies of a vertex
    np.testing.assert_allclose(cage.vertices[cage.source_index], ws.load_surface(stl).vertices, rtol=0,
                               atol=float32_rounding(np.abs(original.vertices).max(), 1))

    # the commands on the CPU (a soup is merged before any device work): bind in process, deform as a user runs it
    # (a subprocess of the installed command)
    out = tmp_path / "b.npz"
    proc = cli("bind", EXAMPLE / "arm.obj", stl, "-o", out, "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    b = ws.load_binding(out, device="cpu")
    assert b.n_handles == 58 and b.stats.partition_of_unity_error <= 1e-5
    assert b.stats.linear_precision_error <= 1e-5 and "merged into 58 handles" in b.settings["cage_handles"]
    assert np.array_equal(b.cage_source_index, cage.source_index)

    # a deformed STL with the same layout deforms the mesh like the deformed cage as OBJ
    moved = _stl(tmp_path / "moved.stl", original.vertices * [1.0, 1.2, 1.0] + [5.0, 0.0, 0.0], original.faces)
    deformed = tmp_path / "deformed.obj"
    proc = warp_stokes("deform", out, moved, "-o", deformed, "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    expected = b.deform(cage.vertices * [1.0, 1.2, 1.0] + [5.0, 0.0, 0.0])
    np.testing.assert_allclose(ws.load_surface(deformed).vertices, expected, atol=1e-3)


def test_a_closed_cage_keeps_its_vertex_order_and_an_open_soup_is_still_refused(tmp_path):
    from conftest import box_cage

    v, f = box_cage()
    v = v[::-1].copy()
    f = (len(v) - 1 - f)[:, ::-1]  # the same box, vertices listed backwards
    cage = ws.check_cage((v, f))
    assert cage.source_index is None and np.array_equal(cage.vertices, v)
    soup = _stl(tmp_path / "open.stl", v, f[:-1])  # one triangle missing: no merging closes it
    with pytest.raises(ws.CageError, match=r"open.stl: the cage is not closed"):
        ws.check_cage(soup)


def test_merge_coincident_keeps_the_first_vertex_of_each_position():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1e-9, 0], [0, 1, 0], [1, 1, 0]], float)
    merged, faces, index = ws.geometry.cage.merge_coincident(v, np.array([[0, 1, 2], [3, 5, 4]]), 1e-6)
    assert index.tolist() == [0, 1, 2, 1, 2, 3] and faces.tolist() == [[0, 1, 2], [1, 3, 2]]
    np.testing.assert_array_equal(merged, v[[0, 1, 2, 5]])


def test_crossing_faces_finds_self_intersections_and_only_them():
    import trimesh
    from warp_stokes.geometry.cage import crossing_faces

    # real cages and clean solids: none (faces that share an edge or a corner are not crossings)
    for mesh in (trimesh.creation.icosphere(2), trimesh.creation.box(extents=[2, 2, 2]),
                 trimesh.creation.box(extents=[2, 2, 2]).subdivide()):
        assert len(crossing_faces(mesh.vertices, mesh.faces)) == 0
    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    assert len(crossing_faces(cage.vertices, cage.faces)) == 0
    # fine latitude-longitude spheres as an OBJ file holds them (8 or 6 decimals): faces that share a corner lie
    # almost in one plane, where rounding put the corner at 1 - 2e-9 along the other face's edge (580 "crossings"
    # at 1,682 handles, 5,610 at 23,702)
    for rings, sections in ((29, 60), (49, 102), (80, 300)):
        vertices, faces = latitude_longitude_sphere(rings, sections)
        for decimals, radius in ((8, 1.0), (8, 1.2), (6, 1.0)):
            rounded = np.round(radius * vertices, decimals)
            assert len(crossing_faces(rounded, faces)) == 0, (rings, sections, decimals, radius)
    # faces that share a corner and cross away from it (the edge opposite the corner passes through the other)
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1]], float)
    assert crossing_faces(v, np.array([[0, 1, 2], [0, 3, 4]])).tolist() == [[0, 1]]
    assert crossing_faces(v + [0, 0, 1e-3], np.array([[0, 1, 2], [0, 3, 4]])).tolist() == [[0, 1]]
    # a vertex pushed through the far side of a sphere
    sphere = trimesh.creation.icosphere(2)
    poked = sphere.vertices.copy()
    poked[0] = -1.5 * poked[0]
    pairs = crossing_faces(poked, sphere.faces)
    assert len(pairs) > 0 and all(0 in sphere.faces[i] or 0 in sphere.faces[j] for i, j in pairs)
    # two overlapping boxes in one file, also where a crossing edge runs along the diagonal of a box's face
    for shift in ([0.7, 0.6, 0.9], [1.0, 1.0, 1.0]):
        b = trimesh.creation.box(extents=[2, 2, 2])
        b.apply_translation(shift)
        both = trimesh.util.concatenate([trimesh.creation.box(extents=[2, 2, 2]), b])
        pairs = crossing_faces(both.vertices, both.faces)
        assert len(pairs) > 0 and ((pairs[:, 0] < 12) & (pairs[:, 1] >= 12)).all()
        with pytest.raises(ws.CageError, match=r"the cage intersects itself: faces \d+ \[.*\] and \d+ \[.*\] cross"):
            ws.check_cage((both.vertices, both.faces))
