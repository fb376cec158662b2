"""Solver benchmark: whole binds over grid resolutions, pairs and devices, with the roofline of the stencil.

    python benchmarks/bench_solver.py --device cuda:0 --resolutions 32 64 96 128 192 256 --out results.md

Each (pair, resolution) runs in a fresh process (so that the GPU memory pool's high-water mark belongs to that
bind alone) and reports: device, n, handles, active and interior nodes, seconds per stage after a warm-up bind of the same size
(voxelise, multigrid setup, boundary data, solve, sample) and the whole bind, CG iterations, the CG iterations
that reach a 1e-6 max weight error (from the error history of a CG run that does not stop early), final residual,
max weight error at the vertices against a tightly converged reference (tol 1e-9, 60 iterations), peak GPU memory
(memory-pool high-water mark) next to the estimate made before allocating, and the batched stencil kernel's
achieved bandwidth (32 bytes per node and handle: read the packed (q, G) once, write the result once) as a
fraction of a device-to-device copy measured in the same process, with float32 sums (the V-cycle's smoothing
steps, six of the seven applications per CG iteration) and float64 sums (residuals and the CG step A p). At
small n it also runs the source paper's method: damped Jacobi sweeps (omega = 0.78) stopped when the largest
change per sweep falls below 1e-6.

The pairs are the real ones of ../shared/data (WARP_STOKES_DATA) and a synthetic cage with 240+ handles.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import (PAIRS, copy_bandwidth, markdown_table, pair, pool_high, select_device, table_head,  # noqa: E402
                    table_row, time_kernel, warm_up)


# ---------------------------------------------------------------------------------------------------------------
# measurements inside one process


def damped_jacobi(ws, wp, grid, cage, device, omega=0.78, threshold=1e-6, max_sweeps=400_000, max_seconds=120):
    """The source paper's solver: damped Jacobi sweeps stopped when the largest change per sweep < threshold."""
    from warp_stokes.kernels import multigrid as mgk
    from warp_stokes.kernels import cg

    @wp.kernel
    def max_abs(d: wp.array2d(dtype=wp.vec4f), out: wp.array(dtype=float)):
        n, h = wp.tid()
        wp.atomic_max(out, 0, wp.abs(d[n, h][0]))

    field = ws.boundary_field(grid, cage, device=device)
    n = grid.n_interior
    x = field[0:n]
    inv = np.zeros((n, 4, 4), np.float32)
    inv[:, 0, 0], inv[:, 1, 1], inv[:, 2, 2], inv[:, 3, 3] = 1 / 48, 1 / 4, 1 / 4, 1 / 4
    inv = wp.array(inv, dtype=wp.mat44f, device=device)
    r = wp.empty(x.shape, dtype=wp.vec4f, device=device)
    d = wp.empty_like(r)
    zero = wp.zeros(x.shape, dtype=wp.vec4f, device=device)
    change = wp.zeros(1, dtype=float, device=device)
    start = time.perf_counter()
    sweeps = 0
    while sweeps < max_sweeps and time.perf_counter() - start < max_seconds:
        for _ in range(100):
            ws.apply_operator(grid, field, r, device=device)
            wp.launch(cg.residual, dim=r.shape, inputs=[zero, r], outputs=[r], device=device)
            wp.launch(mgk.chebyshev_start, dim=r.shape, inputs=[r, inv, omega], outputs=[x, d], device=device)
            sweeps += 1
        change.zero_()
        wp.launch(max_abs, dim=d.shape, inputs=[d], outputs=[change], device=device)
        if float(change.numpy()[0]) < threshold:
            break
    wp.synchronize_device(device)
    return field, sweeps, time.perf_counter() - start


