"""The cage editor without a page (warp_stokes.edit.CageEditor): moves and turns, pins, the schemes, undo and redo,
keys on a timeline, and saving through the writers ``animate`` uses, read back as a user would."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

import warp_stokes as ws
from conftest import cli
from warp_stokes.edit import CageEditor, rotation_matrix


@pytest.fixture(scope="module")
def binding(arm_npz):
    return ws.load_binding(arm_npz, device="cpu")


def lower_third(cage: np.ndarray) -> list:
    """The handles in the lowest third of the cage along its longest axis: a region an artist would pin."""
    axis = int(np.argmax(np.ptp(cage, axis=0)))
    lo, hi = cage[:, axis].min(), cage[:, axis].max()
    return [int(h) for h in np.flatnonzero(cage[:, axis] < lo + (hi - lo) / 3)]


def edge_lengths(cage: np.ndarray, faces: np.ndarray) -> np.ndarray:
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    return np.linalg.norm(cage[edges[:, 0]] - cage[edges[:, 1]], axis=1)


def test_a_move_with_no_scheme_moves_the_handles_alone_and_the_mesh_follows_as_deform_computes_it(binding):
    ed = CageEditor(binding, scheme="none")
    cage = ed.move([3, 7], offset=[0.0, 0.05, 0.0])
    expected = binding.cage_vertices.copy()
    expected[[3, 7], 1] += 0.05
    np.testing.assert_array_equal(cage, expected)
    np.testing.assert_allclose(ed.mesh(), binding.deform(cage), atol=1e-6)


def test_arap_keeps_the_cage_nearly_rigid_where_it_is_not_pulled_and_pins_hold(binding):
    ed = CageEditor(binding, scheme="arap")
    pinned = lower_third(ed.rest)
    ed.pin(pinned)
    top = int(np.argmax(ed.rest[:, int(np.argmax(np.ptp(ed.rest, axis=0)))]))
    offset = np.array([0.1 * ed.diagonal, 0.0, 0.0])
    cage = ed.move([top], offset)
    np.testing.assert_allclose(cage[top], ed.rest[top] + offset, atol=1e-12)
    np.testing.assert_array_equal(cage[pinned], ed.rest[pinned])
    rest, now = edge_lengths(ed.rest, binding.cage_faces), edge_lengths(cage, binding.cage_faces)
    change = np.abs(now - rest) / rest
    assert change.mean() < 0.02, change.mean()  # the bound: other edges within 2 % on average
    # the scheme matters: handles next to the pulled one moved with it, unlike "none"
    assert np.linalg.norm(cage - ed.rest, axis=1).astype(bool).sum() > 1 + 0


def test_laplacian_follows_smoothly_and_translates_everything_when_every_constraint_moves_together(binding):
    ed = CageEditor(binding, scheme="laplacian")
    ed.pin([0, 1, 2])
    shift = np.array([0.01, -0.02, 0.03])
    ed.move([0, 1, 2], shift)  # the pinned handles are the ones moved: everything goes with them
    np.testing.assert_allclose(ed.cage, ed.rest + shift, atol=1e-9)


def test_turning_every_handle_turns_the_mesh_exactly(binding):
    ed = CageEditor(binding, scheme="none")
    turn = rotation_matrix([0.2, -0.4, 0.3])
    centre = ed.rest.mean(axis=0)
    ed.move(range(binding.n_handles), rotation=turn, about=centre)
    expected = (binding.mesh_vertices - centre) @ turn.T + centre
    assert np.abs(ed.mesh() - expected).max() < 1e-5 * ed.diagonal  # linear precision, float32 weights


def test_undo_redo_and_reset_walk_the_history(binding):
    ed = CageEditor(binding, scheme="none")
    first = ed.move([5], [0.1, 0, 0])
    second = ed.move([6], [0, 0.1, 0])
    assert ed.undo()
    np.testing.assert_array_equal(ed.cage, first)
    assert ed.redo()
    np.testing.assert_array_equal(ed.cage, second)
    ed.reset()
    np.testing.assert_array_equal(ed.cage, ed.rest)
    assert ed.undo()
    np.testing.assert_array_equal(ed.cage, second)
    ed.move([1], [0, 0, 0.1])  # a new step forgets what was undone
    assert not ed.redo()


def test_the_timeline_inbetweens_keys_and_holds_beyond_them(binding):
    ed = CageEditor(binding, scheme="none")
    ed.key(0)
    ed.seek(10)
    ed.move([2], [0.0, 0.2, 0.0])
    ed.key(10)
    np.testing.assert_allclose(ed.pose_at(5)[2], ed.rest[2] + [0.0, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(ed.pose_at(2.5)[2], ed.rest[2] + [0.0, 0.05, 0.0], atol=1e-12)
    np.testing.assert_array_equal(ed.pose_at(-3), ed.rest)
    np.testing.assert_array_equal(ed.pose_at(40), ed.keys[10.0])
    poses = ed.timeline()
    assert poses.frames.tolist() == list(range(11))
    spline = CageEditor(binding, scheme="none", interpolation="spline")
    for frame, lift in ((0, 0.0), (10, 0.2), (20, 0.0)):
        spline.seek(frame)
        spline.set_cage(spline.rest + [0.0, lift, 0.0])
        spline.key(frame)
    assert spline.pose_at(5)[0, 1] - spline.rest[0, 1] > 0.1  # above the straight line 0.1: a curve
    np.testing.assert_allclose(spline.pose_at(5), spline.timeline().positions[5], atol=1e-12)


@pytest.mark.parametrize("suffix", [".npz", ".npy"])
def test_saved_poses_played_by_animate_give_the_edited_mesh(binding, arm_npz, tmp_path, suffix):
    """The issue's check: poses saved by the editor and written by ``animate`` equal the edited mesh within 1e-6 of
    the diagonal, frame by frame (read back with pxr)."""
    from pxr import Usd, UsdGeom

    ed = CageEditor(arm_npz, scheme="arap")
    ed.pin(lower_third(ed.rest))
    ed.key(0)
    ed.seek(4)
    ed.move([int(np.argmax(ed.rest[:, 1]))], [0.05 * ed.diagonal, 0.0, 0.0], rotation=[0.0, 0.0, 0.3])
    ed.key(4)
    saved = ed.save(tmp_path / f"poses{suffix}")
    assert len(saved.frames) == 5
    proc = cli("animate", arm_npz, tmp_path / f"poses{suffix}", "-o", tmp_path / "edited.usda")
    assert proc.returncode == 0, proc.stderr
    stage = Usd.Stage.Open(str(tmp_path / "edited.usda"))
    mesh = next(UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    diagonal = float(np.linalg.norm(np.ptp(binding.mesh_vertices, axis=0)))
    for k, frame in enumerate(saved.frames):
        time = float(frame) if suffix == ".npz" else k + 1.0  # a bare array's poses are frames 1, 2, ...
        written = np.asarray(mesh.GetPointsAttr().Get(time), dtype=np.float64)
        edited = ed.deform(ed.pose_at(frame))
        assert np.abs(written - edited).max() <= 1e-6 * diagonal, frame


def test_save_writes_usd_and_a_glb_skin_and_refuses_the_binding_and_unknown_kinds(binding, arm_npz, tmp_path):
    ed = CageEditor(arm_npz, scheme="none")
    ed.move([4], [0.0, 0.0, 0.1])
    ed.save(tmp_path / "pose.usda")
    from pxr import Usd

    assert Usd.Stage.Open(str(tmp_path / "pose.usda")) is not None
    pytest.importorskip("pygltflib")
    ed.save(tmp_path / "pose.glb")
    assert (tmp_path / "pose.glb").stat().st_size > 0
    with pytest.raises(ws.WarpStokesError, match="arm.npz"):
        ed.save(arm_npz)  # never over its own binding
    with pytest.raises(ws.WarpStokesError, match=r"\.txt: save poses as"):
        ed.save(tmp_path / "poses.txt")
    assert not (tmp_path / "poses.txt").exists()


def test_bad_edits_are_one_line_errors(binding):
    ed = CageEditor(binding)
    n = binding.n_handles
    for call, match in ((lambda: ed.move([n], [0, 0, 0]), f"handle {n} is not one of"),
                        (lambda: ed.move([1, 1], [0, 0, 0]), "each handle once"),
                        (lambda: ed.move([], [0, 0, 0]), "at least one handle"),
                        (lambda: ed.move([1], [0, np.nan, 0]), "offset"),
                        (lambda: ed.move([1], [0, 0, 0], rotation=np.diag([1.0, 1.0, -1.0])), "rotation"),
                        (lambda: ed.move([1], [0, 0, 0], scheme="bendy"), "scheme must be one of"),
                        (lambda: ed.seek(float("inf")), "finite"),
                        (lambda: CageEditor(binding, poses=np.zeros((2, n + 1, 3))), "poses of shape")):
        with pytest.raises(ws.WarpStokesError, match=match) as info:
            call()
        assert "\n" not in str(info.value)


class EditSessions(RuleBasedStateMachine):
    """Random edit sessions on the arm: whatever the order of moves, turns, pins, keys, undos and redos, the pinned
    handles stay put through a move, the moved ones land where asked, every pose is finite, and undoing every step
    comes back to the start."""

    binding = None

    def __init__(self):
        super().__init__()
        self.ed = CageEditor(self.binding, scheme="arap")
        self.steps = 0

    handle_sets = st.lists(st.integers(0, 57), min_size=1, max_size=4, unique=True)
    offsets = st.lists(st.floats(-0.2, 0.2, allow_nan=False), min_size=3, max_size=3)

    @rule(handles=handle_sets, offset=offsets, scheme=st.sampled_from(["none", "laplacian", "arap"]),
          turn=st.one_of(st.none(), st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3)))
    def move(self, handles, offset, scheme, turn):
        before = self.ed.cage
        held = [h for h in self.ed.pinned if h not in handles]
        wanted = self.ed.targets(handles, offset, turn)
        cage = self.ed.move(handles, offset, rotation=turn, scheme=scheme)
        self.steps += 1
        np.testing.assert_allclose(cage[handles], wanted, atol=1e-9 * self.ed.diagonal)
        np.testing.assert_array_equal(cage[held], before[held])

    @rule(handles=handle_sets)
    def pin(self, handles):
        self.ed.pin(handles)
        self.steps += 1

    @rule()
    def unpin(self):
        self.ed.unpin()
        self.steps += 1

    @rule(frame=st.integers(0, 30))
    def key(self, frame):
        self.ed.key(frame)
        self.steps += 1

    @precondition(lambda self: self.steps > 0)
    @rule()
    def undo(self):
        assert self.ed.undo()
        self.steps -= 1

    @invariant()
    def finite(self):
        assert np.all(np.isfinite(self.ed.cage))

    def teardown(self):
        while self.steps:
            assert self.ed.undo()
            self.steps -= 1
        np.testing.assert_array_equal(self.ed.cage, self.ed.rest)
        assert self.ed.pinned == () and self.ed.keys == {}


def test_random_edit_sessions_keep_their_promises(binding):
    EditSessions.binding = binding
    runner = EditSessions.TestCase
    runner.settings = settings(max_examples=25, stateful_step_count=12, deadline=None,
                               suppress_health_check=[HealthCheck.too_slow])
    runner("runTest").runTest()


def test_the_page_paints_each_material_in_its_colour_and_its_textures_mean(tmp_path, monkeypatch):
    """The editor's page shows a textured character in colour: each triangle in its material's group, a group's
    colour its base colour factor times its texture's mean (here an image of one colour with a darker diagonal), one grey group for a
    mesh without looks."""
    from conftest import box_cage, write_obj
    from looks_inputs import LooksCase, write_gltf_case
    from warp_stokes.cli import main
    from warp_stokes.edit.server import MESH, material_colours

    monkeypatch.chdir(tmp_path)
    vertices, faces = box_cage((-2.0, -1.0, -1.0), (2.0, 1.5, 1.0))
    write_obj(tmp_path / "cage.obj", vertices, faces)
    case = LooksCase((0, 1, 0), (True, False))
    write_gltf_case(tmp_path / "two.glb", case)
    assert main(["bind", "two.glb", "cage.obj", "-o", "b.npz", "--resolution", "8", "--device", "cpu", "--quiet"]) == 0
    binding = ws.load_binding("b.npz")
    groups, colours = material_colours(binding)
    darkened = tuple(int(round(c * 14 / 16)) for c in case.colours[0])  # the image's diagonal is half as bright
    assert colours == [darkened, case.colours[1], MESH]
    per_part = len(binding.mesh_faces) // 3
    assert groups.tolist() == [0] * per_part + [1] * per_part + [0] * per_part
    assert material_colours(CageEditor(binding).binding)[1] == colours
    plain = ws.Binding(binding.weights, binding.cage_vertices, binding.cage_faces, binding.mesh_vertices,
                       binding.mesh_faces, binding.settings, binding.stats)
    assert material_colours(plain)[1] == [MESH]


def test_an_edit_not_keyed_is_neither_saved_silently_nor_lost_to_a_seek(binding, arm_npz, tmp_path):
    """With keys on the timeline, saving writes the keys: an edit on top of them not keyed yet is refused with a
    line saying so, not dropped; a seek away from it is a step of the history, so undo brings it back, at its
    frame; a save never replaces the poses file the editor started from."""
    poses = tmp_path / "start.npz"
    np.savez(poses, poses=np.stack([binding.cage_vertices, binding.cage_vertices + 0.1]), frames=[0.0, 10.0])
    ed = CageEditor(arm_npz, poses=poses, scheme="none")
    assert sorted(ed.keys) == [0.0, 10.0] and ed.frame == 0.0
    ed.seek(5)
    moved = ed.move([3], [0.0, 0.2, 0.0])
    with pytest.raises(ws.WarpStokesError, match="the pose at frame 5 is not keyed: key it"):
        ed.save(tmp_path / "out.npz")
    assert not (tmp_path / "out.npz").exists()
    ed.seek(8)  # away from the edit: undoable
    assert not np.array_equal(ed.cage, moved)
    assert ed.undo()
    np.testing.assert_array_equal(ed.cage, moved)
    assert ed.frame == 5.0
    ed.key()
    assert len(ed.save(tmp_path / "out.npz").frames) == 11
    with pytest.raises(ws.WarpStokesError, match="start.npz"):
        ed.save(poses)
    # a seek far along the timeline costs one segment, not every frame between the keys
    ed.key(90000)
    np.testing.assert_allclose(ed.pose_at(45005), 0.5 * (ed.keys[10.0] + ed.keys[90000.0]), atol=1e-9)
