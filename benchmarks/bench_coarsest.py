"""The coarsest multigrid level's size limit against a bind's time, iterations, peak memory and weights.

    python benchmarks/bench_coarsest.py --pairs arm ogre --limits 400 100 --resolutions 16 24 32 48 64 --device cpu

Each (pair, limit) in a fresh process, the resolutions coarsest first, each bind on one thread, its peak measured as
``sweep`` measures it (on a CPU: the process's peak resident set above its size at the bind's start, freed heap handed back
first). Prints a Markdown table: levels' sizes, seconds (total, setup, solve), CG iterations, peak and estimated
memory, and the largest weight difference against the first limit's weights at the same resolution.
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
from common import pair_files, table_head, table_row  # noqa: E402


def _one(pair: str, limit: int, resolutions: list[int], device: str, folder: str) -> list[dict]:
    """In this process: bind ``pair`` at each resolution with the coarsest limit ``limit``; rows, weights saved."""
    import numpy as np
    import warp as wp

    import warp_stokes as ws
    from warp_stokes.binding import columns
    from warp_stokes.solver import hierarchy
    from warp_stokes.sweep import _PeakMemory

    coarsen = hierarchy.coarsen
    columns.coarsen = lambda grid, device=None, coarsest_nodes=None: coarsen(grid, device, coarsest_nodes=limit)
    mesh, cage = pair_files(pair)
    warnings.simplefilter("ignore")
    ws.bind(mesh, cage, resolution=16, device=device, threads=1)  # kernels loaded, BLAS started
    rows = []
    for n in resolutions:
        peak = _PeakMemory(wp.get_device(device))
        start = time.perf_counter()
        b = ws.bind(mesh, cage, resolution=n, device=device, threads=1)
        seconds = time.perf_counter() - start
        np.save(os.path.join(folder, f"{pair}_{limit}_{n}.npy"), b.weights)
        s = b.stats
        rows.append(dict(pair=pair, limit=limit, n=n, levels=s.solver.levels, seconds=seconds,
                         setup=s.seconds["setup"], solve=s.seconds["solve"], iterations=s.solver.iterations,
                         peak=peak.bytes(), estimate=s.memory_estimate_bytes))
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pairs", nargs="+", default=["arm"])
    p.add_argument("--limits", type=int, nargs="+", default=[400, 100])
    p.add_argument("--resolutions", type=int, nargs="+", default=[16, 24, 32, 48, 64])
    p.add_argument("--device", default="cpu")
    p.add_argument("--child", nargs=2, help=argparse.SUPPRESS)  # PAIR LIMIT: one process's share
    p.add_argument("--folder", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    resolutions = sorted(args.resolutions)
    if args.child:
        rows = _one(args.child[0], int(args.child[1]), resolutions, args.device, args.folder)
        print(json.dumps(rows))
        return 0

    import numpy as np

    print(table_head(["pair", "limit", "n", "levels", "seconds", "setup s", "solve s", "iterations", "peak MiB",
                      "estimate MiB", "max |w - w(first limit)|"]))
    with tempfile.TemporaryDirectory() as folder:
        for pair in args.pairs:
            for limit in args.limits:
                proc = subprocess.run([sys.executable, __file__, "--child", pair, str(limit), "--folder", folder,
                                       "--device", args.device, "--resolutions", *map(str, resolutions)],
                                      capture_output=True, text=True, check=True)
                for row in json.loads(proc.stdout.strip().splitlines()[-1]):
                    first = np.load(os.path.join(folder, f"{pair}_{args.limits[0]}_{row['n']}.npy"))
                    mine = np.load(os.path.join(folder, f"{pair}_{limit}_{row['n']}.npy"))
                    print(table_row([pair, limit, row["n"], row["levels"], f"{row['seconds']:.2f}",
                                     f"{row['setup']:.2f}", f"{row['solve']:.2f}", row["iterations"],
                                     f"{row['peak'] / 2**20:.1f}", f"{row['estimate'] / 2**20:.1f}",
                                     f"{np.abs(mine - first).max():.1e}"]), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
