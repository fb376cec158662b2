"""One bind spread over the GPUs of a host (issue 15's target: the ogre at n = 512 on 2 GPUs in at most 0.6x the time
on one): the wall time of a bind on one device against the same bind spread with ``device="cuda:all"`` (one Ray task
per GPU, each a share of the handles), the spread's phases, and the largest weight difference.

    python benchmarks/bench_spread.py --resolutions 256 512            # on a host with several GPUs
    python benchmarks/bench_spread.py --resolutions 128 --shares 2     # one GPU: two shares on it at once (a check)
    python benchmarks/bench_spread.py --device cpu --pair arm --resolutions 24 --shares 2   # the CPU path

``--shares K`` runs K shares per GPU (Ray's fractional GPUs; on the CPU, K worker processes) instead of one per GPU:
a functional check on a one-GPU machine, not a speed-up. Needs the ray extra. Run from a process connected to a Ray
cluster (``main(argv)`` after ``ray.init(address=...)``), it runs on that cluster and leaves it running; otherwise it
starts a local one.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import PAIRS, GpuBusy, busy_text, markdown_table, select_device, warm_up  # noqa: E402


def spread_bind(mesh, cage, resolution, on_cpu: bool, shares_per_device: int, devices: int):
    """A bind whose solves run as Ray tasks: ``devices`` x ``shares_per_device`` shares (the library's own spread,
    with fractional GPUs where there are more shares than GPUs)."""
    import ray

    import warp_stokes as ws
    from warp_stokes.binding import spread

    count = devices * shares_per_device
    if shares_per_device == 1 and not on_cpu:
        return ws.bind(mesh, cage, resolution=resolution, device=spread.ALL_GPUS)
    # K shares per device: the spread's own task with a share of a GPU each (a check, not a speed-up)
    original = spread.spread_columns

    def shared(checked, points, res, names, plan):
        task = ray.remote(spread._solve_share).options(num_cpus=0 if not on_cpu else 1,
                                                       num_gpus=0 if on_cpu else 1.0 / shares_per_device)
        parts = np.array_split(np.arange(checked.n_handles), count)
        start = time.perf_counter()
        threads = max(1, plan.backend.threads // count) if on_cpu else None
        refs = [task.remote(checked, points, res, slice(int(s[0]), int(s[-1]) + 1), "cpu" if on_cpu else "cuda:0",
                            threads, plan) for s in parts]
        return spread._gathered(ray.get(refs), time.perf_counter() - start)

    spread.spread_columns = shared
    try:
        return ws.bind(mesh, cage, resolution=resolution, device=["cpu"] * count if on_cpu else "cuda:0,cuda:1")
    finally:
        spread.spread_columns = original


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default=None, help="cpu, or the one-device run's CUDA device (default cuda:0)")
    p.add_argument("--pair", default="ogre", choices=list(PAIRS))
    p.add_argument("--resolutions", nargs="+", type=int, default=[256, 512])
    p.add_argument("--shares", type=int, default=1, help="shares per device (1: one per GPU)")
    args = p.parse_args(argv)
    import ray

    import warp_stokes as ws

    resolved, name = select_device(args.device)
    on_cpu = resolved.is_cpu
    mesh, cage = PAIRS[args.pair]
    warm_up(resolved.alias)
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=max(2, args.shares) if on_cpu else None, num_gpus=0 if on_cpu else None,
                 include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    gpus = int(ray.cluster_resources().get("GPU", 0))
    devices = 1 if on_cpu else gpus
    print(f"device: {name}; Ray cluster: {gpus} GPU(s); {devices} device(s) x {args.shares} share(s)")
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spread_bind(mesh, cage, args.resolutions[0], on_cpu, args.shares, devices)  # workers start, compile
        for n in args.resolutions:
            t = time.perf_counter()
            one = ws.bind(mesh, cage, resolution=n, device=resolved.alias)
            single = time.perf_counter() - t
            with GpuBusy(period_ms=50) as busy:
                t = time.perf_counter()
                many = spread_bind(mesh, cage, n, on_cpu, args.shares, devices)
                wall = time.perf_counter() - t
            s = many.stats.seconds
            rows.append((n, one.stats.handles, f"{one.stats.grid.interior_nodes:,}", f"{single:.2f}",
                         len(many.stats.solver.devices), f"{wall:.2f}", f"{wall / single:.2f}",
                         f"{s['voxelize'] + s['setup']:.2f}", f"{s['solve']:.2f}", f"{s['spread']:.2f}",
                         many.stats.solver.iterations, f"{np.abs(many.weights - one.weights).max():.1e}",
                         busy_text(busy.fraction())))
    if started:
        ray.shutdown()
    print()
    print(markdown_table(["n", "handles", "interior nodes", "one device s", "shares", "spread s", "ratio",
                          "slowest share: voxelize + setup s", "solve s", "Ray and transfers s", "its",
                          "max |w_spread - w_one|", "GPU busy %"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
