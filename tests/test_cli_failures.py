"""The command as a user meets it when something is wrong: each case runs the command line (CPU, small grids) and
checks the exit code, the one-line message and the files left behind (issue 13). In process (``main(argv)``, its
output captured) where a fresh process would add only its start; as a subprocess where the process is the subject:
Ctrl-C, the warnings a fresh process prints, a writer failing in a process of its own."""

import hashlib
import re
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, cli, cuda_available, float32_rounding, one_error_line, warp_stokes, write_obj
from warp_stokes.io.outputs import is_temporary

MESH, CAGE = str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj")


def test_version():
    proc = cli("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"warp-stokes {ws.__version__}"


@pytest.mark.parametrize("args, message", [
    (["--max-iterations", "-1"], "argument --max-iterations: must be an integer >= 1, got -1"),
    (["--tol", "0"], "argument --tol: must be > 0 and <= 0.1, got 0"),
    (["--tol", "nan"], "argument --tol: must be > 0 and <= 0.1, got nan"),
    (["--resolution", "abc"], "argument --resolution: 'abc' is neither auto nor an integer"),
    (["--memory-gb", "0"], "argument --memory-gb: must be > 0, got 0"),
])
def test_numbers_out_of_range_are_one_line_errors(tmp_path, args, message):
    proc = cli("bind", MESH, CAGE, "-o", str(tmp_path / "b.npz"), *args)
    assert proc.returncode == 2 and one_error_line(proc) == f"warp-stokes bind: error: {message}"
    assert os.listdir(tmp_path) == []


def test_outputs_are_checked_before_the_solve(tmp_path):
    # a missing folder: refused before anything is computed (no stats printed)
    proc = cli("bind", MESH, CAGE, "-o", str(tmp_path / "missing" / "b.npz"), "--device", "cpu")
    assert proc.returncode == 2 and proc.stdout == ""
    assert one_error_line(proc) == f"warp-stokes: error: {tmp_path / 'missing' / 'b.npz'}: the output folder " \
                                   f"{tmp_path / 'missing'} does not exist"
    # the output may not be an input: the mesh stays as it was
    mesh = tmp_path / "arm.obj"
    shutil.copy(MESH, mesh)
    before = hashlib.sha256(mesh.read_bytes()).hexdigest()
    binding = tmp_path / "arm.npz"
    shutil.copy(mesh, binding)  # a mesh saved under a binding's name
    proc = cli("bind", str(binding), CAGE, "-o", str(binding), "--device", "cpu")
    assert proc.returncode == 2 and "the output would replace the input" in one_error_line(proc)
    binding.unlink()
    assert hashlib.sha256(mesh.read_bytes()).hexdigest() == before
    # a folder that takes no files (for root too, who passes every permission check)
    proc = cli("bind", MESH, CAGE, "-o", "/proc/b.npz", "--device", "cpu")
    assert proc.returncode == 2 and proc.stdout == ""
    assert one_error_line(proc).startswith("warp-stokes: error: /proc/b.npz: the output folder /proc takes no new files")
    # nor a folder
    (tmp_path / "folder.npz").mkdir()
    proc = cli("bind", MESH, CAGE, "-o", str(tmp_path / "folder.npz"), "--device", "cpu")
    assert proc.returncode == 2 and "the output is a folder" in one_error_line(proc)
    (tmp_path / "folder.npz").rmdir()
    assert sorted(os.listdir(tmp_path)) == ["arm.obj"]


def test_a_mesh_far_outside_its_cage_is_refused(tmp_path):
    # wrong units or a transform not applied: the mesh sits 100 cage diagonals away
    cage = ws.check_cage(CAGE)
    mesh = ws.load_surface(MESH)
    far = tmp_path / "far.obj"
    write_obj(far, mesh.vertices + [100 * cage.diagonal, 0, 0], mesh.faces)
    proc = cli("bind", str(far), CAGE, "-o", str(tmp_path / "b.npz"), "--device", "cpu")
    assert proc.returncode == 2
    line = one_error_line(proc)
    assert "far.obj: 2089 of 2089 vertices (100%) lie outside" in line and "cage diagonals away" in line
    assert sorted(os.listdir(tmp_path)) == ["far.obj"]


def test_deform_takes_reordered_faces_and_plain_positions(tmp_path, arm_npz):
    cage = ws.load_surface(CAGE)
    moved = cage.vertices + [0.5, -0.25, 1.0]
    expected = ws.load_binding(arm_npz, device="cpu").deform(moved)  # on the CPU, like the commands below

    # the deformed cage as another exporter writes it: faces in another order, corners rotated
    rng = np.random.default_rng(3)
    faces = np.roll(cage.faces[rng.permutation(len(cage.faces))], 1, axis=1)
    shuffled = tmp_path / "shuffled.obj"
    write_obj(shuffled, moved, faces)
    positions = tmp_path / "moved.npy"
    np.save(positions, moved)
    for source, name in ((shuffled, "a.obj"), (positions, "b.obj")):
        proc = cli("deform", str(arm_npz), str(source), "-o", str(tmp_path / name), "--device", "cpu")
        assert proc.returncode == 0, proc.stderr
        # float32 positions (~140) deformed by the command (the OBJ's 8 decimals lose nothing of them): 8 eps
        np.testing.assert_allclose(ws.load_surface(tmp_path / name).vertices, expected, rtol=0,
                                   atol=float32_rounding(np.abs(expected).max()))

    # really another topology: refused with the reason, nothing written
    other = tmp_path / "other.obj"
    faces = cage.faces.copy()
    faces[0] = [faces[0][0], faces[0][1], faces[5][2] if faces[5][2] not in faces[0] else faces[7][2]]
    write_obj(other, moved, faces)
    proc = cli("deform", str(arm_npz), str(other), "-o", str(tmp_path / "c.obj"), "--device", "cpu")
    assert proc.returncode == 2 and "the pose's faces differ from the bound cage's" in one_error_line(proc)
    np.save(tmp_path / "short.npy", moved[:-1])
    proc = cli("deform", str(arm_npz), str(tmp_path / "short.npy"), "-o", str(tmp_path / "d.obj"), "--device", "cpu")
    assert proc.returncode == 2 and "positions of shape (57, 3); the bound cage needs (58, 3)" in one_error_line(proc)
    assert not (tmp_path / "c.obj").exists() and not (tmp_path / "d.obj").exists()


@pytest.mark.skipif(cuda_available(), reason="checks a machine without CUDA")
def test_no_cuda_warning_on_the_cpu_and_a_clear_error_when_cuda_is_asked_for(tmp_path, arm_npz):
    proc = warp_stokes("deform", str(arm_npz), CAGE, "-o", str(tmp_path / "rest.obj"))
    assert proc.returncode == 0 and "CUDA" not in proc.stderr, proc.stderr
    proc = warp_stokes("deform", str(arm_npz), CAGE, "-o", str(tmp_path / "x.obj"), "--device", "cuda")
    assert proc.returncode == 2 and "no CUDA driver or GPU was found" in one_error_line(proc)


def test_ctrl_c_exits_130_and_leaves_no_file(tmp_path):
    import pty
    import select

    exe = shutil.which("warp-stokes")
    command = [exe] if exe else [sys.executable, "-m", "warp_stokes.cli"]
    out = tmp_path / "b.npz"
    # stderr on a terminal, as a user's is: the progress line says when the solve has begun, so the signal comes
    # inside the solve however fast the machine (a fixed sleep let a faster bind finish first). The child handles
    # SIGINT as a command started from a terminal does, even where the suite runs with SIGINT ignored.
    leader, follower = pty.openpty()
    # two threads whatever the machine's cores: two chunks, each drawing at most one more iteration once signalled.
    # At resolution 96 the solve lasts seconds (4.7 s of 8.7 on 2 idle cores; 128 took 11 of 21): the signal, sent
    # as soon as "solving" is read, comes well inside it
    proc = subprocess.Popen(command + ["bind", MESH, CAGE, "-o", str(out), "--resolution", "96", "--device", "cpu",
                                       "--threads", "2"],
                            stdout=subprocess.PIPE, stderr=follower, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    os.close(follower)
    seen, deadline = "", time.monotonic() + 300
    try:
        while "solving" not in seen and proc.poll() is None and time.monotonic() < deadline:
            if select.select([leader], [], [], 1.0)[0]:
                seen += os.read(leader, 4096).decode(errors="replace")
        assert proc.poll() is None, f"the bind ended before it could be interrupted: {seen!r}"
        assert "solving" in seen, f"no progress line within 300 s: {seen!r}"
        proc.send_signal(signal.SIGINT)
        signalled = len(seen)
        proc.wait(timeout=120)
        while select.select([leader], [], [], 0.5)[0]:
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # the child's end closed (Linux reports EIO)
                break
            if not chunk:
                break
            seen += chunk.decode(errors="replace")
    finally:
        os.close(leader)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130
    # what is left on the terminal once the progress line is cleared: the last line written
    lines = [line.strip() for line in re.split(r"[\r\n]", seen) if line.strip()]
    assert lines[-1] == "warp-stokes: interrupted; no output was left half-written"
    assert os.listdir(tmp_path) == []
    # the chunks' solves on their threads stop at their next iteration (they used to run on to convergence, about
    # eight more iterations each, before the interrupt took effect)
    assert seen[signalled:].count("iteration") <= 4, seen[signalled:]


def test_a_self_intersecting_cage_is_refused_naming_two_crossing_faces(tmp_path):
    import trimesh

    sphere = trimesh.creation.icosphere(2)
    poked = sphere.vertices.copy()
    poked[0] = -1.5 * poked[0]
    cage = tmp_path / "poked.obj"
    trimesh.Trimesh(poked, sphere.faces, process=False).export(cage)
    proc = cli("bind", MESH, str(cage), "-o", str(tmp_path / "b.npz"), "--device", "cpu")
    assert proc.returncode == 2
    assert re.fullmatch(r"warp-stokes: error: .*poked\.obj: the cage intersects itself: faces \d+ \[\d+, \d+, \d+\] "
                        r"and \d+ \[\d+, \d+, \d+\] cross \(\d+ crossing pair\(s\)\); .*", one_error_line(proc))
    assert sorted(os.listdir(tmp_path)) == ["poked.obj"]


def test_a_full_disk_is_one_line_and_leaves_no_file(tmp_path, arm_npz, monkeypatch, capsys, device):
    # in process (so on the device under test), with the writers made to fail as they do on a full disk: the
    # binding's file write raises ENOSPC, and USD's Save returns False
    import errno

    from pxr import Sdf

    from warp_stokes.cli import main

    real_open = open

    def full_disk_open(path, mode="r", *args, **kwargs):
        if "w" in mode and is_temporary(str(path)):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real_open(path, mode, *args, **kwargs)

    out = tmp_path / "out"
    out.mkdir()
    with monkeypatch.context() as patch:
        patch.setattr("builtins.open", full_disk_open)
        rc = main(["bind", MESH, CAGE, "-o", str(out / "b.npz"), "--resolution", "16", "--device", device])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and [line for line in err if not line.startswith("warning:")] == [
        f"warp-stokes: error: {out / 'b.npz'}: could not write it: No space left on device"]
    assert os.listdir(out) == []

    with monkeypatch.context() as patch:
        patch.setattr(Sdf.Layer, "Save", lambda self, *args: False)
        rc = main(["animate", str(arm_npz), str(EXAMPLE / "bend_poses.npy"), "-o", str(out / "a.usd"),
                   "--device", device])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err == [f"warp-stokes: error: {out / 'a.usd'}: could not write the USD file (is the disk full "
                               "or the folder gone?)"]
    assert os.listdir(out) == []


def test_a_full_disk_during_animate_in_a_subprocess(tmp_path, arm_npz):
    # the command as a user runs it, with USD's writer failing as on a full disk (Save returns False)
    script = ("import sys; from pxr import Sdf; Sdf.Layer.Save = lambda self, *a: False; "
              "from warp_stokes.cli import main; sys.exit(main(sys.argv[1:]))")
    out = tmp_path / "out.usd"
    proc = subprocess.run([sys.executable, "-c", script, "animate", str(arm_npz), str(EXAMPLE / "bend_poses.npy"),
                           "-o", str(out), "--device", "cpu"], capture_output=True, text=True)
    assert proc.returncode == 2
    assert one_error_line(proc) == f"warp-stokes: error: {out}: could not write the USD file (is the disk full or " \
                                   "the folder gone?)"
    assert os.listdir(tmp_path) == []


def test_a_mesh_and_cage_the_other_way_round_get_a_hint(tmp_path):
    proc = cli("bind", CAGE, MESH, "-o", str(tmp_path / "b.npz"), "--device", "cpu")
    line = one_error_line(proc)
    assert proc.returncode == 2 and "arm.obj: the cage is not closed" in line
    assert "the cage has more vertices (2089) than the mesh (58): are the mesh and the cage the other way round?" in line
    # a cage that is merely bad gets no such guess
    proc = cli("bind", MESH, MESH, "-o", str(tmp_path / "b.npz"), "--device", "cpu")
    assert proc.returncode == 2 and "other way round" not in one_error_line(proc)
    assert not (tmp_path / "b.npz").exists()


def test_a_mesh_given_as_its_own_cage_is_refused_saying_so(tmp_path):
    # its vertices lie on the cage: not "outside, in other units" (what the message said), and nothing to solve
    import trimesh

    ball = tmp_path / "ball.obj"
    trimesh.creation.icosphere(2).export(ball)
    proc = cli("bind", str(ball), str(ball), "-o", str(tmp_path / "b.npz"), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 2
    assert one_error_line(proc) == (
        f"warp-stokes: error: {ball}: 162 of 162 vertices (100%) lie on {ball} itself; a cage must enclose the mesh "
        "with room around it (is the cage the mesh itself? `warp-stokes cage MESH -o CAGE.obj` makes one)")
    assert sorted(os.listdir(tmp_path)) == ["ball.obj"]


@pytest.mark.parametrize("scale, command", [(1e-11, "bind"), (1e20, "cage")])
def test_a_mesh_float32_cannot_resolve_is_refused_by_its_size(tmp_path, scale, command):
    # a ball 3.5e-11 or 3.5e20 across: `cage` said "no surface at the offset" or crashed in marching cubes with a
    # traceback (squared lengths overflow float32), `bind` that the mesh lay on its cage; now both name the size (the
    # check is in the loader both take: each command once)
    import trimesh

    ball = trimesh.creation.icosphere(2)
    mesh, cage = tmp_path / "ball.obj", tmp_path / "cage.obj"
    write_obj(mesh, ball.vertices * scale, ball.faces)
    write_obj(cage, 1.3 * ball.vertices * scale, ball.faces)
    diagonal = np.linalg.norm(np.ptp(ball.vertices * scale, axis=0))
    message = (f"its bounding diagonal is {diagonal:.3g}, outside what the solver's float32 arithmetic resolves "
               "(1e-08 to 1e+18 in any unit); scale it (to metres, say)")
    args = {"cage": ("cage", str(mesh), "-o", str(tmp_path / "made.obj")),
            "bind": ("bind", str(mesh), str(cage), "-o", str(tmp_path / "b.npz"), "--resolution", "16")}[command]
    proc = cli(*args, "--device", "cpu")
    assert proc.returncode == 2 and one_error_line(proc) == f"warp-stokes: error: {mesh}: {message}"
    assert sorted(os.listdir(tmp_path)) == ["ball.obj", "cage.obj"]
    # just inside the range, the same ball is made a cage and bound as at any size
    inside = (3e-8 if scale < 1 else 3e17) / np.linalg.norm(np.ptp(ball.vertices, axis=0))
    made = ws.make_cage((ball.vertices * inside, ball.faces), handles=30, device="cpu")
    binding = ws.bind((ball.vertices * inside, ball.faces), made.cage, resolution=16, device="cpu")
    assert made.cage.n_handles == 30
    assert binding.stats.partition_of_unity_error <= 1e-5 and binding.stats.linear_precision_error <= 1e-5
