import numpy as np
import pytest

import warp_stokes as ws
from conftest import PAIRS, box_cage, pair


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
