"""Rigged animation in from glTF: ``ws.load_frames`` against an independent evaluation of the file's skinning
(``rigged_assets.reference_frames``: pygltflib and numpy, its own hierarchy and quaternion code) at every key time,
within 1e-5 of the bounding diagonal: the Fox (every animation), a bent cylinder built here (a joint chain under a
moved, scaled rig; two influence sets; STEP, LINEAR and CUBICSPLINE; a rigid prop on a joint; its buffer in a file
beside it), morph targets (one sparse) under a skin, several primitives, and random rigs drawn by hypothesis."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import warp_stokes as ws
from conftest import DATA
from rigged_assets import (FLOAT, UBYTE, USHORT, SkinnedGltf, cylinder, key_times_of, reference_frames,
                           trs_matrix)
from warp_stokes.io.scene import load_scene

FOX = DATA / "fox_gltf" / "Fox.glb"
TOLERANCE = 1e-5  # of the bounding diagonal


def quaternion(axis, angle):
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return np.concatenate([axis * np.sin(angle / 2), [np.cos(angle / 2)]])


def deviation(path, animation, fps=None) -> float:
    """The largest distance between ``load_frames`` and the reference at the frames' times, over the diagonal;
    the frames' times are the animation's key times (or its rate's samples)."""
    frames = ws.load_frames(path, animation=animation, fps=fps)
    keys = key_times_of(path, animation)
    # the times as the file keeps them (the frame numbers are whole where within 1e-4 of one: a STEP key's time
    # from them could fall a hair before the key)
    seconds = keys if fps is None else keys[0] + (1.0 / fps) * np.arange(len(frames.frames))
    assert np.allclose(frames.frames / frames.time_codes_per_second, seconds, atol=1e-5)
    reference = reference_frames(path, animation, seconds)
    assert frames.positions.shape == reference.shape
    diagonal = np.linalg.norm(np.ptp(reference.reshape(-1, 3), axis=0))
    return float(np.abs(frames.positions - reference).max() / diagonal)


def bent_cylinder(path, weight_type=FLOAT):
    """A cylinder skinned to a three-joint chain under a moved, turned and scaled rig node, two influence sets per
    vertex (a joint named twice, sums of weights 0.9 to 1.1), the mesh node itself moved (glTF ignores that for a
    skinned mesh), a rigid prop hanging on the last joint; animations Bend (STEP translation, LINEAR rotations with a
    quaternion sign flip, CUBICSPLINE rotation and LINEAR scale) and Wave."""
    gltf = SkinnedGltf()
    rig = gltf.node("Rig", root=True, translation=[0.2, -0.1, 0.3], rotation=quaternion([0, 0, 1], 0.3).tolist(),
                    scale=[1.5, 1.5, 1.5])
    rest = [dict(translation=[0, 0, 0]), dict(translation=[0, 1, 0]), dict(translation=[0, 1, 0])]
    joints = [gltf.node("j0", rig, **rest[0])]
    joints.append(gltf.node("j1", joints[0], **rest[1]))
    joints.append(gltf.node("j2", joints[1], **rest[2]))
    worlds = [trs_matrix(**rest[0])]
    for r in rest[1:]:
        worlds.append(worlds[-1] @ trs_matrix(**r))
    points, faces = cylinder()
    height = points[:, 1] / 3.0
    w = np.stack([np.clip(1 - 2 * height, 0, 1), 1 - np.abs(2 * height - 1), np.clip(2 * height - 1, 0, 1)], 1)
    scale = 0.9 + 0.2 * np.linspace(0, 1, len(points))  # sums of 0.9 to 1.1: normalised when read
    joint_sets = np.zeros((len(points), 8), dtype=int)
    weight_sets = np.zeros((len(points), 8))
    joint_sets[:, [0, 1, 4, 5]] = [0, 1, 2, 1]
    weight_sets[:, [0, 1, 4, 5]] = np.stack([w[:, 0], 0.6 * w[:, 1], w[:, 2], 0.4 * w[:, 1]], 1) * scale[:, None]
    body = gltf.mesh("Body", [dict(points=points, faces=faces, joints=joint_sets, weights=weight_sets,
                                   weight_type=weight_type, joint_type=UBYTE)])
    gltf.node("Body", root=True, mesh=body, skin=gltf.skin(joints, np.linalg.inv(worlds)),
              translation=[5.0, 5.0, 5.0])
    prop_points = np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0], [0, 0, 0.3]], dtype=float)
    prop = gltf.mesh("Prop", [dict(points=prop_points, faces=np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))])
    gltf.node("Prop", joints[2], mesh=prop, translation=[0, 0.5, 0])
    flip = -quaternion([0, 0, 1], 0.9)  # the same rotation as +q: interpolated along the shorter arc
    cubic = np.stack([np.stack([np.zeros(4), quaternion([1, 0, 0], a), 0.3 * np.ones(4)]) for a in (0.0, 0.8, -0.4)])
    gltf.animation("Bend", [
        (joints[0], "translation", [0.0, 0.5, 1.0], [[0, 0, 0], [0.1, 0, 0], [0, 0.2, 0]], "STEP"),
        (joints[1], "rotation", [0.0, 0.25, 1.0], [quaternion([0, 0, 1], 0.0), quaternion([0, 0, 1], 0.6), flip],
         "LINEAR"),
        (joints[2], "rotation", [0.0, 0.4, 1.0], cubic, "CUBICSPLINE"),
        (rig, "scale", [0.0, 1.0], [[1.5, 1.5, 1.5], [1.2, 1.8, 1.5]], "LINEAR"),
    ])
    gltf.animation("Wave", [(joints[1], "rotation", [0.0, 1 / 24, 2 / 24, 3 / 24],
                             [quaternion([1, 0, 1], a) for a in (0.0, 0.5, 0.0, -0.5)], "LINEAR")])
    return gltf.save(path)


