"""V-cycles replayed as CUDA graphs against plain launches (``warp_stokes.solver.multigrid.GRAPHS``): the weights
bit for bit, and the bind times, on one GPU.

    python benchmarks/bench_graphs.py --pair ogre --rounds 2

Each case is bound with graphs off and on in turn, ``--rounds`` times (binds at 128 and 256 five times a round,
the others once): the minimum and median wall time of each setting over all its binds, the solver's iterations
and chunks, and whether the two settings' weights are identical (they are the same kernels, arguments and order).
The chunked case (a memory budget that splits the handles into chunks) is where a graph is replayed most.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import PAIRS, markdown_table  # noqa: E402

CASES = {"n = 128": dict(resolution=128), "n = 256": dict(resolution=256),
         "n = 96, 60 MiB budget (chunks)": dict(resolution=96, memory_budget=60 * 2**20),
         "harmonic, n = 64": dict(resolution=64, method="harmonic"), "Jacobi, n = 32": dict(resolution=32,
                                                                                            solver="jacobi")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pair", default="ogre", choices=sorted(PAIRS))
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--device", default="cuda:0")
    args = parser.parse_args()
    import warp as wp

    import warp_stokes as ws
    import warp_stokes.solver.multigrid as multigrid

    mesh, cage = PAIRS[args.pair]
    warnings.simplefilter("ignore")
    ws.bind(mesh, cage, resolution=64, device=args.device)  # kernels loaded
    walls, weights, stats = {}, {}, {}
    for _ in range(args.rounds):
        for graphs in (False, True):
            multigrid.GRAPHS = graphs
            for name, options in CASES.items():
                for _ in range(5 if "256" in name or "128" in name else 1):
                    start = time.perf_counter()
                    b = ws.bind(mesh, cage, device=args.device, **options)
                    walls.setdefault((name, graphs), []).append(time.perf_counter() - start)
                weights[(name, graphs)], stats[name] = b.weights, b.stats.solver
    rows = []
    for name in CASES:
        plain, replayed = walls[(name, False)], walls[(name, True)]
        rows.append((name, stats[name].iterations, stats[name].chunks, f"{min(plain):.3f} / {np.median(plain):.3f}",
                     f"{min(replayed):.3f} / {np.median(replayed):.3f}",
                     f"{np.median(replayed) / np.median(plain):.2f}",
                     "yes" if np.array_equal(weights[(name, False)], weights[(name, True)]) else "NO"))
    print(f"device: {wp.get_device(args.device).name}; {args.pair}: {b.n_vertices} vertices, {b.n_handles} handles; "
          f"{args.rounds} rounds")
    print(markdown_table(("case", "iterations", "chunks", "plain launches s (min / median)",
                          "graphs s (min / median)", "median ratio", "weights identical"), rows))


if __name__ == "__main__":
    main()
