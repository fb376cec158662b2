"""Blender's Mesh Deform beside warp-stokes on a CPU: the same pairs, the same cores, comparable grids.

    pip install "bpy==4.5.*"          # Blender 4.5 LTS as a Python module: Python 3.11 only, about 370 MB
    python benchmarks/bench_blender.py --pairs ogre --grids 64 128 --cores 2

Blender's precision P binds on a grid of 2^P + 2 cells a side (P = 6: 66, P = 7: 130); each ``--grids`` value n is
set beside the P whose grid is closest (64 beside 66, 128 beside 130). Each case (pair, tool, grid) runs in a fresh
child process of this script, pinned to the first ``--cores`` cores (``os.sched_setaffinity``, before Blender or
Warp start their thread pools), so that its peak memory is its own. warp-stokes binds on the CPU with
``threads=--cores`` after a warm-up bind at n = 16 (the kernels loaded); Blender binds with
``bpy.ops.object.meshdeform_bind`` (the bind runs inside the operator). Both deform the mesh by the pair's deformed
cage (the poses of ``bench_quality.py``) and are measured the same way (``warp_stokes.quality``): conformal distortion
p50 / p95 of the mesh's triangles, and, for SMPL, the RMS distance to the real T-pose mesh over the diagonal. With
``--repeat R`` the cases of a pair and grid run in turn R times (Blender, warp-stokes, Blender, ...): the table shows
each case's median bind time and every run's. Memory:
the child's peak resident set above its size before the bind (Linux: VmHWM reset through ``/proc/self/clear_refs``).
Prints a Markdown table; ``--json`` writes the rows.

``bpy`` is a benchmark extra only, never a dependency of the package or its tests.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import table_head, table_row  # noqa: E402

INSTALL = 'pip install "bpy==4.5.*" (Blender 4.5 LTS as a Python module; Python 3.11 only)'


def blender_precision(n: int) -> int:
    """Blender's Mesh Deform precision whose grid (2^P + 2 cells a side) is closest to ``n`` cells (P in 2..10)."""
    return min(range(2, 11), key=lambda p: abs(2**p + 2 - n))


def _peak_reset() -> None:
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")


