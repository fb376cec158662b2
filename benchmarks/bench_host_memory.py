"""Peak memory of a bind on the CPU against the planner's estimate, from small to large meshes (issue 13).

    python benchmarks/bench_host_memory.py --meshes arm ogre ogre:1 ogre:2 --resolution 48

Each bind runs in a fresh process after a warm-up bind of the arm (kernels loaded); the peak is the growth of the
process's maximum resident set size (``ru_maxrss``) over the bind, the estimate is ``stats.memory_estimate_bytes``
(which on the CPU counts the host arrays: the grid's, the mesh's and all the weights). ``ogre:K`` is the ogre
subdivided K times (each about 4x the vertices), inside the ogre's cage.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import WORK, HostPeak, markdown_table, pair_files, warm_up  # noqa: E402


def mesh_files(name: str, folder: Path) -> tuple[Path, Path]:
    base, _, times = name.partition(":")
    if base not in ("arm", "ogre") or (times and base != "ogre"):
        raise SystemExit(f"unknown mesh {name!r}: arm, ogre or ogre:K")
    mesh, cage = pair_files(base, folder)
    if times:
        import trimesh

        out = folder / f"ogre_sub{times}.obj"
        if not out.exists():
            m = trimesh.load(mesh, process=False, force="mesh")
            for _ in range(int(times)):
                m = m.subdivide()
            m.export(out)
        mesh = out
    return mesh, cage


def run_case(mesh: str, cage: str, resolution: int) -> dict:
    import warnings

    import warp_stokes as ws

    # warm-up: every kernel loaded; the arm at n = 16, so that its own peak stays below the measured binds' (measure
    # at n = 48 or more: max RSS only grows past the highest peak so far; the arm at 32 reads 0)
    warm_up("cpu")
    with HostPeak() as memory, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = ws.bind(mesh, cage, resolution=resolution, device="cpu")
    return {"vertices": b.n_vertices, "handles": b.n_handles, "resolution": resolution,
            "estimate": b.stats.memory_estimate_bytes, "peak_growth": memory.bytes, "before": memory.before}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--meshes", nargs="+", default=["arm", "ogre", "ogre:1", "ogre:2"])
    p.add_argument("--resolution", type=int, default=48)
    p.add_argument("--folder", default=str(WORK))
    p.add_argument("--case", nargs=3, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.case:
        print(json.dumps(run_case(args.case[0], args.case[1], int(args.case[2]))))
        return 0
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.meshes:
        mesh, cage = mesh_files(name, folder)
        proc = subprocess.run([sys.executable, __file__, "--case", str(mesh), str(cage), str(args.resolution)],
                              capture_output=True, text=True)
        if proc.returncode:
            print(proc.stderr[-2000:], file=sys.stderr)
            return proc.returncode
        rows.append({"mesh": name, **json.loads(proc.stdout.strip().splitlines()[-1])})
        print(rows[-1], flush=True)
    print("\nDevice: cpu. Peak = growth of the process's max RSS over the bind.\n")
    print(markdown_table(("mesh", "vertices", "handles", "n", "estimate MiB", "peak MiB", "peak / estimate"), [
        (r["mesh"], f"{r['vertices']:,}", r["handles"], r["resolution"], f"{r['estimate'] / 2**20:.0f}",
         f"{r['peak_growth'] / 2**20:.0f}", f"{r['peak_growth'] / r['estimate']:.2f}") for r in rows]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
