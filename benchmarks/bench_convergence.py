"""Does every bind converge? Sweeps of resolutions over the shared pairs and the synthetic cages of
``warp_stokes.geometry.shapes.stress_pairs`` (issue 29).

    python benchmarks/bench_convergence.py --device cuda --sets shared --json shared.json
    python benchmarks/bench_convergence.py --device cuda --sets synthetic --json synthetic.json
    python benchmarks/bench_convergence.py --device cuda --sets synthetic --methods harmonic --synthetic 16:97:4
    python benchmarks/bench_convergence.py --device cpu --sets shared --shared 20:33 --pairs smpl   # a CPU check

Sets: ``shared``, every mesh/cage pair of the shared data (the arm, SMPL rest and T-pose, the ogre) at the
resolutions ``--shared`` (default every one from 20 to 128, then every fourth up to 256); ``synthetic``, the 24
synthetic cages (boxes, perturbed and stretched icospheres, random star-shaped cages, thin slabs, dumbbells with thin
necks, tori; 8 to 218 handles) at ``--synthetic`` (default every resolution from 16 to 96). Every bind runs with the
package's defaults (``max_iterations`` 200). A bind fails the sweep when it does not converge, takes more than 20 CG
iterations, ends with partition of unity or linear precision above 1e-5 at the vertices, needed a recovery (the
solver's watchdog switched preconditioner), or raised. Prints one row per pair (binds, failures, iterations max and
median, worst PU / LP, the smallest coarsest-operator eigenvalue relative to the largest, seconds) and every failure;
``--json`` writes every bind's figures (written as it goes, so that a run cut short keeps what it measured).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import warp_stokes as ws

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[1] / "tests"))  # the synthetic cages: tests/shapes.py

from shapes import stress_pairs  # noqa: E402
from common import ARM, OGRE, SMPL, markdown_table, select_device, warm_up  # noqa: E402

ITERATIONS = 20
EXACT = 1e-5
SHARED = {
    "arm": (ARM / "arm.obj", ARM / "arm_cage.obj"),
    "smpl-rpose": (SMPL / "model_rpose.obj", SMPL / "cage_rpose.obj"),
    "smpl-tpose": (SMPL / "model_tpose.obj", SMPL / "cage_tpose.obj"),
    "ogre": (OGRE / "Ogre.obj", OGRE / "cage_tri.obj"),
}


def resolutions(text: str) -> list[int]:
    """'20:129,132:257:4' -> every resolution of each range (Python's start:stop:step), or single numbers."""
    out = []
    for part in text.split(","):
        bounds = [int(v) for v in part.split(":")]
        out += list(range(*bounds)) if len(bounds) > 1 else bounds
    return sorted(set(out))


def measure(mesh, cage, n: int, device, method: str) -> dict:
    """One bind's figures and what fails the sweep in it."""
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # folded edges, thin features: not what is measured here
        try:
            s = ws.bind(mesh, cage, resolution=n, device=device, method=method).stats
        except ws.ConvergenceError as exc:
            report = exc.report
            return {"iterations": report.iterations if report else None, "fault": str(exc),
                    "seconds": time.perf_counter() - start}
        except ws.ResolutionError as exc:  # refused (a grid too coarse for the cage): not a solver failure
            return {"refused": str(exc), "seconds": time.perf_counter() - start}
    row = {"iterations": s.solver.iterations, "converged": s.converged, "pu": s.partition_of_unity_error,
           "lp": s.linear_precision_error, "levels": s.solver.levels, "recoveries": s.solver.recoveries,
           "coarsest": s.solver.coarsest_operator, "seconds": time.perf_counter() - start}
    faults = []
    if not s.converged:
        faults.append("not converged")
    if s.solver.iterations > ITERATIONS:
        faults.append(f"{s.solver.iterations} iterations")
    if not (row["pu"] <= EXACT and row["lp"] <= EXACT):
        faults.append(f"PU {row['pu']:.1e} LP {row['lp']:.1e}")
    if s.solver.recoveries:
        faults.append("recovered: " + "; ".join(e["fault"] for e in s.solver.recoveries))
    if faults:
        row["fault"] = ", ".join(faults)
    return row


def summary_row(name: str, handles: int, rows: list[dict]) -> list:
    ran = [r for r in rows if "refused" not in r]
    its = [r["iterations"] for r in ran if r.get("iterations") is not None]
    failed = [r for r in ran if "fault" in r]
    smallest = [r["coarsest"]["smallest_eigenvalue"] for r in ran if r.get("coarsest")]
    worst = max([max(r["pu"], r["lp"]) for r in ran if "pu" in r] or [float("nan")])
    return [name, handles, f"{min(r['n'] for r in rows)}-{max(r['n'] for r in rows)}", len(ran),
            len(rows) - len(ran), len(failed), max(its) if its else "-", f"{np.median(its):.0f}" if its else "-",
            f"{worst:.1e}", f"{min(smallest):.1e}" if smallest else "-", f"{sum(r['seconds'] for r in rows):.1f}"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--sets", nargs="+", choices=["shared", "synthetic"], default=["shared", "synthetic"])
    parser.add_argument("--shared", type=resolutions, default=resolutions("20:129,132:257:4"))
    parser.add_argument("--synthetic", type=resolutions, default=resolutions("16:97"))
    parser.add_argument("--pairs", nargs="+", default=None, help="only pairs whose name starts with one of these")
    parser.add_argument("--methods", type=lambda text: text.split(","), default=["stokes"],
                        help="stokes, harmonic, or both as stokes,harmonic")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    unknown = set(args.methods) - {"stokes", "harmonic"}
    if unknown:
        parser.error(f"--methods: unknown {', '.join(sorted(unknown))} (stokes, harmonic)")
    device, name = select_device(args.device)
    warm_up(device)
    if "harmonic" in args.methods:
        warm_up(device, method="harmonic")
    cases = []
    if "shared" in args.sets:
        cases += [(key, mesh, cage, ws.load_surface(cage).vertices.shape[0], args.shared)
                  for key, (mesh, cage) in SHARED.items() if mesh.exists()]
    if "synthetic" in args.sets:
        cases += [(p.name, p.mesh, p.cage, len(p.cage_vertices), args.synthetic) for p in stress_pairs()]
    if args.pairs:
        cases = [c for c in cases if any(c[0].startswith(p) for p in args.pairs)]
    print(f"device: {name}; {len(cases)} pairs; methods {', '.join(args.methods)}", flush=True)
    everything, table, failures = [], [], []
    for method in args.methods:
        for key, mesh, cage, handles, grid_resolutions in cases:
            rows = []
            for n in grid_resolutions:
                row = {"pair": key, "method": method, "n": n, **measure(mesh, cage, n, device, method)}
                rows.append(row)
                if "fault" in row:
                    failures.append(row)
                    print(f"  FAIL {key} {method} n={n}: {row['fault'][:300]}", flush=True)
            everything += rows
            table.append(summary_row(f"{key} ({method})", handles, rows))
            print("  " + " | ".join(str(c) for c in table[-1]), flush=True)
            if args.json:
                Path(args.json).write_text(json.dumps({"device": name, "binds": everything}, indent=1,
                                                      default=str))
    print()
    print(markdown_table(["pair", "handles", "resolutions", "binds", "refused", "failed", "iterations max",
                          "median", "worst PU/LP", "smallest coarsest λ", "seconds"], table))
    total = sum(1 for r in everything if "refused" not in r)
    print(f"\n{len(failures)} of {total} binds failed on {name}")
    for row in failures:
        print(f"- {row['pair']} ({row['method']}) n = {row['n']}: {row['fault'][:300]}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
