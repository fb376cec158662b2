"""Throughput of a batch in one process against Ray workers (issue 15): assets per minute on one GPU and on two.

    python benchmarks/bench_ray_batch.py --assets 40 --resolution 128 --runs serial ray:1 ray:2

Makes ``--assets`` assets from the shared pairs (arm, ogre, SMPL) and variants of them (each pair's mesh and cage
rotated about the vertical axis and scaled together, so every asset is a different bind), writes a manifest, warms
the kernel cache with a one-asset batch, then times each run as a user runs it: ``warp-stokes batch`` in a fresh
process (``serial``: in-process on the default device; ``ray:N``: ``--workers N``, a local Ray cluster). The wall
time includes starting Python, Ray and its workers; the table also gives the time from the command's start to its
first asset written, the rate from the first asset finished to the last (the steady state: from the times the
bindings were written, first to last), and how busy each GPU was over the run and over its steady state (the share of
time a kernel ran, from ``nvidia-smi``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import PAIRS, WORK, GpuBusy, busy_text, markdown_table  # noqa: E402


def make_assets(folder: Path, n_assets: int) -> list[tuple[str, Path, Path]]:
    """(name, mesh, cage) of each asset: the pairs as they are, then rotated and scaled variants."""
    import numpy as np
    import trimesh

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    names = list(PAIRS)
    for k in range(n_assets):
        pair = names[k % len(names)]
        mesh, cage = PAIRS[pair]
        variant = k // len(names)
        if variant == 0:
            out.append((f"{pair}_0", mesh, cage))
            continue
        angle, scale = np.radians(11.0 * variant), 1.0 + 0.02 * variant
        transform = trimesh.transformations.rotation_matrix(angle, [0, 1, 0])
        transform[:3, :3] *= scale
        files = []
        for role, source in (("mesh", mesh), ("cage", cage)):
            target = folder / f"{pair}_{variant}_{role}.obj"
            if not target.exists():
                m = trimesh.load(source, process=False, force="mesh", maintain_order=True)
                m.apply_transform(transform)
                m.export(target)
            files.append(target)
        out.append((f"{pair}_{variant}", *files))
    return out


def write_manifest(path: Path, assets, resolution: int) -> Path:
    text = f"[defaults]\nresolution = {resolution}\n"
    for name, mesh, cage in assets:
        text += f'\n[[asset]]\nname = "{name}"\nmesh = "{mesh}"\ncage = "{cage}"\n'
    path.write_text(text)
    return path


def run(manifest: Path, outdir: Path, extra: list[str]) -> dict:
    command = [sys.executable, "-m", "warp_stokes.cli", "batch", str(manifest), "-o", str(outdir), "--force", *extra]
    with GpuBusy() as busy:
        start, began = time.perf_counter(), time.time()
        result = subprocess.run(command, capture_output=True, text=True)
        wall = time.perf_counter() - start
    if result.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(command)} failed ({result.returncode}):\n{result.stderr[-3000:]}")
    assets = json.loads((outdir / "summary.json").read_text())["assets"]
    done = [a for a in assets if a["status"] == "ok"]
    devices = sorted({a.get("device", "") for a in done})
    pids = sorted({a.get("pid") for a in done})
    # the steady state: when each asset finished, by the time its last output was written (a binding, then its
    # animation), from the first asset to the last: starting Python, Ray and the workers is left out
    finished = sorted(max(os.path.getmtime(o) for o in a["outputs"]) for a in done if a["outputs"])
    span = finished[-1] - finished[0] if len(finished) > 1 else 0.0
    steady = 60.0 * (len(finished) - 1) / span if span > 0 else float("nan")
    first = finished[0] - began if finished else float("nan")  # the command's start to its first asset written
    steady_busy = busy.fraction(finished[0], finished[-1]) if len(finished) > 1 else {}
    return {"wall_s": wall, "first_s": first, "ok": len(done), "failed": sum(a["status"] == "failed" for a in assets),
            "busy": busy_text(busy.fraction(began, began + wall)), "steady_busy": busy_text(steady_busy),
            "pace": next((line for line in result.stdout.splitlines() if line.startswith("first asset done")), ""),
            "bind_s": sum(a["seconds"] for a in done), "devices": devices, "processes": len(pids),
            "steady": steady, "errors": [a["error"] for a in assets if a["status"] == "failed"][:3]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--assets", type=int, default=40)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--runs", nargs="+", default=["serial", "ray:1", "ray:2"])
    parser.add_argument("--folder", default=str(WORK / "ray_batch"))
    args = parser.parse_args()
    folder = Path(args.folder)
    assets = make_assets(folder / "assets", args.assets)
    manifest = write_manifest(folder / "batch.toml", assets, args.resolution)
    warm = write_manifest(folder / "warm.toml", assets[:1], args.resolution)
    run(warm, folder / "warm", [])  # compile or load every kernel once: the cache is on disk, shared by workers
    rows = []
    for spec in args.runs:
        extra = [] if spec == "serial" else ["--workers", re.sub(r"^ray:", "", spec)]
        measured = run(manifest, folder / f"out_{spec.replace(':', '_')}", extra)
        rows.append((spec, args.assets, args.resolution, measured["ok"], measured["failed"], measured["processes"],
                     ", ".join(measured["devices"]), f"{measured['wall_s']:.1f}", f"{measured['first_s']:.1f}",
                     f"{60.0 * measured['ok'] / measured['wall_s']:.0f}", f"{measured['steady']:.0f}",
                     f"{measured['bind_s']:.1f}", measured["busy"], measured["steady_busy"]))
        print(rows[-1], measured["pace"], measured["errors"], file=sys.stderr, flush=True)
    base = next((float(r[7]) for r in rows if r[0] in ("serial", "ray:1")), None)
    print(markdown_table(("run", "assets", "n", "ok", "failed", "processes", "devices", "wall s", "first asset s",
                          "assets / min", "steady assets / min", "sum of bind s", "GPU busy %",
                          "GPU busy % (steady)"), rows))
    if base:
        for r in rows:
            print(f"{r[0]}: wall {float(r[7]) / base:.2f}x that of {rows[0][0]}")


if __name__ == "__main__":
    main()
