"""Skins against baked points (issue 34): file size and write time of a cage animation of the ogre written as baked
points, as a UsdSkel rig and as a glTF skin, for 100 and 1,000 frames; and the skin's error by influences per
vertex on every pair with poses.

    python benchmarks/bench_skin.py [--frames 100 1000] [--resolution 128] [--device cpu]

The ogre (26,155 vertices, 118 handles) is bound once (``--resolution``), then each write runs in a fresh process:
the cage poses (the rest cage blended towards the QMVC deformed cage, no two frames alike, as
``bench_usd_write.py``) written as

- ``baked``: ``write_animation`` to a standalone ``.usdc`` stage, points and extent per frame;
- ``usdskel all`` / ``usdskel 8``: ``write_skin`` to a ``.usdc`` UsdSkel rig with all 118 / 8 influences per vertex;
- ``glb 8`` / ``glb 4``: ``write_skin`` to a binary glTF skin (non-negative weights).

Seconds include measuring the skin's error over every frame (what ``write_skin`` does before writing). Memory is
the growth of the process's maximum resident set size over the write.

Errors by K: the distance of the skin from ``Binding.deform`` over the poses (max and RMS over the rest mesh's
diagonal, ``skin_error``, float64), for the arm's 24 bend poses and the ogre's deformed cage.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ARM, OGRE, PAIRS, HostPeak, markdown_table  # noqa: E402

CASES = ("baked", "usdskel all", "usdskel 8", "glb 8", "glb 4")


def _binding_path(name: str, folder: Path, resolution: int, device: str | None) -> Path:
    import warp_stokes as ws

    path = folder / f"{name}_{resolution}.npz"
    if not path.exists():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ws.bind(*PAIRS[name], resolution=resolution, device=device).save(path)
    return path


def _ogre_poses(binding, frames: int):
    import numpy as np

    import warp_stokes as ws

    rest = binding.cage_vertices
    target = binding._check_topology(ws.load_surface(OGRE / "cage_deformed_tri.obj"))
    blend = np.linspace(0.0, 1.0, frames) ** 1.5  # no two frames alike (crate files store equal arrays once)
    return ws.Poses(rest + blend[:, None, None] * (target - rest), np.arange(1.0, frames + 1), "blend")


def run_case(case: str, frames: int, folder: Path, resolution: int, device: str | None) -> dict:
    import warp_stokes as ws

    binding = ws.load_binding(_binding_path("ogre", folder, resolution, device), device=device)
    poses = _ogre_poses(binding, frames)
    binding.deform(poses.positions[:1])  # device arrays and kernels ready
    kind, influences = (case.split() + ["all"])[:2]
    out = folder / f"{kind}_{influences}_{frames}{'.glb' if kind == 'glb' else '.usdc'}"
    error = None
    with HostPeak() as memory:
        start = time.perf_counter()
        if kind == "baked":
            ws.write_animation(out, binding, poses, fps=24)
        else:
            report = ws.write_skin(out, binding, poses, fps=24,
                                   influences=None if influences == "all" else int(influences))
            error = report.error.max
        seconds = time.perf_counter() - start
    return {"case": case, "frames": frames, "vertices": binding.n_vertices, "handles": binding.n_handles,
            "seconds": seconds, "file_mib": os.path.getsize(out) / 2**20, "memory_growth_mib": memory.bytes / 2**20,
            "max_error": error, "device": str(binding.device)}


def error_rows(folder: Path, resolution: int, device: str | None) -> list:
    import numpy as np

    import warp_stokes as ws

    rows = []
    for name in ("arm", "ogre"):
        binding = ws.load_binding(_binding_path(name, folder, resolution, device), device=device)
        if name == "arm":
            positions, what = np.load(ARM / "bend_poses.npy"), "24 bend poses"
        else:
            positions = binding._check_topology(ws.load_surface(OGRE / "cage_deformed_tri.obj"))[None]
            what = "QMVC deformed cage"
        for influences in (None, 16, 8, 4):
            for non_negative in (False, True):
                skin = ws.skin_weights(binding, influences, non_negative)
                error = ws.skin_error(binding, skin, positions)
                rows.append((name, what, "all" if influences is None else influences,
                             "yes" if non_negative else "no", f"{error.max:.2e}", f"{error.rms:.2e}"))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--device", default=None)
    parser.add_argument("--folder", default=None, help="work folder (default: a temporary one)")
    parser.add_argument("--one", nargs=2, metavar=("CASE", "FRAMES"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    folder = Path(args.folder or tempfile.mkdtemp(prefix="bench_skin_"))
    if args.one:
        print(json.dumps(run_case(args.one[0], int(args.one[1]), folder, args.resolution, args.device)))
        return
    _binding_path("ogre", folder, args.resolution, args.device)
    rows = []
    for frames in args.frames:
        for case in args.cases:
            command = [sys.executable, __file__, "--one", case, str(frames), "--folder", str(folder),
                       "--resolution", str(args.resolution)]
            if args.device:
                command += ["--device", args.device]
            result = subprocess.run(command, capture_output=True, text=True, check=True)
            rows.append(json.loads(result.stdout.strip().splitlines()[-1]))
            print(rows[-1], file=sys.stderr)
    print(f"device: {rows[0]['device']}; ogre {rows[0]['vertices']} vertices, {rows[0]['handles']} handles, "
          f"bound at n = {args.resolution}")
    print(markdown_table(("case", "frames", "file MiB", "seconds", "memory growth MiB", "skin max error"), [
        (r["case"], r["frames"], f"{r['file_mib']:.2f}", f"{r['seconds']:.2f}", f"{r['memory_growth_mib']:.0f}",
         "-" if r["max_error"] is None else f"{r['max_error']:.2e}") for r in rows]))
    print()
    print(markdown_table(("pair", "poses", "influences", "non-negative", "max / diagonal", "RMS / diagonal"),
                         error_rows(folder, args.resolution, args.device)))


if __name__ == "__main__":
    main()
