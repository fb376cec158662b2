"""Cages of thousands of handles: where a bind's time goes, and its peak memory against the plan (issue 30, item 13).

    python benchmarks/bench_large_cages.py --spheres 17x30 29x60 49x102 --resolution 16 --device cpu

Each cage is a latitude-longitude sphere of radius 1.2 (RINGSxSECTIONS: 2 + (RINGS - 1) SECTIONS handles, slivers at
the poles) around an icosphere of radius 1 (642 vertices). Each bind runs in a fresh process after a warm-up bind of
the arm (kernels loaded). Host peak = growth of the process's maximum resident set size over the bind; the
estimate is ``stats.memory_estimate_bytes`` (on the CPU it counts the host arrays, the local data's normal
derivatives among them: 8 bytes per cage face and handle). With ``--memory-gb`` the plan must keep to that budget.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[1] / "tests"))  # the synthetic cages: tests/shapes.py
from common import WORK, HostPeak, markdown_table, warm_up  # noqa: E402


def sphere_files(rings: int, sections: int, folder: Path) -> tuple[Path, Path]:
    """The cage and mesh OBJ files of one case (written once)."""
    import trimesh

    from shapes import latitude_longitude_sphere

    cage = folder / f"sphere_{rings}x{sections}.obj"
    mesh = folder / "icosphere3.obj"
    if not cage.exists():
        trimesh.Trimesh(*latitude_longitude_sphere(rings, sections, radius=1.2), process=False).export(cage)
    if not mesh.exists():
        trimesh.creation.icosphere(subdivisions=3).export(mesh)
    return mesh, cage


def run_case(mesh: str, cage: str, resolution: int, device: str, memory_gb: float | None) -> dict:
    import warnings

    import warp as wp

    import warp_stokes as ws

    warm_up(device)
    budget = None if memory_gb is None else int(memory_gb * 2**30)
    with HostPeak() as memory, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = ws.bind(mesh, cage, resolution=resolution, device=device, memory_budget=budget)
    device_peak = None
    if wp.get_device(device).is_cuda:
        device_peak = b.stats.get("peak_memory_bytes")
    return {"handles": b.n_handles, "faces": len(b.cage_faces), "resolution": resolution, "device": device,
            "seconds": b.stats.seconds, "chunks": b.stats.solver.chunks, "iterations": b.stats.solver.iterations,
            "estimate": b.stats.memory_estimate_bytes, "host_peak": memory.bytes, "device_peak": device_peak,
            "partition_of_unity_error": b.stats.partition_of_unity_error}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--spheres", nargs="+", default=["17x30", "29x60", "49x102"], help="RINGSxSECTIONS per cage")
    p.add_argument("--resolution", type=int, default=16)
    p.add_argument("--device", default="cpu")
    p.add_argument("--memory-gb", type=float, default=None)
    p.add_argument("--folder", default=str(WORK))
    p.add_argument("--case", nargs=5, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.case:
        mesh, cage, resolution, device, memory_gb = args.case
        print(json.dumps(run_case(mesh, cage, int(resolution), device,
                                  None if memory_gb == "none" else float(memory_gb))))
        return 0
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for spec in args.spheres:
        try:
            rings, sections = (int(x) for x in spec.split("x"))
        except ValueError:
            raise SystemExit(f"--spheres: {spec!r} is not RINGSxSECTIONS, e.g. 29x60") from None
        mesh, cage = sphere_files(rings, sections, folder)
        proc = subprocess.run([sys.executable, __file__, "--case", str(mesh), str(cage), str(args.resolution),
                               args.device, "none" if args.memory_gb is None else str(args.memory_gb)],
                              capture_output=True, text=True)
        if proc.returncode:
            print(proc.stderr[-2000:], file=sys.stderr)
            return proc.returncode
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        print(rows[-1], flush=True)
    budget = "none" if args.memory_gb is None else f"{args.memory_gb:g} GiB"
    print(f"\nDevice: {args.device}; memory budget: {budget}. Host peak = growth of the process's max RSS over the "
          f"bind.\n")
    print(markdown_table(
        ("handles", "faces", "n", "voxelize s", "boundary s", "solve s", "total s", "iterations", "chunks",
         "estimate MiB", "host peak MiB", "device peak MiB", "PU error"),
        [(f"{r['handles']:,}", f"{r['faces']:,}", r["resolution"], f"{r['seconds']['voxelize']:.2f}",
          f"{r['seconds']['boundary']:.2f}", f"{r['seconds']['solve']:.2f}", f"{r['seconds']['total']:.2f}",
          r["iterations"], r["chunks"], f"{r['estimate'] / 2**20:.0f}", f"{r['host_peak'] / 2**20:.0f}",
          "-" if r["device_peak"] is None else f"{r['device_peak'] / 2**20:.0f}",
          f"{r['partition_of_unity_error']:.1e}") for r in rows]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
