"""``warp-stokes edit`` as a user meets it: the command started as a process, its page loaded in a real headless
Chromium (Debian's ``chromium``, driven by playwright), a screenshot with the mesh on it, an edit made through the
page's panel, saved through it, and the saved poses played by ``animate``; the server on 127.0.0.1 alone."""

from __future__ import annotations

import io
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import warp_stokes as ws
from conftest import cli

pytest.importorskip("viser")
playwright = pytest.importorskip("playwright.sync_api")
CHROMIUM = next((shutil.which(name) for name in ("chromium", "chromium-browser") if shutil.which(name)), None)
# what renders viser's WebGL page without a GPU or a screen
CHROMIUM_ARGS = ["--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def listening_addresses(port: int) -> set:
    """The local addresses with a socket listening on ``port`` (from /proc/net/tcp and tcp6, hex as Linux writes
    them): "0100007F" is 127.0.0.1, all zeros is every address."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as fh:
            for line in fh.readlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                address, hex_port = local.split(":")
                if state == "0A" and int(hex_port, 16) == port:
                    found.add(address)
    return found


@pytest.fixture
def editing(arm_npz, tmp_path):
    """``warp-stokes edit`` running on a free port: (process, url, where Save writes)."""
    port, output = free_port(), tmp_path / "edited.npz"
    exe = shutil.which("warp-stokes")
    command = [exe] if exe else [sys.executable, "-m", "warp_stokes.cli"]
    proc = subprocess.Popen([*command, "edit", str(arm_npz), "-o", str(output), "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = first_line(proc, seconds=120)  # the command says where it serves once it does
        assert line.startswith("editing ") and f"http://127.0.0.1:{port}" in line, (line, proc.stderr.read()
                                                                                     if proc.poll() is not None else "")
        yield proc, f"http://127.0.0.1:{port}", output
    finally:
        proc.send_signal(signal.SIGINT)  # Ctrl-C: how an editor is left, exit 0
        try:
            out, err = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    assert proc.returncode == 0 and out.strip().splitlines()[-1] == "stopped", (proc.returncode, out, err)


def first_line(proc, seconds: float) -> str:
    """The process's first line of stdout, or "" after ``seconds`` (a command that never says it serves fails the
    test instead of hanging the suite)."""
    import selectors

    with selectors.DefaultSelector() as waiting:
        waiting.register(proc.stdout, selectors.EVENT_READ)
        return proc.stdout.readline() if waiting.select(timeout=seconds) else ""


def panel_input(page, label: str):
    """The inputs of the panel's row labelled ``label``."""
    return page.locator(f"xpath=//label[normalize-space()='{label}']/../../following-sibling::div[1]//input")


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (CI installs Debian's)")
def test_the_page_shows_the_mesh_and_an_edit_through_it_is_saved_and_played_back(editing, arm_npz, tmp_path):
    from PIL import Image

    proc, url, output = editing
    port = int(url.rsplit(":", 1)[1])
    assert listening_addresses(port) == {"0100007F"}  # 127.0.0.1 only
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1000, "height": 700})
            page.goto(url)
            page.get_by_role("button", name="Move selected by offset").wait_for(timeout=60_000)
            blank = Image.open(io.BytesIO(page.screenshot())).convert("L")
            drawn = _wait_for_drawing(page)
            assert drawn > 0.005, (drawn, blank)  # the scene's part of the page (the panel left out) shows a mesh

            panel_input(page, "Selected handles").fill("40")
            page.get_by_text("selected 40", exact=True).wait_for(timeout=30_000)  # taken before the move is asked
            offset = panel_input(page, "Offset")
            offset.nth(0).fill("2.5")
            offset.nth(0).press("Tab")
            page.get_by_role("button", name="Move selected by offset").click()
            page.get_by_text("moved", exact=True).wait_for(timeout=30_000)
            page.get_by_role("button", name="Save").click()
            page.get_by_text("saved", exact=True).wait_for(timeout=30_000)
        finally:
            browser.close()
    saved = np.load(output)
    expected = ws.CageEditor(arm_npz, scheme="arap")
    expected.move([40], [2.5, 0.0, 0.0])
    np.testing.assert_allclose(saved["poses"][0], expected.cage, atol=1e-9)
    assert np.abs(saved["poses"][0][40] - expected.rest[40]).max() == pytest.approx(2.5)

    played = cli("animate", arm_npz, output, "-o", tmp_path / "played.usda")
    assert played.returncode == 0, played.stderr
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(tmp_path / "played.usda"))
    mesh = next(UsdGeom.Mesh(prim) for prim in stage.Traverse() if prim.IsA(UsdGeom.Mesh))
    points = np.asarray(mesh.GetPointsAttr().Get(0.0))
    assert np.abs(points - expected.mesh()).max() <= 1e-6 * expected.diagonal


