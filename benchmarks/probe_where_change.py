"""Where the weights change most between two resolutions (issue 19's refinement target), per pair and data.

    python benchmarks/probe_where_change.py --device cuda                       # n = 256 against 384
    python benchmarks/probe_where_change.py --device cpu --resolutions 24,32    # smoke test

For the ogre, the arm and SMPL (rest pose), with the local boundary data (the default), MVC data and harmonic
coordinates: the largest change of any weight of any vertex between the two resolutions, its 99th percentile, the
vertices beyond the grid's band at each, the four vertices that change most (handle, weights, inside or outside the
cage, distance from the cage in cells of the finer grid) and the largest change per distance band.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

import warp_stokes as ws
from warp_stokes.geometry.inside import classify_points

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ARM, OGRE, SMPL, select_device  # noqa: E402

PAIRS = {"ogre": (OGRE / "Ogre.obj", OGRE / "cage_tri.obj"), "arm": (ARM / "arm.obj", ARM / "arm_cage.obj"),
         "smpl": (SMPL / "model_rpose.obj", SMPL / "cage_rpose.obj")}
VARIANTS = (("local", {}), ("mvc-data", {"boundary": "mvc"}), ("harmonic", {"method": "harmonic"}))


def probe(name: str, coarse: int, fine: int, device) -> None:
    mesh, cage_path = PAIRS[name]
    cage = ws.check_cage(cage_path)
    cell = (cage.vertices.max(0) - cage.vertices.min(0)).max() / fine
    for label, options in VARIANTS:
        b = {n: ws.bind(mesh, cage, resolution=n, device=device, **options) for n in (coarse, fine)}
        change = np.abs(b[coarse].weights - b[fine].weights)
        per_vertex = change.max(axis=1)
        inside, distance = classify_points(cage, b[coarse].mesh_vertices, device=device)
        print(f"{name} {label}: max change {per_vertex.max():.3f}; p99 {np.percentile(per_vertex, 99):.4f}; vertices "
              f"> 0.05: {(per_vertex > 0.05).sum()}; beyond the band {b[coarse].stats.vertices_beyond_band} / "
              f"{b[fine].stats.vertices_beyond_band}")
        for j in np.argsort(per_vertex)[::-1][:4]:
            h = int(change[j].argmax())
            print(f"   v{j}: change {per_vertex[j]:.3f} (handle {h}: {b[coarse].weights[j, h]:.3f} -> "
                  f"{b[fine].weights[j, h]:.3f}), {'inside' if inside[j] else 'OUTSIDE'}, "
                  f"{distance[j] / cell:.2f} cells (n = {fine}) from the cage")
        edges = [0, 1, 2, 4, 8, np.inf]
        for low, high in zip(edges[:-1], edges[1:]):
            band = (distance / cell >= low) & (distance / cell < high)
            if band.any():
                print(f"     {low}-{high} cells: {band.sum()} vertices, max change {per_vertex[band].max():.3f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--resolutions", default="256,384", help="the two resolutions, coarse,fine")
    p.add_argument("--pairs", default=",".join(PAIRS), help=f"comma-separated, from {', '.join(PAIRS)}")
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)
    coarse, fine = (int(n) for n in args.resolutions.split(","))
    resolved, name = select_device(args.device)
    print(f"device: {name}")
    warnings.simplefilter("ignore")
    for pair in args.pairs.split(","):
        probe(pair.strip(), coarse, fine, resolved.alias)
    return 0


if __name__ == "__main__":
    sys.exit(main())
