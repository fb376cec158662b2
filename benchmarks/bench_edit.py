"""How fast an edit reaches the page: the live editor's move -> cage follows -> mesh deformed -> sent, per scheme.

    python benchmarks/bench_edit.py --pair ogre --resolution 32 --moves 40
    python benchmarks/bench_edit.py --pair fox --resolution 32          # the Fox in a cage made for it

A second table gives, for the pair's cage, what the issue asks of ARAP: the highest handle (along the cage's longest
axis) moved by 10 % of the diagonal across that axis with the lowest third pinned: the other edges' mean change of
length, and the distance from libigl's ARAP on the same constraints, both run to convergence (when ``igl`` is
installed).

Binds the pair on the CPU (or reads ``--binding``), starts the editor's server with a headless Chromium connected
to its page (so that every update is encoded and sent to a real client), pins the lowest third of the cage, then
drags the highest handle in ``--moves`` small steps (as a gizmo drag does: no history step each, ARAP's iterations
capped at ``DRAG_ITERATIONS`` from the last pose) with each scheme.
Per step it times, on the Python side: the cage following (``CageEditor.place``), the deformation (one product of
the weights with the pose), and the page update (every scene node's new data encoded and handed to the server,
``EditorServer.update``, which flushes). The table gives the median, 95th percentile and largest step in ms.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import socket
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import PAIRS, markdown_table  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def lower_third(cage: np.ndarray) -> list:
    axis = int(np.argmax(np.ptp(cage, axis=0)))
    lo, hi = cage[:, axis].min(), cage[:, axis].max()
    return [int(h) for h in np.flatnonzero(cage[:, axis] < lo + (hi - lo) / 3)], axis


FOX = PAIRS["ogre"][0].parents[1] / "fox_gltf" / "Fox.glb"


def arap_quality(binding, pinned: list, top: int, axis: int) -> tuple:
    """(mean relative length change of the edges not at the moved handle, libigl's distance / diagonal or None,
    iterations) for the 10 % move with ARAP run to convergence."""
    from warp_stokes.geometry.cage_follow import CageFollow

    rest, faces = binding.cage_vertices, binding.cage_faces
    diagonal = float(np.linalg.norm(np.ptp(rest, axis=0)))
    target = rest[top] + 0.1 * diagonal * np.eye(3)[(axis + 1) % 3]
    handles = np.array(pinned + [top])
    targets = np.vstack([rest[pinned], target])
    result = CageFollow(rest, faces).solve(handles, targets, "arap", iterations=5000, tolerance=1e-9, report=True)
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1),
                      axis=0)
    others = edges[(edges != top).all(axis=1)]
    length = lambda v: np.linalg.norm(v[others[:, 0]] - v[others[:, 1]], axis=1)  # noqa: E731
    change = float(np.mean(np.abs(length(result.vertices) - length(rest)) / length(rest)))
    try:
        import igl
    except ImportError:
        return change, None, result.iterations
    data = igl.ARAPData()
    data.max_iter = 5000
    igl.arap_precomputation(rest, faces, 3, handles.astype(np.int32), data)
    theirs = igl.arap_solve(targets, data, rest.copy())
    return change, float(np.abs(theirs - result.vertices).max() / diagonal), result.iterations


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pair", default="ogre", choices=sorted(PAIRS) + ["fox"])
    parser.add_argument("--binding", default=None, help="a binding file instead of binding the pair")
    parser.add_argument("--resolution", type=int, default=32)
    parser.add_argument("--moves", type=int, default=40)
    parser.add_argument("--no-browser", action="store_true", help="no page connected (the encoding alone)")
    parser.add_argument("--screenshot", default=None, help="save the page after the drags here (PNG)")
    args = parser.parse_args()

    import warp_stokes as ws
    from warp_stokes.edit.server import DRAG_ITERATIONS, EditorServer

    if args.binding:
        binding = ws.load_binding(args.binding, device="cpu")
    else:
        mesh, cage = (FOX, "auto") if args.pair == "fox" else PAIRS[args.pair]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            binding = ws.bind(mesh, cage, resolution=args.resolution, device="cpu")
    editor = ws.CageEditor(binding)
    pinned, axis = lower_third(editor.rest)
    editor.pin(pinned)
    top = int(np.argmax(editor.rest[:, axis]))
    server = EditorServer(editor, port=free_port())
    browser = playwright = None
    if not args.no_browser:
        from playwright.sync_api import sync_playwright

        playwright = sync_playwright().start()
        chromium = shutil.which("chromium") or shutil.which("chromium-browser")
        browser = playwright.chromium.launch(executable_path=chromium, headless=True, args=[
            "--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader"])
        page = browser.new_page(viewport={"width": 1000, "height": 700})
        page.goto(server.url)
        page.get_by_role("button", name="Move selected by offset").wait_for(timeout=60_000)
        deadline = time.monotonic() + 30
        while not server.server.get_clients() and time.monotonic() < deadline:
            time.sleep(0.1)
    clients = len(server.server.get_clients())
    step = 0.1 * editor.diagonal / args.moves  # the whole drag: 10 % of the diagonal
    rows = []
    try:
        for scheme in ("none", "laplacian", "arap"):
            editor.reset()
            editor.scheme = scheme
            server.select([top])
            follow, deform, update, total = [], [], [], []
            for k in range(args.moves):
                t0 = time.perf_counter()
                target = editor.rest[top] + (k + 1) * step * np.eye(3)[(axis + 1) % 3]
                editor.place([top], target[None], record=False, iterations=DRAG_ITERATIONS)
                t1 = time.perf_counter()
                editor.mesh()
                t2 = time.perf_counter()
                server.update(gizmo=False)  # deforms again, as the page's drag does: part of the update
                t3 = time.perf_counter()
                follow.append(t1 - t0)
                deform.append(t2 - t1)
                update.append(t3 - t2)
                total.append((t1 - t0) + (t3 - t2))
            ms = lambda xs: np.array(xs) * 1e3  # noqa: E731
            rows.append((scheme, f"{np.median(ms(follow)):.2f}", f"{np.median(ms(deform)):.2f}",
                         f"{np.median(ms(update)):.2f}", f"{np.median(ms(total)):.1f}",
                         f"{np.percentile(ms(total), 95):.1f}", f"{ms(total).max():.1f}"))
        drawn = None
        if browser is not None:  # the page after the drags: how much of its scene part differs from the background
            import io

            from PIL import Image

            time.sleep(3.0)  # software WebGL draws the last update
            png = page.screenshot(path=args.screenshot)
            shot = np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=np.float64)
            scene = shot[shot.shape[0] // 5: -shot.shape[0] // 5, shot.shape[1] // 5: int(shot.shape[1] * 0.6)]
            drawn = float(np.mean(np.abs(scene - np.median(scene)) > 24))
    finally:
        if browser is not None:
            browser.close()
            playwright.stop()
        server.stop()
    change, gap, iterations = arap_quality(binding, pinned, top, axis)
    cores = len(os.sched_getaffinity(0))
    print(f"device: {platform.processor() or platform.machine()}, {cores} cores; {binding.n_vertices} vertices, "
          f"{binding.n_handles} handles ({len(pinned)} pinned), {clients} page(s) connected, {args.moves} steps of "
          f"{step:.4g} (10 % of the diagonal in all)"
          + ("" if drawn is None else f"; the page's scene area {100 * drawn:.1f} % drawn (not background)"))
    print(markdown_table(("scheme", "follow ms (median)", "deform ms", "page update ms (deform + send)",
                          "edit to page ms (median)", "p95 ms", "max ms"), rows))
    print()
    print(markdown_table(("cage", "handles", "pinned", "ARAP iterations", "other edges' mean length change",
                          "distance from libigl's ARAP / diagonal"),
                         [(args.pair, binding.n_handles, len(pinned), iterations, f"{100 * change:.2f} %",
                           "igl not installed" if gap is None else f"{gap:.1e}")]))


if __name__ == "__main__":
    main()