@pytest.mark.parametrize("animation", ["Survey", "Walk", "Run"])
def test_the_fox_matches_an_independent_evaluation_of_its_skin(animation):
    if not FOX.exists():
        pytest.skip(f"test data not found: {FOX} (set WARP_STOKES_DATA)")
    assert deviation(FOX, animation) <= TOLERANCE
    frames = ws.load_frames(FOX, animation=animation)
    assert frames.positions.shape[1:] == (1728, 3) and frames.time_codes_per_second == 24
    # the vertices bind reads, in its order (the reference's, unskinned)
    assert np.allclose(load_scene(FOX).surface().vertices, reference_frames(FOX, None, [0.0])[0], atol=1e-4)


@pytest.mark.parametrize("name, weight_type", [("bent.gltf", FLOAT), ("bent.glb", UBYTE), ("bent16.glb", USHORT)])
def test_a_bent_cylinder_matches_the_reference_in_every_animation(tmp_path, name, weight_type):
    path = bent_cylinder(tmp_path / name, weight_type)
    for animation in ("Bend", "Wave"):
        assert deviation(path, animation) <= TOLERANCE, animation
    assert deviation(path, "Bend", fps=30) <= TOLERANCE  # between the keys too: every interpolation
    frames = ws.load_frames(path, animation="Bend", fps=30)
    assert frames.time_codes_per_second == 30 and frames.frames.tolist() == list(range(31))
    # the order and the place bind reads: the meshes' stored positions by their nodes, Body then Prop
    assert np.allclose(load_scene(path).surface().vertices, reference_frames(path, None, [0.0])[0], atol=1e-6)


def morphed(path) -> str:
    """A cylinder with two morph targets (the second sparse) and default weights, skinned to two joints; animation
    Morph keys the node's weights, animation Turn only the joints (the mesh's default weights hold)."""
    gltf = SkinnedGltf()
    base = gltf.node("j0", root=True, translation=[0, 0, 0])
    tip = gltf.node("j1", base, translation=[0, 1.5, 0])
    points, faces = cylinder()
    bulge = np.where(points[:, 1:2] > 1.0, 0.2, 0.0) * np.array([[1.0, 0, 0]])
    rows = np.arange(0, len(points), 3)
    lift = np.tile([[0.0, 0.3, 0.0]], (len(rows), 1))
    joint_sets = np.zeros((len(points), 4), dtype=int)
    joint_sets[:, 1] = 1
    share = np.clip(points[:, 1] / 3.0, 0, 1)
    weights = np.zeros((len(points), 4))
    weights[:, 0], weights[:, 1] = 1 - share, share
    mesh = gltf.mesh("Blob", [dict(points=points, faces=faces, joints=joint_sets, weights=weights,
                                   targets=[bulge, ("sparse", rows, lift)])], weights=[0.5, 0.0])
    inverse_bind = np.linalg.inv([trs_matrix([0, 0, 0]), trs_matrix([0, 1.5, 0])])
    blob = gltf.node("Blob", root=True, mesh=mesh, skin=gltf.skin([base, tip], inverse_bind))
    gltf.animation("Morph", [(blob, "weights", [0.0, 0.5, 1.0], [[0.0, 0.0], [1.0, 0.5], [0.2, 1.0]], "LINEAR"),
                             (tip, "rotation", [0.0, 1.0], [quaternion([0, 0, 1], 0), quaternion([0, 0, 1], 0.7)],
                              "LINEAR")])
    gltf.animation("Turn", [(tip, "rotation", [0.0, 1.0], [quaternion([1, 0, 0], 0), quaternion([1, 0, 0], -0.5)],
                             "LINEAR")])
    return gltf.save(path)


