"""Boundary data compared by the deformations they give, beside mean value coordinates (issue 19).

    python benchmarks/bench_boundary.py --resolutions 96 128 256 --device cuda:0 --json out.jsonl
    python benchmarks/bench_boundary.py --refinement 64 96 128 192 256 384 --device cuda:0

Pairs: SMPL rest pose (arms down, hands beside the thighs) deformed by its T-pose cage and compared with the real
T-pose mesh (regions: the hand at +x and the hand at -x in the T-pose, |x| > 0.6, and the whole body); the ogre
deformed by its deformed cage and the arm by its most bent pose (no reference meshes). For every boundary-data
variant and resolution, the measures of ``warp_stokes.quality``: conformal distortion (per triangle, sigma1 / sigma2
of the map rest -> deformed), dihedral-angle change against the reference (degrees, SMPL), the weight held by
distant handles, min weight, fraction of negative weights; and CG iterations, bind seconds. Mean value coordinates
evaluated at the vertices are the reference method (one row per pair).

``--refinement`` instead follows the min weight of each pair over resolutions: its value, the vertex where it occurs
and that vertex's distance to the nearest folded cage edge (faces whose normals are more than 150 degrees apart),
and the largest change of any weight from the previous resolution.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import warp_stokes as ws
from warp_stokes.geometry.cage import folded_edges

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ARM, OGRE, SMPL, select_device, table_head, table_row  # noqa: E402

VARIANTS = {
    "mvc-data": "mvc",
    "local": ws.LocalData(),  # the default
    "local-no-folds": ws.LocalData(fold_radius=0.0),
    "least-norm": ws.LocalData(model="least-norm"),
    "local-r3": ws.LocalData(radius=3.0),
    "mix-0.5": ws.LocalData(fold_radius=0.0, least_norm_share=0.5),
}


def segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P,) distance of each point to the nearest of the segments a[i]-b[i]."""
    if len(a) == 0:
        return np.full(len(points), np.inf)
    d = b - a
    t = np.clip(np.einsum("pik,ik->pi", points[:, None] - a[None], d) / (d * d).sum(1), 0, 1)
    return np.linalg.norm(points[:, None] - (a[None] + t[..., None] * d[None]), axis=2).min(axis=1)


def load_pair(name: str):
    if name == "smpl":
        mesh = ws.load_surface(SMPL / "model_rpose.obj")
        cage = ws.check_cage(SMPL / "cage_rpose.obj")
        pose = ws.load_surface(SMPL / "cage_tpose.obj").vertices
        reference = ws.load_surface(SMPL / "model_tpose.obj").vertices
        x = reference[:, 0]
        regions = {"body": np.ones(len(x), bool), "hand +x": x > 0.6, "hand -x": x < -0.6}
        return mesh, cage, pose, reference, regions
    if name == "ogre":
        mesh = ws.load_surface(OGRE / "Ogre.obj")
        return mesh, ws.check_cage(OGRE / "cage_tri.obj"), ws.load_surface(OGRE / "cage_deformed_tri.obj").vertices, \
            None, {"body": np.ones(len(mesh.vertices), bool)}
    if name == "arm":
        mesh = ws.load_surface(ARM / "arm.obj")
        cage = ws.check_cage(ARM / "arm_cage.obj")
        poses = np.load(ARM / "bend_poses.npy")
        return mesh, cage, poses[-1], None, {"body": np.ones(len(mesh.vertices), bool)}
    raise SystemExit(f"unknown pair {name}")


def measure(name, mesh, cage, pose, reference, regions, weights, device):
    q = ws.deformation_quality(weights, mesh.vertices, mesh.faces, cage, pose, reference, regions, device=device)
    out = {}
    for region, m in q["regions"].items():
        row = {"conformal_p95": m["conformal"]["p95"], "conformal_p50": m["conformal"]["p50"],
               "conformal_max": m["conformal"]["max"], "distant_p95": m["distant_weight"]["p95"]}
        if "dihedral_change" in m:
            row["dihedral_p95"] = m["dihedral_change"]["p95"]
        out[region] = row
    return {"pair": name, "regions": out, "min_weight": q["min_weight"], "negative_fraction": q["negative_fraction"]}


