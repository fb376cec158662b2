"""Progress while binding: one line on a terminal (stage, iteration, residual, time), nothing in logs or pipes."""

import os
import pty
import shutil
import sys

import warp_stokes as ws
from conftest import EXAMPLE, warp_stokes

ARGS = ["bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "--resolution", "24", "--device", "cpu"]


def on_a_terminal(args: list[str]) -> tuple[int, str]:
    """Run the command with stdout and stderr on a pseudo-terminal, as in an interactive shell."""
    exe = shutil.which("warp-stokes")
    command = [exe, *args] if exe else [sys.executable, "-m", "warp_stokes.cli", *args]
    pid, fd = pty.fork()
    if pid == 0:  # the child: the command, its output on the terminal
        os.execv(command[0], command)
    chunks = []
    while True:
        try:
            data = os.read(fd, 4096)
        except OSError:  # the terminal closes with the child
            break
        if not data:
            break
        chunks.append(data)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status), b"".join(chunks).decode()


def test_a_bind_on_a_terminal_shows_its_stages_on_one_line(tmp_path):
    code, text = on_a_terminal([*ARGS, "-o", str(tmp_path / "a.npz")])
    assert code == 0, text
    line = text.split("device ")[0]  # what was drawn before the table
    # (on several cores the handles are solved in chunks, one per thread: the stages name their chunk)
    for stage in ("arm.obj: voxelising at resolution 24", "arm.obj: multigrid", "arm.obj: boundary data",
                  "arm.obj: solving", ", iteration 1, residual", "arm.obj: sampling"):
        assert stage in line, (stage, line)
    assert "\n" not in line and line.endswith("\r")  # rewritten in place, cleared before the table starts
    assert text.index("arm.obj: sampling") < text.index("partition of unity")


def test_no_progress_in_a_pipe_or_with_quiet(tmp_path):
    proc = warp_stokes(*ARGS, "-o", str(tmp_path / "a.npz"))
    assert proc.returncode == 0 and "\r" not in proc.stderr and "solving" not in proc.stderr
    code, text = on_a_terminal([*ARGS, "-o", str(tmp_path / "b.npz"), "--quiet"])
    assert code == 0 and "solving" not in text and "\r\r" not in text.replace("\r\n", "")


def test_the_python_callback_sees_every_stage_in_order():
    seen = []
    ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=24, device="cpu",
            progress=lambda stage, **info: seen.append((stage, info)))
    stages = [s for s, _ in seen]
    first = {s: stages.index(s) for s in ("voxelising", "multigrid", "boundary data", "solving", "sampling")}
    assert first["voxelising"] < first["multigrid"] < first["boundary data"] < first["solving"] < first["sampling"]
    # each chunk's iterations in order (chunks solved at once by threads interleave)
    chunks = {info.get("chunk") for s, info in seen if s == "solving"}
    for chunk in chunks:
        iterations = [info["iteration"] for s, info in seen if s == "solving" and info.get("chunk") == chunk]
        assert iterations == list(range(1, len(iterations) + 1))
    assert all(info["residual"] >= 0 for s, info in seen if s == "solving")
    assert len(chunks) == (1 if ws.threads.cpu_threads() == 1 else min(ws.threads.cpu_threads(), 58))