def _wait_for_drawing(page, seconds: float = 60.0) -> float:
    """The fraction of the scene's pixels (the left 60 % of the page: the panel is on the right) that differ from
    the background, once the mesh is drawn (software WebGL takes a few seconds)."""
    from PIL import Image

    deadline = time.monotonic() + seconds
    while True:
        shot = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("L"), dtype=np.float64)
        scene = shot[shot.shape[0] // 5: -shot.shape[0] // 5, shot.shape[1] // 5: int(shot.shape[1] * 0.6)]
        background = np.median(scene)
        drawn = float(np.mean(np.abs(scene - background) > 24))
        if drawn > 0.005 or time.monotonic() > deadline:
            return drawn
        time.sleep(0.5)


def test_the_editor_listens_elsewhere_only_when_told_and_refuses_without_viser(arm_npz, tmp_path):
    """Without viser the command is one line saying how to install it; given another host, the server listens on
    it."""
    script = ("import sys; sys.modules['viser'] = None\n"
              "from warp_stokes.cli import main; sys.exit(main(sys.argv[1:]))")
    proc = subprocess.run([sys.executable, "-c", script, "edit", str(arm_npz)], capture_output=True, text=True,
                          timeout=120, env=dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1])))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == ["warp-stokes: error: the editor needs viser: pip install "
                                                "'warp-stokes[edit]'"]
    from warp_stokes.edit.server import EditorServer

    port = free_port()
    server = EditorServer(ws.CageEditor(arm_npz), host="0.0.0.0", port=port)
    try:
        assert listening_addresses(port) & {"00000000", "00000000000000000000000000000000"}
    finally:
        server.stop()


def test_a_gizmo_drag_moves_and_turns_the_selection_in_one_undo_step(arm_npz):
    """The page's drag, as its callbacks receive it (start, updates, end): the selected handles follow the gizmo's
    translation and turn, the pinned ones stay, the mesh sent is the editor's, and one undo takes the drag back."""
    from types import SimpleNamespace

    from warp_stokes.edit.editor import rotation_matrix
    from warp_stokes.edit.server import EditorServer, _quaternion_matrix

    editor = ws.CageEditor(arm_npz, scheme="arap")
    editor.pin(range(10))
    server = EditorServer(editor, port=free_port())
    try:
        server.select([40, 41])
        start = editor.cage
        pivot = np.array(server._gizmo.position)
        np.testing.assert_allclose(pivot, start[[40, 41]].mean(axis=0))
        server._gizmo_moved(SimpleNamespace(phase="start"))
        angle = 0.3
        for step in (0.25, 0.5, 1.0):  # the pointer's path: each update from where the drag began
            server._gizmo.position = pivot + step * np.array([1.0, 2.0, 0.0])
            server._gizmo.wxyz = (np.cos(step * angle / 2), 0.0, 0.0, np.sin(step * angle / 2))
            server._gizmo_moved(SimpleNamespace(phase="update"))
        server._gizmo_moved(SimpleNamespace(phase="end"))
        turn = rotation_matrix([0.0, 0.0, angle])
        np.testing.assert_allclose(_quaternion_matrix(server._gizmo.wxyz), turn, atol=1e-12)
        expected = (start[[40, 41]] - pivot) @ turn.T + pivot + [1.0, 2.0, 0.0]
        np.testing.assert_allclose(editor.cage[[40, 41]], expected, atol=1e-9)
        np.testing.assert_array_equal(editor.cage[:10], start[:10])
        np.testing.assert_array_equal(server._parts[0][1].vertices, editor.mesh()[server._parts[0][0]])
        assert editor.undo()
        np.testing.assert_array_equal(editor.cage, start)  # the whole drag, one step
        # the weights view: the mesh coloured by the picked handle's weights, the plain mesh hidden meanwhile
        server._show_weights.value = True
        assert server._weights is not None and not server._parts[0][1].visible
        server._show_weights.value = False
        assert server._weights is None and server._parts[0][1].visible
    finally:
        server.stop()


@pytest.mark.parametrize("case", ["no binding", "a folder as the binding", "text as the binding",
                                  "poses of another cage", "output over the binding", "output over the poses",
                                  "output a folder", "an unknown scheme", "a port out of range"])
def test_bad_input_is_one_line_before_anything_is_served(arm_npz, tmp_path, monkeypatch, case):
    """What the editor reads and writes is checked before it serves: one line, exit 2, nothing made."""
    import warp_stokes.edit.server as server_module

    def served(*args, **kwargs):
        raise AssertionError(f"{case}: served")

    monkeypatch.setattr(server_module, "EditorServer", served)
    shutil.copy(arm_npz, tmp_path / "arm.npz")
    np.save(tmp_path / "poses.npy", np.zeros((2, 58, 3)))
    np.save(tmp_path / "other.npy", np.zeros((2, 12, 3)))
    (tmp_path / "text.npz").write_text("not a binding")
    (tmp_path / "folder").mkdir()
    argv = {"no binding": ["missing.npz"], "a folder as the binding": ["folder"], "text as the binding": ["text.npz"],
            "poses of another cage": ["arm.npz", "other.npy"], "output over the binding": ["arm.npz", "-o", "arm.npz"],
            "output over the poses": ["arm.npz", "poses.npy", "-o", "poses.npy"],
            "output a folder": ["arm.npz", "-o", "folder"], "an unknown scheme": ["arm.npz", "--scheme", "bendy"],
            "a port out of range": ["arm.npz", "--port", "70000"]}[case]
    before = sorted(p.name for p in tmp_path.iterdir())
    proc = cli("edit", *argv, cwd=tmp_path)
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before
