"""Deformation quality of Stokes (and harmonic) cage coordinates over resolutions, beside mean value coordinates
(issues 17 and 19: the source paper's Table 2).

    python benchmarks/bench_quality.py --resolutions 64,128,256,384 --device cuda --json quality.json
    python benchmarks/bench_quality.py --methods stokes,harmonic --resolutions 128,256 --device cuda
    python benchmarks/bench_quality.py --resolutions 24,32 --device cpu            # smoke test

Pairs (``--pairs``, default all three):

- ``smpl``: SMPL's rest pose (``model_rpose.obj``: arms down, the hand at +x beside the thigh) bound to
  ``cage_rpose.obj``, deformed by ``cage_tpose.obj`` and compared with the real T-pose mesh ``model_tpose.obj`` (same
  vertex order). Regions: the whole body and each hand (:func:`hand_regions`: the vertices beyond the wrist, the
  thinnest section of the arm between the elbow and the palm, in the T-pose). The model faces +z with +y up (its
  nose and toes point to +z), so the hand at +x is its **left** hand; issue 19 and ``RESULTS.md`` call that hand,
  the one beside the thigh, the right hand.
- ``arm``: the bundled arm (``examples/arm``) deformed by the most bent cage pose of ``bend_poses.npy`` (the frame
  farthest from the rest cage, RMS over handles); no reference mesh.
- ``ogre``: ``Ogre.obj`` / ``cage_tri.obj`` deformed by ``cage_deformed_tri.obj``; no reference mesh.

Per pair, mean value coordinates (MVC, evaluated at the vertices, no grid: the reference method) once, then a binding
by each method of ``--methods`` (the package's defaults otherwise) at each resolution, all measured by ``warp_stokes.quality``: conformal distortion
p50 / p95 / max over the region's triangles (sigma1 / sigma2); dihedral-angle change p95 against the reference
(degrees; unsigned angles between normals as in issue 19, and signed); fraction of negative weights (below -1e-5);
min weight; distant-handle weight (mean over the region's vertices of |w| on handles farther along the cage than a
quarter of its graph diameter); the weights' change against the next finer resolution in the list (max, and RMS
over the region's vertices of each one's largest change); seconds (the bind, or evaluating MVC, after a warm-up bind
that compiles the kernels); peak device memory (CUDA: the memory pool's high-water mark above its level, reset before
each bind). Prints a Markdown table; ``--json`` writes every measure.
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
from warp_stokes import quality

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ARM, OGRE, SMPL, DevicePeak, markdown_table, select_device, warm_up  # noqa: E402

PAIRS = ("smpl", "arm", "ogre")


def hand_regions(reference: np.ndarray, start: float = 0.5, width: float = 0.02) -> dict:
    """The two hands of a mesh in a T-pose: the vertices beyond the wrist along the arm axis.

    The arms lie along the mesh's widest axis. On each side, from the middle of the bounding box out to the side's
    farthest vertex (its reach), the mesh is cut into slices ``width`` of the reach thick from ``start`` of the
    reach on (the elbow lies inside), each measured by its thickness: the RMS distance of its vertices from their
    centroid across the axis. The palm is the thickest slice (the fingers beyond it are thin again); the wrist is
    the thinnest slice between ``start`` and the palm, and the hand every vertex beyond the wrist slice's middle.
    SMPL's T-pose (reach 0.91): wrists at |x| = 0.701, 797 and 800 vertices.

    Parameters
    ----------
    reference : (V, 3) array, the mesh in a T-pose
    start, width : float, fractions of each side's reach

    Returns
    -------
    dict: ``"hand +x"`` and ``"hand -x"`` (named by the axis and the side) -> (V,) bool, ``"wrists"`` -> the two
    wrists' coordinates along the axis (+ side first)
    """
    lo, hi = reference.min(axis=0), reference.max(axis=0)
    axis = int(np.argmax(hi - lo))
    across = [k for k in range(3) if k != axis]
    middle = 0.5 * (lo[axis] + hi[axis])
    out, wrists = {}, []
    for sign in (1.0, -1.0):
        s = sign * (reference[:, axis] - middle)
        reach = s.max()
        cuts = np.arange(start, 1.0, width) * reach
        thickness = np.full(len(cuts), np.nan)
        for i, cut in enumerate(cuts):
            section = reference[(s >= cut) & (s < cut + width * reach)][:, across]
            if len(section) >= 8:
                thickness[i] = np.sqrt(((section - section.mean(axis=0)) ** 2).sum(axis=1).mean())
        palm = int(np.nanargmax(thickness))
        wrist = cuts[int(np.nanargmin(thickness[:palm]))] + 0.5 * width * reach
        wrists.append(float(middle + sign * wrist))
        out[f"hand {'+' if sign > 0 else '-'}{'xyz'[axis]}"] = s > wrist
    out["wrists"] = tuple(wrists)
    return out


def load_pair(name: str) -> dict:
    """Mesh (Surface), cage (Cage), pose ((L, 3)), reference ((V, 3) or None), regions and a note for one pair."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # folded cage edges (SMPL, arm): known, see the README
        if name == "smpl":
            reference = ws.load_surface(SMPL / "model_tpose.obj").vertices
            hands = hand_regions(reference)
            return dict(mesh=ws.load_surface(SMPL / "model_rpose.obj"), cage=ws.check_cage(SMPL / "cage_rpose.obj"),
                        pose=ws.load_surface(SMPL / "cage_tpose.obj").vertices, reference=reference,
                        regions={"body": np.ones(len(reference), bool), "left hand (+x)": hands["hand +x"],
                                 "right hand (-x)": hands["hand -x"]},
                        note="wrists at x = {:.3f} / {:.3f} in the T-pose".format(*hands["wrists"]))
        if name == "arm":
            mesh = ws.load_surface(ARM / "arm.obj")
            cage = ws.check_cage(ARM / "arm_cage.obj")
            poses = np.load(ARM / "bend_poses.npy")
            frame = int(np.argmax(np.sqrt(((poses - cage.vertices) ** 2).sum(axis=2).mean(axis=1))))
            return dict(mesh=mesh, cage=cage, pose=poses[frame], reference=None,
                        regions={"all": np.ones(len(mesh.vertices), bool)}, note=f"bend_poses.npy frame {frame}")
        if name == "ogre":
            mesh = ws.load_surface(OGRE / "Ogre.obj")
            return dict(mesh=mesh, cage=ws.check_cage(OGRE / "cage_tri.obj"),
                        pose=ws.load_surface(OGRE / "cage_deformed_tri.obj").vertices, reference=None,
                        regions={"all": np.ones(len(mesh.vertices), bool)}, note="cage_deformed_tri.obj")
    raise SystemExit(f"unknown pair {name!r} (known: {', '.join(PAIRS)})")


