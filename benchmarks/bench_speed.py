"""End-to-end speed of a bind, as issue 16 tracks it: where the time of a warm bind goes, how busy the GPU is, how far
the fine-level sweeps are from the copy bandwidth, throughput of mixed assets, and a fresh process's start.

    python benchmarks/bench_speed.py --device cuda:0                        # the ogre at 128 / 256 / 512, all tables
    python benchmarks/bench_speed.py --device cuda:0 --resolutions 128 --skip-fresh --assets 6
    python benchmarks/bench_speed.py --device cpu --pair arm --resolutions 24 --assets 3   # the CPU path
    python benchmarks/bench_speed.py --device cuda:0 --resolutions 256 --kernels 256   # and each solver kernel alone

Tables (markdown): (1) per resolution: median wall of ``ws.bind`` over ``--repeats`` warm binds, its phases
(``stats.seconds``), the GPU's busy time in one bind (``wp.timing``: kernels, copies, memsets), the ten kernels that
take longest, CG iterations, peak pool memory; the bandwidth limit: the bytes the fine-level stencil launches must
move (one read of the input and one write of the output per launch, every handle column) over the measured
device-to-device copy bandwidth; (2) throughput: mixed assets (the arm, SMPL, the ogre, round robin) bound one after
another in one process, assets per minute; (3) fresh processes: ``warp-stokes --help`` and ``warp-stokes bind`` at the
first resolution, with Warp's kernel cache warm (and, with ``--cold``, an empty cache: the first run on a machine).
"""

from __future__ import annotations

import argparse
import collections
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import warp as wp

import warp_stokes as ws

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import PAIRS, DevicePeak, markdown_table, select_device, time_kernel, warm_up  # noqa: E402

#: kernels of the fine-level stencil: one application of the compact operator (or the Laplace one) per launch, and
#: the smoother's one-pass residual (which also reads the right-hand side: three streams instead of two)
FINE_STENCIL = ("apply_compact_patches", "apply_operator", "apply_laplacian")
FINE_RESIDUAL = ("residual_operator",)


def copy_bandwidth(device, gib: float = 1.0) -> float:
    """Device-to-device copy bandwidth in bytes per second (read + write counted), median of 5."""
    n = int(gib * 2**30) // 4
    a = wp.zeros(n, dtype=wp.float32, device=device)
    b = wp.empty_like(a)
    times = []
    for _ in range(6):
        wp.synchronize_device(device)
        t = time.perf_counter()
        wp.copy(b, a)
        wp.synchronize_device(device)
        times.append(time.perf_counter() - t)
    return 2 * a.capacity / statistics.median(times[1:])


def bind_once(mesh, cage, resolution, device):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        b = ws.bind(mesh, cage, resolution=resolution, device=device)
        return b, time.perf_counter() - t


def profile(mesh, cage, resolution, device, repeats, bandwidth):
    walls, binding = [], None
    for _ in range(repeats):
        binding, wall = bind_once(mesh, cage, resolution, device)
        walls.append(wall)
    row = {"n": resolution, "wall": statistics.median(walls), "phases": binding.stats.seconds,
           "iterations": binding.stats.solver.iterations, "interior": binding.stats.grid.interior_nodes,
           "handles": binding.stats.handles, "chunks": binding.stats.solver.chunks}
    if not ws.resolve_device(device).is_cuda:
        return row, []
    with DevicePeak(device) as peak:
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
        bind_once(mesh, cage, resolution, device)
        activities = wp.timing_end()
    by_name = collections.defaultdict(lambda: [0.0, 0])
    for a in activities:
        by_name[a.name][0] += a.elapsed / 1e3
        by_name[a.name][1] += 1
    busy = sum(v[0] for v in by_name.values())
    columns = row["handles"] + (row["chunks"] > 1) * row["chunks"]  # a chunked solve adds one column per chunk
    applications = sum(v[1] for k, v in by_name.items() if any(s in k for s in FINE_STENCIL))
    residuals = sum(v[1] for k, v in by_name.items() if any(s in k for s in FINE_RESIDUAL))
    fine_launches = applications + residuals
    # each launch reads the whole input once and writes the output once (vec4 float32 per node and column), a residual
    # also reads the right-hand side; a chunked solve's launches each cover a share of the columns, so the total is per
    # column, not per launch
    streams = 2 * applications + 3 * residuals
    fine_bytes = streams / max(row["chunks"], 1) * row["interior"] * columns * 16
    row.update(busy=busy, peak=peak.bytes / 2**20, fine_launches=fine_launches,
               limit=fine_bytes / bandwidth if bandwidth else float("nan"))
    top = sorted(by_name.items(), key=lambda kv: -kv[1][0])[:10]
    return row, top