def convergence_history(ws, grid, cage, vertices, device, iterations=20):
    """Max weight error at the vertices after each CG iteration, against a tightly converged reference on the
    same grid (tol 1e-9, up to 60 iterations), with the identity deviation the solver checks. The CG runs
    `iterations` iterations without stopping (tol 1e-12), so the history is the plain multigrid-CG curve."""
    field = ws.boundary_field(grid, cage, device=device)
    ws.solve_biharmonic(grid, field, tol=1e-9, max_iterations=60, handles=cage.vertices, device=device)
    reference, corners = ws.sample_weights(grid, field, vertices, device=device)
    sampled = (corners >= 0).all(axis=1)
    reference = reference[sampled]
    field = ws.boundary_field(grid, cage, device=device)
    errors, pou = [], []

    def record(iteration, current):
        w, _ = ws.sample_weights(grid, current, vertices, device=device)
        errors.append(float(np.abs(w[sampled] - reference).max()))
        pou.append(float(np.abs(w[sampled].astype(np.float64).sum(axis=1) - 1.0).max()))

    report = ws.solve_biharmonic(grid, field, tol=1e-12, max_iterations=iterations, handles=cage.vertices,
                                 device=device, callback=record)
    return {"error": errors, "partition_of_unity": pou, "identity_at_end": report.identity_error,
            "residual_at_end": report.residual}


def one(name, n, device, memory_budget=None):
    """Measure one (pair, resolution) in this process; returns a dict. ``memory_budget`` (bytes) applies to the
    timed bind (and its warm-up): a budget below what all handles need makes it solve in chunks."""
    import warp as wp

    import warp_stokes as ws

    warnings.simplefilter("ignore")
    mesh, cage = pair(name)
    dev, device_name = select_device(device)
    # warm-up at the same size: compile and load every kernel
    warm_up(device, mesh, cage, resolution=n, memory_budget=memory_budget)
    out = {"pair": name, "n": n, "device": device_name}
    t = time.perf_counter()
    b = ws.bind(mesh, cage, resolution=n, device=device, memory_budget=memory_budget)
    out["wall"] = time.perf_counter() - t
    s = b.stats
    out.update({k: s[k] for k in ("handles", "interior_nodes", "iterations", "restarts", "identity_error",
                                  "solver_rounds",
                                  "residual", "converged", "levels",
                                  "chunks", "memory_estimate_bytes", "partition_of_unity_error",
                                  "linear_precision_error")})
    out["active_nodes"] = s.grid.interior_nodes + s.grid.ring_nodes + s.grid.band_nodes
    out["seconds"] = s.seconds
    out["peak_bytes"] = pool_high(dev)

    # stencil kernel bandwidth against a device copy
    checked = ws.check_cage(cage)
    grid = ws.voxelize(checked, n, device=device)
    field = ws.boundary_field(grid, checked, device=device)  # every handle, as the solver runs it
    x = field[0 : grid.n_interior]
    y = wp.empty(x.shape, dtype=wp.vec4f, device=device)
    moved = 32 * x.shape[0] * x.shape[1]
    for key, precise in (("stencil", True), ("stencil_f32", False)):
        seconds = time_kernel(device, lambda: ws.apply_operator(grid, x, y, n_rows=grid.n_interior, device=device,
                                                                    precise=precise))
        out[f"{key}_ms"] = seconds * 1e3
        out[f"{key}_gbs"] = moved / seconds / 1e9
    if dev.is_cuda:
        out["copy_gbs"] = copy_bandwidth(device) / 1e9
    field = x = y = None  # free them before the reference bind

    # tightly converged reference
    ref = ws.bind(mesh, cage, resolution=n, device=device, tol=1e-9, max_iterations=60)
    out["ref_iterations"] = ref.stats.solver.iterations
    out["error"] = float(np.abs(b.weights - ref.weights).max())

    if s.solver.chunks == 1:
        out["history"] = convergence_history(ws, grid, checked, b.mesh_vertices, device)
        out["iterations_to_1e-6"] = next((k for k, e in enumerate(out["history"]["error"]) if e <= 1e-6), None)

    if n <= 48:
        field, sweeps, seconds = damped_jacobi(ws, wp, grid, checked, device)
        w, _ = ws.sample_weights(grid, field, b.mesh_vertices, device=device)
        sampled = np.isfinite(w).all(axis=1) & (np.abs(w).sum(axis=1) > 0)
        out["jacobi"] = {"sweeps": sweeps, "seconds": seconds,
                         "error": float(np.abs(w[sampled] - ref.weights[sampled]).max())}
    return out


# ---------------------------------------------------------------------------------------------------------------


