"""A CPU bind on 1, 2, 4, ... threads: time, speed-up and parallel efficiency against one thread, and the weights
against the one-thread bind's.

    python benchmarks/bench_cpu_threads.py --pair ogre --resolutions 64 128 --threads 1 2 4 8 16
    python benchmarks/bench_cpu_threads.py --pair ogre --resolutions 64 --threads 1 --kernels
    python benchmarks/bench_cpu_threads.py --pair ogre --resolutions 128 --threads 1 4 16 --bandwidth

Threads solve chunks of handles at once (``ws.bind(..., threads=T)``); voxelising, the multigrid's setup and the
checks stay on one thread. One process: a warm-up bind at n = 16 loads the kernels, then per resolution one bind per
thread count (``--repeat`` times, the fastest kept). Peak memory is the process's peak resident set above its size
at the bind's start (Linux: reset through ``/proc/self/clear_refs``; the freed heap handed back first), beside the
memory plan's estimate. Prints a Markdown table with the CPU's model and core count.

``--bandwidth`` first measures what the memory gives the same threads: a Warp CPU kernel streaming ``c = a + s b``
over float32 arrays far larger than the caches, each of T threads launching it over its share of the rows (as the
bind's threads launch theirs). A solve that streams its vectors cannot speed up by more than that rate's ratio to one
thread's; the table shows this ceiling beside the bind's speed-up.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import pair, table_head, table_row  # noqa: E402


_TRIAD = """
const float* __restrict__ x = a.data;
const float* __restrict__ y = b.data;
float* __restrict__ z = c.data;
for (int i = first; i < stop; ++i) z[i] = x[i] + s * y[i];
"""


@wp.func_native(_TRIAD)
def _triad_rows(a: wp.array(dtype=float), b: wp.array(dtype=float), s: float, first: int, stop: int,
                c: wp.array(dtype=float)): ...


@wp.kernel
def triad(a: wp.array(dtype=float), b: wp.array(dtype=float), s: float, first: int, stop: int,
          c: wp.array(dtype=float)):
    """c = a + s b over rows [first, stop), one C++ loop (vectorised by the compiler, as the solver's CPU loops):
    the memory's streaming rate, each of the bind's threads launching over its range."""
    _triad_rows(a, b, s, first, stop, c)

def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "CPU"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pair", default="ogre")
    p.add_argument("--resolutions", type=int, nargs="+", default=[64])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--bandwidth", action="store_true",
                   help="first the memory's streaming rate on each thread count (a Warp triad kernel), and the "
                        "speed-up it allows")
    p.add_argument("--bandwidth-mib", type=int, default=512, help="each of the triad's three arrays (MiB)")
    p.add_argument("--kernels", action="store_true",
                   help="then, per resolution, one more bind on the first thread count with each launch timed: a "
                        "table of the kernels by time")
    args = p.parse_args(argv)

    import numpy as np
    import warp as wp

    import warp_stokes as ws
    from warp_stokes.sweep import _PeakMemory

    mesh, cage = pair(args.pair)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"{cpu_model()}, {cores} cores available; warp-stokes {ws.__version__}, Warp {wp.config.version}")
    warnings.simplefilter("ignore")
    ceiling = {}
    if args.bandwidth:
        rates = stream_rates(args.threads, args.bandwidth_mib)
        print(table_head(["threads", "triad GB/s", f"ratio to {args.threads[0]} thread(s)"]))
        for threads, rate in rates.items():
            ceiling[threads] = rate / rates[args.threads[0]]
            print(table_row([threads, f"{rate / 1e9:.1f}", f"{ceiling[threads]:.2f}"]), flush=True)
        print()
    ws.bind(mesh, cage, resolution=16, device="cpu", threads=1)
    print(table_head(["pair", "n", "threads", "chunks", "seconds", "voxelize s", "setup s", "boundary s", "solve s",
                      "sample s", "speed-up", "efficiency"] + (["bandwidth ratio"] if ceiling else [])
                     + ["iterations", "peak MiB", "estimate MiB", "max |w - w(1 thread)|"]), flush=True)
    cpu = wp.get_device("cpu")
    for n in args.resolutions:
        first = None
        for threads in args.threads:
            best = None
            for _ in range(args.repeat):
                peak = _PeakMemory(cpu)
                start = time.perf_counter()
                binding = ws.bind(mesh, cage, resolution=n, device="cpu", threads=threads)
                seconds = time.perf_counter() - start
                if best is None or seconds < best[0]:
                    best = (seconds, binding, peak.bytes())
            seconds, binding, peak_bytes = best
            if first is None:
                first = (seconds, binding.weights, threads)
            speedup = first[0] / seconds
            stats = binding.stats
            spent = stats.seconds
            print(table_row([args.pair, n, threads, stats.solver.chunks, f"{seconds:.2f}", f"{spent['voxelize']:.2f}",
                             f"{spent['setup']:.2f}", f"{spent['boundary']:.2f}", f"{spent['solve']:.2f}",
                             f"{spent['sample']:.2f}",
                             f"{speedup:.2f}", f"{speedup / (threads / first[2]):.0%}"]
                            + ([f"{ceiling[threads]:.2f}"] if ceiling else []) + [stats.solver.iterations,
                             f"{peak_bytes / 2**20:.0f}", f"{stats.memory_estimate_bytes / 2**20:.0f}",
                             f"{np.abs(binding.weights - first[1]).max():.1e}"]), flush=True)
    if args.kernels:
        for n in args.resolutions:
            kernel_table(mesh, cage, n, args.threads[0])
    return 0


def stream_rates(thread_counts, mib: int, repeat: int = 5) -> dict:
    """{threads: bytes a second} of ``c = a + s b`` over float32 arrays of ``mib`` MiB each, the rows shared out
    between the threads (each launching the kernel over its range), the fastest of ``repeat`` passes."""
    from concurrent.futures import ThreadPoolExecutor

    import numpy as np

    n = mib * 2**20 // 4
    with wp.ScopedDevice("cpu"):
        a = wp.array(np.ones(n, dtype=np.float32))
        b = wp.array(np.ones(n, dtype=np.float32))
        c = wp.zeros(n, dtype=float)
        wp.launch(triad, dim=1, inputs=[a, b, 0.5, 0, 1], outputs=[c])  # loaded here, not by several threads at once
        rates = {}
        for threads in thread_counts:
            size = -(-n // threads)
            ranges = [(k, min(k + size, n)) for k in range(0, n, size)]
            best = None
            with ThreadPoolExecutor(max_workers=threads) as pool:
                for _ in range(repeat):
                    start = time.perf_counter()
                    list(pool.map(lambda r: wp.launch(triad, dim=1, inputs=[a, b, 0.5, r[0], r[1]], outputs=[c],
                                                      device="cpu"), ranges))
                    spent = time.perf_counter() - start
                    best = spent if best is None else min(best, spent)
            rates[threads] = 3 * 4 * n / best
    return rates


def kernel_table(mesh, cage, n: int, threads: int, rows: int = 16) -> None:
    """One bind with every ``wp.launch`` timed (a CPU launch returns when its kernel is done; launches from several
    threads are summed): the ``rows`` kernels that took longest, with their calls and time a call."""
    import collections

    import warp as wp

    import warp_stokes as ws

    spent, calls = collections.Counter(), collections.Counter()
    launch = wp.launch

    def timed(kernel, *args, **kwargs):
        start = time.perf_counter()
        result = launch(kernel, *args, **kwargs)
        spent[kernel.key] += time.perf_counter() - start
        calls[kernel.key] += 1
        return result

    wp.launch = timed
    try:
        start = time.perf_counter()
        binding = ws.bind(mesh, cage, resolution=n, device="cpu", threads=threads)
        seconds = time.perf_counter() - start
    finally:
        wp.launch = launch
    stages = ", ".join(f"{k} {v:.2f}" for k, v in binding.stats.seconds.items())
    print(f"\nn = {n}, {threads} thread(s): {seconds:.2f} s ({stages})")
    print(table_head(["kernel", "calls", "seconds", "ms a call"]))
    for key, total in spent.most_common(rows):
        print(table_row([key, calls[key], f"{total:.3f}", f"{1000 * total / calls[key]:.2f}"]), flush=True)


if __name__ == "__main__":
    sys.exit(main())