def test_morph_targets_sparse_and_dense_under_a_skin_match_the_reference(tmp_path):
    path = morphed(tmp_path / "blob.glb")
    for animation in ("Morph", "Turn"):
        assert deviation(path, animation) <= TOLERANCE, animation
    assert deviation(path, "Morph", fps=12) <= TOLERANCE


def test_a_mesh_of_several_primitives_comes_in_the_order_bind_reads_every_time(tmp_path):
    gltf = SkinnedGltf()
    joint = gltf.node("joint", root=True)
    parts = []
    for k in range(3):
        points, faces = cylinder(rings=3 + k)
        points = points + [k, 0, 0]
        parts.append(dict(points=points, faces=faces, joints=np.zeros((len(points), 4), dtype=int),
                          weights=np.tile([1.0, 0, 0, 0], (len(points), 1))))
    mesh = gltf.mesh("Parts", parts)
    gltf.node("Parts", root=True, mesh=mesh, skin=gltf.skin([joint], [np.eye(4)]))
    gltf.animation("Lift", [(joint, "translation", [0.0, 1.0], [[0, 0, 0], [0, 1, 0]], "LINEAR")])
    path = gltf.save(tmp_path / "parts.glb")
    assert deviation(path, "Lift") <= TOLERANCE
    rest = reference_frames(path, None, [0.0])[0]
    for _ in range(3):  # trimesh names each primitive's node at random: the order must not follow those names
        assert np.array_equal(load_scene(path).surface().vertices, rest)


def test_wrong_or_missing_animations_are_one_error_listing_what_the_file_has(tmp_path):
    path = bent_cylinder(tmp_path / "bent.glb")
    with pytest.raises(ws.BindingError, match=r"bent.glb: no animation 'Walk'; its animations: Bend, Wave$"):
        ws.load_frames(path, animation="Walk")
    with pytest.raises(ws.BindingError, match=r"2 animations \(Bend, Wave\); name one \(--animation\)"):
        ws.load_frames(path)
    assert ws.load_frames(path, animation=1).name.endswith(":Wave")  # or by number
    gltf = SkinnedGltf()
    points, faces = cylinder()
    gltf.node("Still", root=True, mesh=gltf.mesh("Still", [dict(points=points, faces=faces)]))
    still = gltf.save(tmp_path / "still.glb")
    with pytest.raises(ws.BindingError, match="still.glb: the file has no animations"):
        ws.load_frames(still)
    with pytest.raises(ws.BindingError, match="fps must be > 0"):
        ws.load_frames(path, animation="Bend", fps=-1)
    with pytest.raises(ws.BindingError, match="more than 100000"):
        ws.load_frames(path, animation="Bend", fps=1e9)


def test_a_skin_naming_a_joint_it_does_not_have_is_refused(tmp_path):
    gltf = SkinnedGltf()
    joint = gltf.node("joint", root=True)
    points, faces = cylinder()
    joint_sets = np.zeros((len(points), 4), dtype=int)
    joint_sets[:, 0] = 3
    mesh = gltf.mesh("Body", [dict(points=points, faces=faces, joints=joint_sets,
                                   weights=np.tile([1.0, 0, 0, 0], (len(points), 1)))])
    gltf.node("Body", root=True, mesh=mesh, skin=gltf.skin([joint], [np.eye(4)]))
    gltf.animation("Lift", [(joint, "translation", [0.0, 1.0], [[0, 0, 0], [0, 1, 0]], "LINEAR")])
    path = gltf.save(tmp_path / "bad.glb")
    with pytest.raises(ws.BindingError, match=r"bad.glb: mesh 'Body' \(primitive 0\) names joint 3, its skin has 1"):
        ws.load_frames(path)


# --- random rigs ------------------------------------------------------------------------------------------

unit = st.floats(-1.0, 1.0, allow_nan=False)
rotations = st.tuples(unit, unit, unit, unit).filter(lambda q: np.linalg.norm(q) > 0.2)