def table(rows):
    head = ["device", "pair", "n", "handles", "active", "levels", "chunks", "voxel s", "setup s", "bdry s",
            "solve s", "sample s", "bind s", "iters (restarts)", "iters to 1e-6", "residual", "max err", "peak GiB",
            "est GiB",
            "copy GB/s", "stencil f32 GB/s", "f32/copy", "stencil f64 GB/s", "f64/copy"]
    cells = []
    for r in rows:
        s = r["seconds"]
        peak = f"{r['peak_bytes'] / 2**30:.2f}" if r.get("peak_bytes") else "-"
        copy = r.get("copy_gbs")
        cells.append([
            r["device"], r["pair"], r["n"], r["handles"], r["active_nodes"], len(r["levels"]), r["chunks"],
            f"{s['voxelize']:.3f}", f"{s['setup']:.3f}", f"{s['boundary']:.3f}", f"{s['solve']:.3f}",
            f"{s['sample']:.3f}", f"{r['wall']:.3f}", f"{r['iterations']} ({r.get('restarts', '?')})",
            r.get("iterations_to_1e-6", "-"), f"{r['residual']:.1e}",
            f"{r['error']:.1e}", peak, f"{r['memory_estimate_bytes'] / 2**30:.2f}", f"{copy:.0f}" if copy else "-",
            f"{r['stencil_f32_gbs']:.0f}", f"{r['stencil_f32_gbs'] / copy:.0%}" if copy else "-",
            f"{r['stencil_gbs']:.0f}", f"{r['stencil_gbs'] / copy:.0%}" if copy else "-"])
    lines = [markdown_table(head, cells)]
    jac = [r for r in rows if "jacobi" in r]
    if jac:
        lines += ["", "Source paper's method (damped Jacobi, omega 0.78, stop when max change per sweep < 1e-6):", "",
                  table_head(("pair", "n", "sweeps", "seconds", "max err at stop", "multigrid CG: iters", "bind s",
                              "max err"))]
        for r in jac:
            j = r["jacobi"]
            lines.append(table_row((r["pair"], r["n"], j["sweeps"], f"{j['seconds']:.2f}", f"{j['error']:.1e}",
                                    r["iterations"], f"{r['wall']:.3f}", f"{r['error']:.1e}")))
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--resolutions", nargs="+", type=int, default=[32, 64, 96, 128, 192, 256])
    p.add_argument("--pairs", nargs="+", default=[*PAIRS, "synthetic"])
    p.add_argument("--out", default=None, help="write the markdown table (and a .json of all figures) here")
    p.add_argument("--memory-budget", type=float, default=None, metavar="GIB",
                   help="memory budget of the timed binds (GiB): below what all handles need, they solve in chunks")
    p.add_argument("--one", nargs=2, metavar=("PAIR", "N"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    budget = None if args.memory_budget is None else int(args.memory_budget * 2**30)
    if args.one:
        print("RESULT " + json.dumps(one(args.one[0], int(args.one[1]), args.device, budget)), flush=True)
        return 0
    rows = []
    for name in args.pairs:
        for n in args.resolutions:
            t = time.perf_counter()
            extra = [] if args.memory_budget is None else ["--memory-budget", str(args.memory_budget)]
            proc = subprocess.run([sys.executable, __file__, "--device", args.device, "--one", name, str(n)] + extra,
                                  capture_output=True, text=True)
            found = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
            if proc.returncode or not found:
                print(f"{name} n={n}: FAILED ({proc.returncode})\n{proc.stderr[-2000:]}", flush=True)
                continue
            rows.append(json.loads(found[-1][7:]))
            if args.out:  # keep what was measured even if a later configuration runs out of time
                Path(args.out).with_suffix(".json").write_text(json.dumps(rows, indent=1))
            r = rows[-1]
            print(f"{name} n={n}: bind {r['wall']:.3f} s, {r['iterations']} iterations ({r['restarts']} restarts, "
                  f"identity {r['identity_error']:.1e}, rounds {r['solver_rounds']}), error {r['error']:.1e}, "
                  f"stencil {r['stencil_f32_gbs']:.0f} / {r['stencil_gbs']:.0f} GB/s ({time.perf_counter() - t:.0f} s)", flush=True)
            if "history" in r:
                h = r["history"]
                print("  error per iteration: " + " ".join(f"{e:.1e}" for e in h["error"]), flush=True)
                print("  vertex PoU per iteration: " + " ".join(f"{e:.1e}" for e in h["partition_of_unity"]),
                      flush=True)
    text = table(rows)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
        Path(args.out).with_suffix(".json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