def measure(pair: dict, weights, device, finer=None, fraction=quality.DISTANT_FRACTION) -> dict:
    mesh = pair["mesh"]
    return quality.deformation_quality(weights, mesh.vertices, mesh.faces, pair["cage"], pair["pose"],
                                       pair["reference"], pair["regions"], device, finer, fraction)


def _f(x, digits=3):
    return "-" if x is None or x != x else f"{x:.{digits}f}"


def table(rows: list, device: str) -> str:
    head = ("device", "pair", "region", "method", "n", "conformal p50", "p95", "max", "dihedral p95 (signed)",
            "neg frac", "min w", "distant w", "change max / rms", "s", "peak MiB", "its")
    lines = []
    for r in rows:
        for region, m in r["quality"]["regions"].items():
            c, ch = m["conformal"], m.get("change")
            dihedral = "-"
            if "dihedral_change" in m:
                dihedral = f"{_f(m['dihedral_change']['p95'], 1)} ({_f(m['dihedral_change_signed']['p95'], 1)})"
            lines.append([
                device, r["pair"], region, r["method"], str(r["n"] or "-"), _f(c["p50"]), _f(c["p95"]), _f(c["max"]),
                dihedral, _f(m["negative_fraction"], 4), _f(m["min_weight"]), _f(m["distant_weight"]["mean"]),
                f"{_f(ch['max'])} / {_f(ch['rms'], 4)}" if ch else "-", _f(r["seconds"], 2),
                _f(r.get("peak_bytes", float("nan")) / 2**20, 0), str(r.get("iterations", "-"))])
    return markdown_table(head, lines)


