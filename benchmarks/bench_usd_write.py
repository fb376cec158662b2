"""Writing long animations as USD: seconds, file size and memory for 100 and 1,000 frames of the ogre (issue 14).

    python benchmarks/bench_usd_write.py --frames 100 1000 [--device cpu]

The ogre (26,155 vertices, 118 handles) is bound once at n = 32 (the weights' quality does not change the cost of
writing), then each case runs in a fresh process: the cage poses (the rest cage blended towards the QMVC deformed
cage, no two frames alike) are deformed on the device in chunks of 64 frames and written as

- ``standalone``: a new ``.usdc`` stage, points and extents per frame;
- ``standalone+normals``: the same with vertex normals recomputed per frame;
- ``layer``: a layer over a USD asset holding the ogre (with authored vertex normals) and its cage as prims:
  only overrides of points, extent and normals per frame.

Memory is the growth of the process's maximum resident set size over the write (``ru_maxrss``): binary layers are
saved and reloaded after each chunk of frames, so it stays bounded by a chunk, not by the animation.
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
from common import OGRE, PAIRS, HostPeak, markdown_table  # noqa: E402

CASES = ("standalone", "standalone+normals", "layer")


def _asset(folder: Path) -> Path:
    """The ogre and its cage as prims of a USD asset, with vertex normals on the ogre."""
    import numpy as np
    import trimesh
    from pxr import Usd, UsdGeom, Vt

    import warp_stokes as ws

    path = folder / "ogre.usdc"
    if path.exists():
        return path
    mesh, cage = (ws.load_surface(f) for f in PAIRS["ogre"])
    stage = Usd.Stage.CreateNew(str(path))
    root = UsdGeom.Xform.Define(stage, "/Ogre")
    stage.SetDefaultPrim(root.GetPrim())
    for prim, surface in (("/Ogre/Body", mesh), ("/Ogre/Cage", cage)):
        m = UsdGeom.Mesh.Define(stage, prim)
        m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(surface.vertices.astype(np.float32)))
        m.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(surface.faces)))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(surface.faces.astype(np.int32).ravel()))
    normals = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals
    body = UsdGeom.Mesh(stage.GetPrimAtPath("/Ogre/Body"))
    body.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(normals.astype(np.float32)))
    body.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    stage.GetRootLayer().Save()
    return path


def _bindings(folder: Path, device: str | None) -> dict:
    import warp_stokes as ws

    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, args in (("mesh", (*PAIRS["ogre"], {})),
                           ("asset", (_asset(folder), None, {"cage_prim": "/Ogre/Cage"}))):
            path = folder / f"{name}.npz"
            if not path.exists():
                ws.bind(args[0], args[1], resolution=32, device=device, **args[2]).save(path)
            out[name] = path
    return out


def run_case(case: str, frames: int, folder: Path, device: str | None) -> dict:
    import numpy as np

    import warp_stokes as ws

    bindings = _bindings(folder, device)
    binding = ws.load_binding(bindings["asset" if case == "layer" else "mesh"], device=device)
    rest = binding.cage_vertices
    target = ws.load_surface(OGRE / "cage_deformed_tri.obj").vertices
    blend = np.linspace(0.0, 1.0, frames) ** 1.5  # no two frames alike (crate files store equal arrays once)
    poses = ws.Poses(rest + blend[:, None, None] * (target - rest), np.arange(1.0, frames + 1), "sine")
    normals = binding.mesh_normals
    if case == "standalone+normals":
        import trimesh

        normals = trimesh.Trimesh(binding.mesh_vertices, binding.mesh_faces, process=False).vertex_normals
    binding.deform(poses.positions[:1])  # device arrays and kernels ready
    out = folder / f"{case}_{frames}.usdc"
    with HostPeak() as memory:
        start = time.perf_counter()
        ws.write_animation(out, binding, poses, fps=24, normals=normals if case == "standalone+normals" else None)
        seconds = time.perf_counter() - start
    return {"case": case, "frames": frames, "vertices": binding.n_vertices, "seconds": seconds,
            "frames_per_second": frames / seconds, "file_mib": os.path.getsize(out) / 2**20,
            "memory_growth_mib": memory.bytes / 2**20, "device": str(binding.device)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    parser.add_argument("--device", default=None)
    parser.add_argument("--folder", default=None, help="work folder (default: a temporary one)")
    parser.add_argument("--one", nargs=2, metavar=("CASE", "FRAMES"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    folder = Path(args.folder or tempfile.mkdtemp(prefix="bench_usd_"))
    if args.one:
        print(json.dumps(run_case(args.one[0], int(args.one[1]), folder, args.device)))
        return
    _bindings(folder, args.device)
    rows = []
    for case in args.cases:
        for frames in args.frames:
            command = [sys.executable, __file__, "--one", case, str(frames), "--folder", str(folder)]
            if args.device:
                command += ["--device", args.device]
            result = subprocess.run(command, capture_output=True, text=True, check=True)
            rows.append(json.loads(result.stdout.strip().splitlines()[-1]))
            print(rows[-1], file=sys.stderr)
    print(f"device: {rows[0]['device']}; {rows[0]['vertices']} vertices")
    print(markdown_table(("case", "frames", "seconds", "frames/s", "file MiB", "memory growth MiB"), [
        (r["case"], r["frames"], f"{r['seconds']:.2f}", f"{r['frames_per_second']:.0f}", f"{r['file_mib']:.0f}",
         f"{r['memory_growth_mib']:.0f}") for r in rows]))


if __name__ == "__main__":
    main()
