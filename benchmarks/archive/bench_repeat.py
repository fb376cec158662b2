"""Repeated whole binds of one pair: the median wall time of `ws.bind` (load to weights) after a warm-up.

    python benchmarks/archive/bench_repeat.py --pair ogre --resolutions 128 256 --repeats 5 --device cuda:0
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

import warp_stokes as ws

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from common import pair, select_device, warm_up  # noqa: E402


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pair", default="ogre")
    p.add_argument("--resolutions", nargs="+", type=int, default=[128, 256])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--device", default="cuda:0")
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    mesh, cage = pair(args.pair)
    _, device = select_device(args.device)
    for n in args.resolutions:
        warm_up(args.device, mesh, cage, resolution=n)
        walls = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            b = ws.bind(mesh, cage, resolution=n, device=args.device)
            walls.append(time.perf_counter() - t)
        stages = ", ".join(f"{k} {v:.3f}" for k, v in b.stats.seconds.items())
        print(f"{device} {args.pair} n={n}: whole bind median {statistics.median(walls):.3f} s "
              f"(min {min(walls):.3f}, max {max(walls):.3f}) over {args.repeats}; last: {stages}; "
              f"iters {b.stats.solver.iterations}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
