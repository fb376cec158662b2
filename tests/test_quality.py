"""Deformation quality measures against exact facts."""

import warnings

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE
from test_local_boundary import u_cage
from warp_stokes import quality


def grid_mesh(n=4):
    """A flat n x n grid of squares split into triangles, in the z = 0 plane."""
    x, y = np.meshgrid(np.arange(n + 1, dtype=float), np.arange(n + 1, dtype=float), indexing="ij")
    points = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return points, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def test_similarities_keep_angles_and_a_shear_has_its_known_distortion():
    p, f = grid_mesh()
    rotation = np.array([[0.6, -0.8, 0.0], [0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(quality.conformal_distortion(f, p, 2.5 * p @ rotation.T + 7.0), 1.0, atol=1e-12)
    sheared = p.copy()
    sheared[:, 0] += p[:, 1]  # (x, y) -> (x + y, y): singular values of [[1, 1], [0, 1]], ratio (3 + sqrt 5) / 2
    np.testing.assert_allclose(quality.conformal_distortion(f, p, sheared), (3 + np.sqrt(5)) / 2, rtol=1e-12)
    assert np.all(quality.dihedral_change(f, 3.0 * p @ rotation.T, p) < 1e-6)


def test_dihedral_change_of_a_fold():
    p, f = grid_mesh(2)
    folded = p.copy()
    folded[p[:, 0] > 1, 2] = p[p[:, 0] > 1, 0] - 1  # the half x > 1 rises at 45 degrees
    change = quality.dihedral_change(f, folded, p)
    fa, fb, edges = quality.interior_edges(f)
    on_fold = np.all(p[edges][:, :, 0] == 1, axis=1)  # the edges along x = 1
    np.testing.assert_allclose(change[on_fold], 45.0, atol=1e-9)
    assert np.all(change[~on_fold] < 1e-9)


def test_negative_weights_distant_handles_and_differences():
    cage = u_cage()
    left_tip, right_tip = (np.flatnonzero(np.all(np.isclose(cage.vertices, c), axis=1))[0]
                           for c in ([1, 3, 0], [1.2, 3, 0]))
    point = np.array([[0.95, 2.95, 0.05]])  # beside the left prong's tip, nearest the left prong's inner face
    w = np.zeros((1, cage.n_handles))
    w[0, left_tip], w[0, right_tip] = 1.25, -0.25  # sums to one; the right tip is 4.2 away along the cage
    share = quality.distant_handle_weight(w, cage, point, device="cpu")
    np.testing.assert_allclose(share, [0.25])
    w_near = np.zeros_like(w)
    w_near[0, left_tip] = 1.0
    assert quality.distant_handle_weight(w_near, cage, point, device="cpu")[0] == 0.0
    assert quality.weight_difference(w, w) == {"max": 0.0, "rms": 0.0}
    assert quality.weight_difference(w, w_near)["max"] == pytest.approx(0.25)


def test_deformation_quality_of_a_binding(arm_cage):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = ws.bind(EXAMPLE / "arm.obj", arm_cage, resolution=16, device="cpu")
    rest = ws.deformation_quality(b.weights, b.mesh_vertices, b.mesh_faces, arm_cage, arm_cage.vertices,
                                  reference=b.mesh_vertices, device="cpu")
    # the rest pose reproduces the mesh: no distortion, no dihedral change
    assert rest["regions"]["all"]["conformal"]["max"] < 1.001
    assert rest["regions"]["all"]["dihedral_change"]["max"] < 0.5
    assert rest["min_weight"] == pytest.approx(float(b.weights.min()))
    assert 0 <= rest["negative_fraction"] < 1
    bent = np.load(EXAMPLE / "bend_poses.npy")[-1]
    q = ws.deformation_quality(b.weights, b.mesh_vertices, b.mesh_faces, arm_cage, bent, device="cpu")
    assert q["regions"]["all"]["conformal"]["p95"] > 1.01 and "dihedral_change" not in q["regions"]["all"]