def kernel_limits(mesh, cage, resolution, device, bandwidth, columns):
    """Each kernel of the solver's V-cycle and CG step timed alone on the pair's multigrid (the fine level and the
    first two coarse ones, ``columns`` handles), beside the bytes it must move at least (each vector it reads or
    writes once; coarse blocks and the nodes' coordinates once, not per handle) over the copy bandwidth: how far each
    kernel is from its own limit. Rows: (kernel, level, nodes, ms, GB, limit ms, limit / time)."""
    from warp_stokes.kernels import cg as cg_kernels
    from warp_stokes.kernels import multigrid as mg_kernels
    from warp_stokes.device import Backend
    from warp_stokes.solver.operator import apply_operator, chebyshev_step

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        checked = ws.check_cage(cage)
        grid = ws.voxelize(checked, resolution, device=device)
        mg = ws.Multigrid(grid, device=device)
    rows = []
    vec = 16 * columns  # bytes of one vector entry per node, all columns

    def record(name, depth, n, launch, nbytes):
        seconds = time_kernel(device, launch, repeats=5)
        limit = nbytes / bandwidth
        rows.append((name, depth, f"{n:,}", f"{1e3 * seconds:.2f}", f"{nbytes / 1e9:.2f}", f"{1e3 * limit:.2f}",
                     f"{limit / seconds:.0%}"))

    with wp.ScopedDevice(device):
        for depth in range(min(3, len(mg.levels) - 1)):
            lev, coarse = mg.levels[depth], mg.levels[depth + 1]
            n = lev.n
            b, x, r, d, spare = (wp.ones((n, columns), dtype=wp.vec4f) for _ in range(5))
            structure = 0 if depth == 0 else n * (27 * 64 + 27 * 4 + 64)  # blocks, neighbour rows, inverse diagonal
            if depth == 0:
                record("stencil A x", 0, n, lambda: apply_operator(grid, x, r, n_rows=n, device=device, precise=False),
                       2 * n * vec)
                record("residual b - A x", 0, n, lambda: mg._residual(0, b, x, r), 3 * n * vec)
                record("Chebyshev step, one pass", 0, n,
                       lambda: chebyshev_step(grid, x, b, d, 0.5, 0.5, spare, n_rows=n, device=device), 5 * n * vec)
            else:
                record("block stencil residual", depth, n, lambda: mg._residual(depth, b, x, r),
                       3 * n * vec + structure)
                record("block Chebyshev step, one pass", depth, n,
                       lambda: mg._chebyshev_step(depth, b, x, d, 0.5, 0.5, spare), 5 * n * vec + structure)
            record("Chebyshev step (pointwise)", depth, n,
                   lambda: wp.launch(mg_kernels.chebyshev_step, dim=x.shape, inputs=[r, lev.inv_diag, 0.5, 0.5],
                                     outputs=[x, d]), 5 * n * vec)
            coarse_b = wp.zeros((coarse.n, columns), dtype=wp.vec4f)
            record("restriction", depth, n,
                   lambda: wp.launch(mg_kernels.restrict, dim=coarse_b.shape,
                                     inputs=[mg.table32, coarse.ijk_device, lev.index, lev.n,
                                             wp.vec3i(*coarse.shift), r], outputs=[coarse_b]),
                   n * vec + coarse.n * vec)
            record("prolongation (add)", depth, n,
                   lambda: wp.launch(mg_kernels.prolong_add, dim=x.shape,
                                     inputs=[mg.table32, lev.ijk_device, coarse.index, wp.vec3i(*coarse.shift),
                                             coarse_b], outputs=[x]),
                   2 * n * vec + coarse.n * vec)
            if depth == 0:
                out = wp.zeros(columns, dtype=wp.float64)
                threads = Backend.of(device).reduction_threads(n, columns)
                record("CG dot products", 0, n,
                       lambda: wp.launch(cg_kernels.column_dots, dim=(threads, columns), inputs=[x, r, threads],
                                         outputs=[out]), 2 * n * vec)
            del b, x, r, d, spare
    return rows


def throughput(device, resolution, count):
    names = [n for n in ("arm", "smpl", "ogre") if Path(PAIRS[n][0]).exists()]
    t = time.perf_counter()
    for k in range(count):
        mesh, cage = PAIRS[names[k % len(names)]]
        bind_once(mesh, cage, resolution, device)
    seconds = time.perf_counter() - t
    return names, seconds, 60.0 * count / seconds