def run(args) -> list:
    rows = []
    for method in args.methods:  # compile and load every kernel on this device
        warm_up(args.device, method=method)
    for name in args.pairs:
        pair = load_pair(name)
        mesh, cage = pair["mesh"], pair["cage"]
        print(f"{name}: {len(mesh.vertices)} vertices, {cage.n_handles} handles, {pair['note']}", file=sys.stderr)
        start = time.perf_counter()
        with DevicePeak(args.device) as peak:
            mvc = ws.mean_value_coordinates(cage, mesh.vertices, device=args.device)
        rows.append({"pair": name, "method": "MVC", "n": None, "seconds": time.perf_counter() - start,
                     "peak_bytes": peak.bytes, "quality": measure(pair, mvc, args.device, fraction=args.fraction)})
        for method in args.methods:
            bound = []
            for n in sorted(args.resolutions):
                start = time.perf_counter()
                with warnings.catch_warnings(), DevicePeak(args.device) as peak:
                    warnings.simplefilter("ignore")
                    b = ws.bind(mesh, cage, resolution=n, device=args.device, method=method)
                bound.append((n, b, time.perf_counter() - start, peak.bytes))
                print(f"  {method} n = {n}: {bound[-1][2]:.2f} s, {b.stats.solver.iterations} iterations", file=sys.stderr,
                      flush=True)
            for i, (n, b, seconds, peak_bytes) in enumerate(bound):
                finer = bound[i + 1] if i + 1 < len(bound) else None
                q = measure(pair, b.weights, args.device, None if finer is None else finer[1].weights, args.fraction)
                rows.append({"pair": name, "method": method.capitalize(), "n": n,
                             "finer_n": None if finer is None else finer[0], "seconds": seconds,
                             "peak_bytes": peak_bytes, "quality": q, "iterations": b.stats.solver.iterations,
                             "partition_of_unity_error": b.stats.partition_of_unity_error,
                             "linear_precision_error": b.stats.linear_precision_error})
            del bound
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--resolutions", default="64,128,256,384", help="comma-separated grid resolutions")
    p.add_argument("--device", default=None, help="cpu | cuda | cuda:N (default: CUDA when present)")
    p.add_argument("--pairs", default=",".join(PAIRS), help=f"comma-separated, from {', '.join(PAIRS)}")
    p.add_argument("--methods", default="stokes", help="comma-separated grid methods: stokes, harmonic (MVC is "
                                                       "always measured, as the reference)")
    p.add_argument("--fraction", type=float, default=quality.DISTANT_FRACTION,
                   help="distant-handle threshold, as a fraction of the cage's graph diameter")
    p.add_argument("--json", default=None, help="write every measure to this file")
    args = p.parse_args(argv)
    args.resolutions = [int(n) for n in args.resolutions.split(",") if n.strip()]
    args.pairs = [s.strip() for s in args.pairs.split(",") if s.strip()]
    args.methods = [s.strip() for s in args.methods.split(",") if s.strip()]
    resolved, device = select_device(args.device)
    args.device = resolved.alias
    rows = run(args)
    print(f"\nDevice: {device}. Conformal distortion sigma1/sigma2 over the region's triangles; dihedral-angle change "
          f"p95 in degrees against the reference pose, unsigned (signed); neg frac: weights below "
          f"-{quality.NEGATIVE_TOLERANCE:g}; distant w: mean |w| on handles more than {args.fraction:g} of the "
          f"cage's graph diameter away along it; change: against the next finer n.\n")
    print(table(rows, device))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump([{**r, "device": device} for r in rows], fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