def compare(args) -> int:
    rows = []
    for name in args.pairs:
        mesh, cage, pose, reference, regions = load_pair(name)
        row = measure(name, mesh, cage, pose, reference, regions,
                      ws.mean_value_coordinates(cage, mesh.vertices, device=args.device), args.device)
        rows.append({**row, "method": "MVC", "n": "", "iterations": 0, "seconds": 0.0})
        print(json.dumps(rows[-1]), flush=True)
        for n in args.resolutions:
            for label in args.variants:
                start = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    b = ws.bind(mesh, cage, resolution=n, device=args.device, boundary=VARIANTS[label],
                                sampling=args.sampling)
                seconds = time.perf_counter() - start
                row = measure(name, mesh, cage, pose, reference, regions, b.weights.astype(np.float64), args.device)
                rows.append({**row, "method": f"{label} ({args.sampling})", "n": n, "iterations": b.stats.solver.iterations, "seconds": seconds,
                             "pu": b.stats.partition_of_unity_error, "lp": b.stats.linear_precision_error})
                print(json.dumps(rows[-1]), flush=True)
    if args.json:
        with open(args.json, "a") as fh:
            fh.writelines(json.dumps(r) + "\n" for r in rows)
    device = select_device(args.device)[1]
    print(f"\nDevice: {device}. Conformal distortion p50 / p95 / max, dihedral change p95 (degrees) and distant-handle "
          "weight p95 by region; min weight; iterations.\n")
    print(table_head(("pair", "method", "n", "region", "conformal p50", "p95", "max", "dihedral p95", "distant p95",
                      "min w", "neg %", "its", "s")))
    for r in rows:
        for region, m in r["regions"].items():
            print(table_row((r["pair"], r["method"], r["n"], region, f"{m['conformal_p50']:.3f}",
                             f"{m['conformal_p95']:.3f}", f"{m['conformal_max']:.2f}",
                             f"{m.get('dihedral_p95', float('nan')):.1f}", f"{m['distant_p95']:.3f}",
                             f"{r['min_weight']:.3f}", f"{100 * r['negative_fraction']:.1f}", r["iterations"],
                             f"{r['seconds']:.2f}")))
    return 0


def refinement(args) -> int:
    rows = []
    for name in args.pairs:
        mesh, cage, *_ = load_pair(name)
        folds = folded_edges(cage)
        a, b = cage.vertices[folds[:, 0]], cage.vertices[folds[:, 1]]
        for label in args.variants:
            previous = None
            for n in args.refinement:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    start = time.perf_counter()
                    bound = ws.bind(mesh, cage, resolution=n, device=args.device, boundary=VARIANTS[label],
                                    sampling=args.sampling)
                    seconds = time.perf_counter() - start
                w = bound.weights
                change = float(np.abs(w - previous).max()) if previous is not None else float("nan")
                previous = w
                j, l = np.unravel_index(int(np.argmin(w)), w.shape)
                distance = float(segment_distance(mesh.vertices[j : j + 1], a, b)[0])
                rows.append({"pair": name, "method": f"{label} ({args.sampling})", "n": n, "min_weight": float(w[j, l]), "vertex": int(j),
                             "handle": int(l), "fold_distance": distance / cage.diagonal,
                             "spacing": bound.stats.grid.spacing / cage.diagonal,
                             "iterations": bound.stats.solver.iterations, "seconds": seconds,
                             "cut_off_nodes": bound.stats.grid.cut_off_nodes, "change_from_previous": change})
                print(json.dumps(rows[-1]), flush=True)
    if args.json:
        with open(args.json, "a") as fh:
            fh.writelines(json.dumps(r) + "\n" for r in rows)
    print(f"\nDevice: {select_device(args.device)[1]}. Distances relative to the cage's diagonal.\n")
    print(table_head(("pair", "data", "n", "min weight", "vertex", "handle", "distance to a folded edge", "cell",
                      "nodes cut off by wedges", "max change from the previous n", "its", "s")))
    for r in rows:
        print(table_row((r["pair"], r["method"], r["n"], f"{r['min_weight']:.3f}", r["vertex"], r["handle"],
                         f"{r['fold_distance']:.4f}", f"{r['spacing']:.4f}", r["cut_off_nodes"],
                         f"{r['change_from_previous']:.3f}",
                         r["iterations"], f"{r['seconds']:.2f}")))
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pairs", nargs="+", default=["smpl", "ogre"])
    p.add_argument("--resolutions", nargs="+", type=int, default=[96])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--refinement", nargs="*", type=int, default=None)
    p.add_argument("--sampling", default="hermite", choices=["hermite", "trilinear"])
    p.add_argument("--device", default=None)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    args.device = select_device(args.device)[0].alias
    return refinement(args) if args.refinement else compare(args)


if __name__ == "__main__":
    sys.exit(main())
