"""Large grids: bulky cages and fine resolutions, each bind in a fresh process (issue 20).

    python benchmarks/bench_large.py --cases sphere:256 sphere:384 sphere:512 ogre:512 ogre:768 --batch

A bulky cage fills its grid far more than a character's: the icosphere pair (cage
``trimesh.creation.icosphere(subdivisions=2, radius=1)``, 162 handles, around ``icosphere(subdivisions=4,
radius=0.9)``) has 8.5 M interior nodes at n = 256, where the solver with warp.sparse operators failed with an
illegal memory access. Each case runs in its own process (a CUDA error cannot poison the next case, and the
memory pool's high-water mark is the bind's own) after a warm-up bind of the same pair at n = 32. Prints one row
per case: interior nodes, levels, chunks, iterations, seconds (bind, setup, solve), the peak of Warp's memory
pool above the level before the bind, the planner's estimate and their ratio, bytes per interior node, PU/LP.

``--batch`` also runs ``warp-stokes batch`` on a manifest whose first asset cannot be solved (the sphere at
n = 1024) and whose second can (the ogre at n = 128): the first must fail with a one-line error, the second must
bind in the same process. ``--python-path DIR`` runs the cases with another copy of the package first on the path
(e.g. an older commit, to measure what it did).
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
from common import DevicePeak, pair, select_device, sphere_pair, table_head, table_row, warm_up  # noqa: E402


def run_case(name: str, resolution: int, folder: Path) -> dict:
    """One bind in this process, after a warm-up; a dict of what it measured."""
    import numpy as np

    import warp_stokes as ws

    mesh, cage = pair(name, folder)
    device, _ = select_device(None)
    warm_up(device, mesh, cage, resolution=32)  # compile and load every kernel first
    with DevicePeak(device) as memory, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        b = ws.bind(mesh, cage, resolution=resolution, device=device)
        wall = time.perf_counter() - start
    peak = memory.bytes
    s = b.stats
    w = b.weights.astype(np.float64)
    return {
        "device": s.device, "pair": name, "n": resolution, "handles": s.handles,
        "interior": s.grid.interior_nodes, "active": s.grid.interior_nodes + s.grid.ring_nodes + s.grid.band_nodes,
        "levels": s.solver.levels, "chunks": s.solver.chunks, "iterations": s.solver.iterations, "converged": s.converged,
        "wall_s": wall, "setup_s": s.seconds["setup"], "solve_s": s.seconds["solve"],
        "boundary_s": s.seconds["boundary"], "peak_bytes": peak, "estimate_bytes": s.memory_estimate_bytes,
        "pu": s.partition_of_unity_error, "lp": s.linear_precision_error,
        "identity_error": s.solver.identity_error, "min_weight": float(w.min()),
        "chunk_iterations": s.solver.chunk_iterations, "chunk_rounds": s["chunk_rounds"],
        "multigrid_seconds": s.solver.multigrid_seconds, "voxelize_s": s.seconds["voxelize"],
    }


def run_batch(folder: Path) -> dict:
    """A batch whose first asset cannot be solved and whose second can, as a user runs it."""
    mesh, cage = sphere_pair(folder)
    ogre_mesh, ogre_cage = pair("ogre")
    manifest = folder / "batch.json"
    manifest.write_text(json.dumps({"assets": [
        {"name": "sphere_1024", "mesh": str(mesh), "cage": str(cage), "resolution": 1024},
        {"name": "ogre_128", "mesh": str(ogre_mesh), "cage": str(ogre_cage), "resolution": 128},
    ]}))
    out = folder / "batch_out"
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "warp_stokes.cli", "batch", str(manifest), "-o", str(out), "--force"],
                          capture_output=True, text=True)
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else None
    return {"returncode": proc.returncode, "seconds": time.perf_counter() - start, "summary": summary,
            "stderr_tail": proc.stderr[-2000:]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", nargs="*", default=["sphere:256", "sphere:384", "sphere:512", "ogre:512", "ogre:768"])
    p.add_argument("--batch", action="store_true", help="also run the batch with an impossible asset")
    p.add_argument("--python-path", default=None, help="put this folder first on the cases' PYTHONPATH")
    p.add_argument("--label", default="", help="a label for the rows (e.g. 'before')")
    p.add_argument("--json", default=None, help="append the rows to this JSON-lines file")
    p.add_argument("--case", default=None, help=argparse.SUPPRESS)  # internal: run one case in this process
    p.add_argument("--folder", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)

    folder = Path(args.folder or tempfile.mkdtemp(prefix="bench_large_"))
    if args.case:
        name, n = args.case.split(":")
        print("RESULT " + json.dumps(run_case(name, int(n), folder)), flush=True)
        return 0

    env = dict(os.environ)
    if args.python_path:
        env["PYTHONPATH"] = os.path.abspath(args.python_path) + os.pathsep + env.get("PYTHONPATH", "")
    rows = []
    for case in args.cases:
        start = time.perf_counter()
        proc = subprocess.run([sys.executable, __file__, "--case", case, "--folder", str(folder)],
                              capture_output=True, text=True, env=env)
        found = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
        if found:
            row = json.loads(found[-1][len("RESULT "):])
        else:
            last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
            row = {"pair": case.split(":")[0], "n": int(case.split(":")[1]), "error": last[:300]}
        row["label"], row["process_s"] = args.label, time.perf_counter() - start
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.json:
            with open(args.json, "a") as fh:
                fh.write(json.dumps(row) + "\n")

    header = ("label", "device", "pair", "n", "handles", "interior", "levels", "chunks", "its", "conv", "bind s",
              "setup s", "solve s", "peak GiB", "estimate GiB", "est/peak", "B/interior", "PU", "LP", "min w")
    print("\n" + table_head(header))
    for r in rows:
        if "error" in r:
            print(table_row((r["label"], "-", r["pair"], r["n"], f"error: {r['error']}")))
            continue
        peak = r["peak_bytes"]
        print(table_row((
            r["label"], r["device"], r["pair"], r["n"], r["handles"], f"{r['interior']:,}", len(r["levels"]),
            r["chunks"], r["iterations"], r["converged"], f"{r['wall_s']:.2f}", f"{r['setup_s']:.2f}",
            f"{r['solve_s']:.2f}", f"{peak / 2**30:.2f}", f"{r['estimate_bytes'] / 2**30:.2f}",
            f"{r['estimate_bytes'] / peak:.2f}", f"{peak / r['interior']:.0f}", f"{r['pu']:.1e}", f"{r['lp']:.1e}",
            f"{r['min_weight']:.3f}")))
    if args.batch:
        result = run_batch(folder)
        print("\nbatch (sphere n = 1024, then ogre n = 128): exit code", result["returncode"],
              f"in {result['seconds']:.1f} s")
        for asset in (result["summary"] or {}).get("assets", []):
            print(f"  {asset.get('name')}: {asset.get('status')} {asset.get('error', '')}")
        print("  stderr tail:", result["stderr_tail"].strip().splitlines()[-3:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
