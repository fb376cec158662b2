"""Whole-bind benchmark: real mesh/cage pairs at several resolutions, on every device asked for.

    python benchmarks/bench_bind.py --devices cpu cuda:0 --resolutions 32 64 --pairs arm smpl ogre

Prints one table row per (device, pair, resolution): grid, handles, interior nodes, seconds per stage (after a
warm-up bind that compiles the kernels), CG iterations, final residual, partition-of-unity and
linear-precision errors at the vertices, and peak GPU memory (Warp's memory pool). Also checks that CPU and CUDA
weights agree when both devices are listed.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import warp_stokes as ws

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import PAIRS, DevicePeak, markdown_table, warm_up  # noqa: E402


def run(pair, resolution, device):
    mesh, cage = PAIRS[pair]
    with DevicePeak(device) as memory, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        b = ws.bind(mesh, cage, resolution=resolution, device=device)
        wall = time.perf_counter() - t
    return b, wall, memory.bytes / 2**20


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--devices", nargs="+", default=["cpu"])
    p.add_argument("--resolutions", nargs="+", type=int, default=[32, 64])
    p.add_argument("--pairs", nargs="+", default=list(PAIRS))
    args = p.parse_args(argv)

    header = ("device", "pair", "n", "grid", "handles", "interior", "iters", "residual", "PoU err", "lin err",
              "voxel s", "bdry s", "solve s", "sample s", "total s", "wall s", "peak MiB")
    rows, weights = [], {}
    for device in args.devices:
        warm_up(device)  # compile and load every kernel on this device
        for pair in args.pairs:
            for n in args.resolutions:
                b, wall, peak = run(pair, n, device)
                s = b.stats
                sec = s.seconds
                weights[(device, pair, n)] = b.weights
                rows.append((s.device, pair, n, "x".join(map(str, s.grid.shape)), s.handles,
                             s.grid.interior_nodes, s.solver.iterations, f"{s.solver.residual:.1e}",
                             f"{s.partition_of_unity_error:.1e}", f"{s.linear_precision_error:.1e}",
                             f"{sec['voxelize']:.3f}", f"{sec['boundary']:.3f}", f"{sec['solve']:.3f}",
                             f"{sec['sample']:.3f}", f"{sec['total']:.3f}", f"{wall:.3f}",
                             f"{peak:.0f}" if peak == peak else "-"))
                print(" | ".join(map(str, rows[-1])), flush=True)
    print()
    print(markdown_table(header, rows))
    if len(args.devices) > 1:
        print()
        a = args.devices[0]
        for other in args.devices[1:]:
            for pair in args.pairs:
                for n in args.resolutions:
                    d = np.abs(weights[(a, pair, n)] - weights[(other, pair, n)]).max()
                    print(f"max |w({a}) - w({other})| {pair} n={n}: {d:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