def fresh(args, device, cold: bool):
    mesh, cage = PAIRS[args.pair]
    env = dict(os.environ)
    # as installed: Python's bytecode of warp and the package compiled once (pip does it), not every start (an
    # environment that sets PYTHONDONTWRITEBYTECODE, as the lent GPU machines do, added 1.1 s to each fresh bind)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    subprocess.run([sys.executable, "-m", "compileall", "-q", os.path.dirname(wp.__file__),
                    os.path.dirname(ws.__file__)], capture_output=True, env=env)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        if cold:
            env["WARP_CACHE_PATH"] = os.path.join(tmp, "kernels")
        for label, command in (("warp-stokes --help", [sys.executable, "-m", "warp_stokes.cli", "--help"]),
                               (f"warp-stokes bind {args.pair} n = {args.resolutions[0]}",
                                [sys.executable, "-m", "warp_stokes.cli", "bind", str(mesh), str(cage), "-o",
                                 os.path.join(tmp, "b.npz"), "--resolution", str(args.resolutions[0]), "--device",
                                 device])):
            t = time.perf_counter()
            proc = subprocess.run(command, capture_output=True, text=True, env=env)
            seconds = time.perf_counter() - t
            said = "compiling the kernels" in proc.stderr
            rows.append((label, "empty (first run)" if cold else "warm", f"{seconds:.2f}", proc.returncode,
                         "yes" if said else "no"))
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default=None)
    p.add_argument("--pair", default="ogre", choices=list(PAIRS))
    p.add_argument("--resolutions", nargs="+", type=int, default=[128, 256, 512])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--assets", type=int, default=12, help="binds in the throughput run (0: skip it)")
    p.add_argument("--skip-fresh", action="store_true", help="no fresh-process timings")
    p.add_argument("--cold", action="store_true", help="also time a fresh process with an empty kernel cache")
    p.add_argument("--kernels", type=int, default=None, metavar="N",
                   help="time each solver kernel alone at resolution N against its bandwidth limit (CUDA only)")
    args = p.parse_args(argv)
    resolved, name = select_device(args.device)
    device = resolved.alias
    mesh, cage = PAIRS[args.pair]
    warm_up(device)
    bind_once(mesh, cage, args.resolutions[0], device)  # the pair's own first bind (loading, caches)
    bandwidth = copy_bandwidth(device) if resolved.is_cuda else 0.0
    print(f"device: {name}" + (f"; copy bandwidth {bandwidth / 1e9:.0f} GB/s (read + write)" if bandwidth else ""))

    rows, tops = [], {}
    for n in args.resolutions:
        row, top = profile(mesh, cage, n, device, args.repeats, bandwidth)
        rows.append(row)
        tops[n] = top
    phases = sorted({k for r in rows for k in r["phases"] if k != "total"})
    head = ["n", "handles", "interior nodes", "wall s (median)", *[f"{k} s" for k in phases], "its"]
    if resolved.is_cuda:
        head += ["GPU busy s", "fine stencil launches", "bandwidth limit s", "limit / busy", "peak MiB"]
    table = []
    for r in rows:
        line = [r["n"], r["handles"], f"{r['interior']:,}", f"{r['wall']:.3f}",
                *[f"{r['phases'].get(k, 0.0):.3f}" for k in phases], r["iterations"]]
        if resolved.is_cuda:
            line += [f"{r['busy']:.3f}", r["fine_launches"], f"{r['limit']:.3f}", f"{r['limit'] / r['busy']:.0%}",
                     f"{r['peak']:.0f}"]
        table.append(line)
    print(f"\n{args.pair}: warm binds in one process\n")
    print(markdown_table(head, table))
    for n, top in tops.items():
        if top:
            print(f"\nGPU time by activity at n = {n} (one bind)\n")
            print(markdown_table(["activity", "s", "launches"], [(k, f"{v[0]:.4f}", v[1]) for k, v in top]))
    if args.kernels and resolved.is_cuda:
        row = next((r for r in rows if r["n"] == args.kernels), rows[-1])
        columns = -(-row["handles"] // row["chunks"]) + (row["chunks"] > 1)  # one chunk's columns, as the bind solves
        print(f"\nsolver kernels alone at n = {args.kernels}, {columns} columns (median of 5; limit: the bytes each "
              "must move at least over the copy bandwidth)\n")
        print(markdown_table(["kernel", "level", "nodes", "ms", "GB", "limit ms", "limit / time"],
                             kernel_limits(mesh, cage, args.kernels, device, bandwidth, columns)))
    if args.assets:
        names, seconds, per_minute = throughput(device, args.resolutions[0], args.assets)
        print(f"\nthroughput: {args.assets} binds of {', '.join(names)} (round robin) at n = {args.resolutions[0]} in "
              f"{seconds:.1f} s: {per_minute:.0f} assets/min")
    if not args.skip_fresh:
        rows = fresh(args, device, cold=False) + (fresh(args, device, cold=True) if args.cold else [])
        print("\nfresh processes\n")
        print(markdown_table(["command", "kernel cache", "s", "exit", "says it compiles"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
