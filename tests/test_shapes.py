"""The synthetic cages of tests/shapes.py: valid cages (closed, outward, not self-intersecting: the
package's own check), points inside them (the package's winding numbers and trimesh's ray test), deterministic."""

import warnings

import numpy as np
import pytest
import trimesh

import warp_stokes as ws
import shapes

FAMILY = shapes.stress_pairs(detail=2) + shapes.stress_pairs(detail=1)


@pytest.mark.parametrize("pair", FAMILY, ids=[f"{p.name} ({len(p.cage_vertices)})" for p in FAMILY])
def test_every_synthetic_cage_is_valid_and_holds_its_points(pair):
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # not even a warning (folded edges, a merged soup, flipped faces)
        cage = ws.check_cage(pair.cage, name=pair.name)
    assert not cage.flipped and len(cage.vertices) == len(pair.cage_vertices)
    assert ws.signed_volume(cage.vertices, cage.faces) > 0
    inside, _ = ws.classify_points(cage, pair.points, device="cpu")
    assert inside.all()
    assert trimesh.Trimesh(*pair.cage, process=False).contains(pair.points).all()


def test_pairs_are_deterministic_and_seeds_differ():
    a, b = shapes.star_pair(5), shapes.star_pair(5)
    assert np.array_equal(a.cage_vertices, b.cage_vertices) and np.array_equal(a.points, b.points)
    assert not np.allclose(shapes.star_pair(6).cage_vertices, a.cage_vertices)
    assert [p.name for p in shapes.stress_pairs()] == [p.name for p in shapes.stress_pairs()]


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="noise must be in"):
        shapes.ellipsoid_pair(noise=1.0)
    with pytest.raises(ValueError, match="neck's radius"):
        shapes.dumbbell_pair(0.6)
    with pytest.raises(ValueError, match="detail must be 1 or 2"):
        shapes.stress_pairs(detail=3)


@pytest.mark.parametrize("rings, sections", [(3, 4), (29, 60), (49, 102)])
def test_latitude_longitude_spheres_are_valid_cages(rings, sections):
    vertices, faces = shapes.latitude_longitude_sphere(rings, sections, radius=1.2)
    cage = ws.check_cage((vertices, faces), name="sphere")  # closed, outward, no crossing faces (slivers included)
    assert not cage.flipped and len(cage.vertices) == 2 + (rings - 1) * sections
    assert np.allclose(np.linalg.norm(vertices, axis=1), 1.2)