@st.composite
def rigs(draw):
    """A random skinned glTF's makings: a joint tree (each joint's parent drawn among those before it, or none),
    rest transforms, keyed channels of any interpolation, and 1 to 3 influence sets of random weights."""
    n_joints = draw(st.integers(1, 5))
    parents = [None] + [draw(st.one_of(st.none(), st.integers(0, j - 1))) for j in range(1, n_joints)]
    rest = [dict(translation=[draw(unit), draw(unit), draw(unit)], rotation=list(draw(rotations)),
                 scale=[draw(st.floats(0.5, 2.0))] * 3) for _ in range(n_joints)]
    channels = []
    for joint in range(n_joints):
        for path in draw(st.sets(st.sampled_from(["translation", "rotation", "scale"]))):
            interpolation = draw(st.sampled_from(["LINEAR", "STEP", "CUBICSPLINE"]))
            n_keys = draw(st.integers(2, 4))
            times = np.cumsum([0.0] + [draw(st.floats(0.05, 0.5)) for _ in range(n_keys - 1)])
            width = 4 if path == "rotation" else 3
            keys = [list(draw(rotations)) if path == "rotation" else
                    [draw(st.floats(0.5, 1.5)) if path == "scale" else draw(unit) for _ in range(3)]
                    for _ in range(n_keys)]
            values = np.array(keys)
            if interpolation == "CUBICSPLINE":
                tangents = np.array([[draw(unit) * 0.3 for _ in range(width)] for _ in range(2 * n_keys)])
                values = np.stack([tangents[:n_keys], values, tangents[n_keys:]], axis=1)
            channels.append((joint, path, times, values, interpolation))
    sets = draw(st.integers(1, 3))
    n_points = 9
    weights = np.array([[draw(st.sampled_from([0.0, 0.1, 0.5, 1.0])) for _ in range(4 * sets)]
                        for _ in range(n_points)])
    weights[:, 0] += 0.05  # every vertex weighted
    joints = np.array([[draw(st.integers(0, n_joints - 1)) for _ in range(4 * sets)] for _ in range(n_points)])
    weight_type = draw(st.sampled_from([FLOAT, UBYTE, USHORT]))
    return parents, rest, channels, weights, joints, weight_type


@settings(max_examples=12, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                                 HealthCheck.function_scoped_fixture])
@given(rig=rigs())
def test_random_rigs_match_the_reference(tmp_path, rig):
    parents, rest, channels, weights, joints, weight_type = rig
    gltf = SkinnedGltf()
    holder = gltf.node("Holder", root=True, translation=[0.3, 0.0, -0.2],
                       rotation=quaternion([1, 1, 0], 0.4).tolist())
    nodes, worlds = [], []
    for j, (parent, transform) in enumerate(zip(parents, rest)):
        nodes.append(gltf.node(f"joint{j}", holder if parent is None else nodes[parent], **transform))
        local = trs_matrix(**transform)
        worlds.append(local if parent is None else worlds[parent] @ local)
    rng = np.random.default_rng(len(channels))
    points = rng.uniform(-1, 1, (9, 3))
    faces = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6], [6, 7, 8]])
    if weight_type != FLOAT:  # normalised integers: each vertex's weights as they will be stored
        largest = 255 if weight_type == UBYTE else 65535
        weights = np.round(weights / weights.max(axis=1, keepdims=True) * largest) / largest
    mesh = gltf.mesh("Body", [dict(points=points, faces=faces, joints=joints, weights=weights,
                                   weight_type=weight_type)])
    inverse_bind = np.linalg.inv(np.array(worlds) @ trs_matrix([0.1, 0.2, 0.0], quaternion([0, 1, 0], 0.2)))
    gltf.node("Body", root=True, mesh=mesh, skin=gltf.skin(nodes, inverse_bind), translation=[1.0, 2.0, 3.0])
    moved = [(nodes[joint], *rest_of) for joint, *rest_of in channels] or [
        (nodes[0], "translation", np.array([0.0, 1.0]), np.array([[0, 0, 0], [0.5, 0, 0]]), "LINEAR")]
    gltf.animation("Random", moved)
    path = gltf.save(tmp_path / "random.glb")
    assert deviation(path, "Random") <= TOLERANCE
    assert deviation(path, "Random", fps=20) <= TOLERANCE


@settings(max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                                 HealthCheck.function_scoped_fixture])
@given(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), max_size=4))
def test_a_damaged_glb_is_read_or_refused_in_one_line(tmp_path, cut, flips):
    """Bytes cut off or changed anywhere (the JSON included): frames, or one WarpStokesError naming the file."""
    whole = bytearray(open(bent_cylinder(tmp_path / "whole.glb"), "rb").read())
    for where, value in flips:
        whole[int(where * (len(whole) - 1))] = value
    damaged = tmp_path / "damaged.glb"
    damaged.write_bytes(bytes(whole[:max(1, int(cut * len(whole)))] if cut < 1 else whole))
    try:
        frames = ws.load_frames(damaged, animation="Bend")
    except ws.WarpStokesError as exc:
        assert "damaged.glb" in str(exc) and "\n" not in str(exc)
    else:
        assert np.isfinite(frames.positions).all()
