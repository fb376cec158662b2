"""Multigrid smoothing against CG iterations on one chunk of handles, at large n (issue 20: 28 iterations on the
icosphere pair at n = 512, against 11 at n = 224).

    python benchmarks/bench_smoother.py --pair sphere --resolution 512 --handles 6 --variants 3,3/12/1.1 3,8/40/1.2 3,3,8/40/1.2

One grid, one hierarchy, one chunk's field (the first ``--handles`` handles and the complement column) solved once
per variant ``DEGREES/POWER/SAFETY``: the Chebyshev degrees from the fine level down (the last for every deeper
level, e.g. ``3,8``: 3 on the fine level, 8 on the coarse ones), the power iterations that estimate each level's lmax and the factor above the estimate. Prints the levels,
and per variant the CG iterations, the solve's seconds and seconds per iteration, and the identity error.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import WORK, pair_files, select_device, table_head, table_row  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pair", default="sphere")
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--handles", type=int, default=6)
    p.add_argument("--variants", nargs="+", default=["3,3/12/1.1", "3,8/40/1.2"])
    p.add_argument("--coarsest", type=int, default=None, help="coarsest level's node limit")
    p.add_argument("--first", type=int, nargs="+", default=[0], help="first handle of each chunk solved (0)")
    p.add_argument("--device", default=None)
    p.add_argument("--folder", default=str(WORK))
    args = p.parse_args(argv)

    import warp as wp

    import warp_stokes as ws
    from warp_stokes.solver import multigrid

    _, cage_file = pair_files(args.pair, Path(args.folder))
    cage = ws.check_cage(cage_file)
    device, device_name = select_device(args.device)
    start = time.perf_counter()
    grid = ws.voxelize(cage, args.resolution, device=device)
    voxelize = time.perf_counter() - start
    start = time.perf_counter()
    mg = multigrid.Multigrid(grid, device, **({"coarsest_nodes": args.coarsest} if args.coarsest else {}))
    setup = time.perf_counter() - start
    print(f"device {device_name}, {args.pair} n = {args.resolution}: levels {mg.level_sizes}, "
          f"voxelize {voxelize:.1f} s, multigrid setup {setup:.1f} s", flush=True)
    rows = []
    runs = [(v, f) for v in args.variants for f in args.first]
    for variant, first in runs:
        chunk = slice(first, min(first + args.handles, cage.n_handles))
        degrees, power, safety = variant.split("/")
        # the variant's degrees whatever the hierarchy's depth
        multigrid.SMOOTHER_DEGREES = multigrid.DEEP_SMOOTHER_DEGREES = tuple(int(d) for d in degrees.split(","))
        if (int(power), float(safety)) != (multigrid.POWER_ITERATIONS, multigrid.LMAX_SAFETY):
            multigrid.POWER_ITERATIONS, multigrid.LMAX_SAFETY = int(power), float(safety)
            with wp.ScopedDevice(device):
                mg._estimate_eigenvalues()
        field = ws.boundary_field(grid, cage, device=device, handles=chunk, complement=True, data="local")
        wp.synchronize_device(device)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            report = ws.solve_biharmonic(grid, field, handles=cage.vertices, chunk=chunk, preconditioner=mg,
                                         device=device)
        label = f"{variant} handles {chunk.start}-{chunk.stop - 1}"
        rows.append((label, report.iterations, report.seconds, report.identity_error, report.converged,
                     [[r[0], f"{r[1]:.1e}"] for r in report.rounds]))
        print(rows[-1], flush=True)
        del field
    print("\n" + table_head(("degrees (fine, coarse...), power its, safety; chunk", "iterations",
                             "solve s", "s / iteration", "identity error", "converged",
                             "rounds (iterations, true residual)")))
    for variant, its, seconds, identity, converged, rounds in rows:
        print(table_row((variant, its, f"{seconds:.2f}", f"{seconds / its:.3f}", f"{identity:.1e}", converged, rounds)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