def _status_bytes(key: str) -> int:
    """A field of /proc/self/status in bytes (VmHWM: the peak resident set since the reset; VmRSS: the current one)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return 0


def _pair(name: str) -> dict:
    from bench_quality import load_pair

    return load_pair(name)


def _blender_case(pair: dict, n: int) -> dict:
    """Bind with Blender's Mesh Deform at the precision closest to ``n``; deform by the pair's pose."""
    import bpy

    precision = blender_precision(n)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh, cage = pair["mesh"], pair["cage"]
    data = bpy.data.meshes.new("mesh")
    data.from_pydata(mesh.vertices.tolist(), [], mesh.faces.tolist())
    obj = bpy.data.objects.new("mesh", data)
    cage_data = bpy.data.meshes.new("cage")
    cage_data.from_pydata(cage.vertices.tolist(), [], cage.faces.tolist())
    cage_obj = bpy.data.objects.new("cage", cage_data)
    for o in (obj, cage_obj):
        bpy.context.scene.collection.objects.link(o)
    modifier = obj.modifiers.new("MeshDeform", "MESH_DEFORM")
    modifier.object = cage_obj
    modifier.precision = precision
    bpy.context.view_layer.objects.active = obj
    _peak_reset()
    base = _status_bytes("VmRSS")
    start = time.perf_counter()
    with bpy.context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.meshdeform_bind(modifier=modifier.name)
    seconds = time.perf_counter() - start
    peak = _status_bytes("VmHWM") - base
    if not modifier.is_bound:
        raise RuntimeError("Blender's Mesh Deform did not bind")
    cage_data.vertices.foreach_set("co", np.asarray(pair["pose"], dtype=np.float32).ravel())
    cage_data.update()
    graph = bpy.context.evaluated_depsgraph_get()
    graph.update()
    evaluated = obj.evaluated_get(graph).to_mesh()
    deformed = np.empty(3 * len(evaluated.vertices), dtype=np.float32)
    evaluated.vertices.foreach_get("co", deformed)
    return dict(tool="Blender Mesh Deform", grid=f"{2**precision + 2}^3 (precision {precision})", seconds=seconds,
                peak=peak, deformed=deformed.reshape(-1, 3).astype(np.float64), iterations=None)


def _warp_stokes_case(pair: dict, n: int, threads: int, method: str, memory_gb: float | None = None) -> dict:
    import warp_stokes as ws

    budget = None if memory_gb is None else int(memory_gb * 2**30)
    mesh, cage = pair["mesh"], pair["cage"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ws.bind(mesh, cage, resolution=16, device="cpu", threads=threads, method=method)  # the kernels loaded
        _peak_reset()
        base = _status_bytes("VmRSS")
        start = time.perf_counter()
        binding = ws.bind(mesh, cage, resolution=n, device="cpu", threads=threads, method=method,
                          memory_budget=budget)
        seconds = time.perf_counter() - start
        peak = _status_bytes("VmHWM") - base
    deformed = binding.deform(pair["pose"])
    tool = f"warp-stokes {method}" + ("" if memory_gb is None else f", --memory-gb {memory_gb:g}")
    return dict(tool=tool, grid=f"{n} (cells along the longest axis)", seconds=seconds, peak=peak,
                deformed=np.asarray(deformed, dtype=np.float64), iterations=binding.stats.solver.iterations)


def _child(pair_name: str, tool: str, n: int, cores: int, method: str, memory_gb: float | None = None) -> dict:
    """One case, in this (child) process."""
    os.sched_setaffinity(0, set(range(cores)))  # before any thread pool starts
    pair = _pair(pair_name)
    case = (_blender_case(pair, n) if tool == "blender" else _warp_stokes_case(pair, n, cores, method, memory_gb))
    from warp_stokes import quality

    mesh = pair["mesh"]
    conformal = quality.conformal_distortion(mesh.faces, mesh.vertices, case["deformed"])
    row = dict(pair=pair_name, tool=case["tool"], grid=case["grid"], cores=cores, seconds=case["seconds"],
               peak_mib=case["peak"] / 2**20, iterations=case["iterations"],
               conformal_p50=float(np.percentile(conformal, 50)), conformal_p95=float(np.percentile(conformal, 95)))
    if pair["reference"] is not None:
        diagonal = float(np.linalg.norm(np.ptp(pair["reference"], axis=0)))
        error = np.sqrt(((case["deformed"] - pair["reference"]) ** 2).sum(axis=1).mean()) / diagonal
        row["rms_to_reference"] = float(error)
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pairs", nargs="+", default=["ogre"], help="arm, smpl, ogre (default: ogre)")
    p.add_argument("--grids", type=int, nargs="+", default=[64, 128])
    p.add_argument("--cores", type=int, default=min(2, os.cpu_count() or 1), help="cores for both tools (2)")
    p.add_argument("--methods", nargs="+", default=["stokes"], help="warp-stokes methods (stokes, harmonic)")
    p.add_argument("--repeat", type=int, default=1, help="runs of each case, taken in turn; the median is shown (1)")
    p.add_argument("--json", default=None, help="write the rows to this file")
    p.add_argument("--memory-gb", type=float, default=None,
                   help="also bind with warp-stokes within this memory budget (GiB): fewer handles solved at once")
    p.add_argument("--child", nargs=6, help=argparse.SUPPRESS)  # PAIR TOOL N CORES METHOD MEMORY: one case
    args = p.parse_args(argv)
    if args.child:
        pair_name, tool, n, cores, method, memory = args.child
        budget = None if memory == "-" else float(memory)
        print(json.dumps(_child(pair_name, tool, int(n), int(cores), method, budget)))
        return 0
    try:
        import bpy  # noqa: F401
    except ImportError:
        print(f"bench_blender.py needs Blender's Python module: {INSTALL}", file=sys.stderr)
        return 2
    if not hasattr(os, "sched_setaffinity"):
        print("bench_blender.py pins each case to its cores with os.sched_setaffinity (Linux)", file=sys.stderr)
        return 2
    rows = []
    columns = ["pair", "tool", "grid", "cores", "bind s", "runs (s)", "peak MiB", "iterations", "conformal p50",
               "conformal p95", "RMS to reference / diagonal"]
    print(table_head(columns), flush=True)
    for pair_name in args.pairs:
        for n in args.grids:
            cases = [("blender", "stokes", "-")] + [("warp-stokes", m, "-") for m in args.methods]
            if args.memory_gb is not None:
                cases += [("warp-stokes", m, str(args.memory_gb)) for m in args.methods]
            runs = {case: [] for case in cases}
            # the cases in turn, --repeat times: a shared machine's speed drifts over minutes, and each tool's
            # median then comes from the same stretch of time as the other's
            for _ in range(args.repeat):
                for case in cases:
                    tool, method, memory = case
                    proc = subprocess.run([sys.executable, __file__, "--child", pair_name, tool, str(n),
                                           str(args.cores), method, memory], capture_output=True, text=True)
                    if proc.returncode != 0:
                        print(proc.stderr, file=sys.stderr)
                        return 1
                    runs[case].append(json.loads(proc.stdout.strip().splitlines()[-1]))
            for case in cases:
                row = dict(runs[case][0])
                times = [r["seconds"] for r in runs[case]]
                row.update(seconds=float(np.median(times)), runs=times,
                           peak_mib=float(np.median([r["peak_mib"] for r in runs[case]])))
                rows.append(row)
                print(table_row([row["pair"], row["tool"], row["grid"], row["cores"], f"{row['seconds']:.2f}",
                                 " / ".join(f"{t:.2f}" for t in times), f"{row['peak_mib']:.0f}",
                                 row["iterations"] if row["iterations"] is not None else "-",
                                 f"{row['conformal_p50']:.4f}", f"{row['conformal_p95']:.4f}",
                                 f"{row['rms_to_reference']:.4f}" if "rms_to_reference" in row else "-"]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
