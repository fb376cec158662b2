"""Made cages (`warp-stokes cage`, issue 33) on every pair with an artist's cage, at the artist's handle count and at
half and twice it: time, validity, enclosure, tightness, and how well the cage expresses the artist's deformations.

    python benchmarks/bench_cage.py --device cpu                      # all pairs, scales 0.5, 1, 2
    python benchmarks/bench_cage.py --device cuda --pairs ogre --scales 1 --json cage.json
    python benchmarks/bench_cage.py --device cpu --pairs "" --synthetic 0,1    # the synthetic shapes only
    python benchmarks/bench_cage.py --device cpu --pairs "" --meshes models/*.obj --mesh-handles 30
    python benchmarks/bench_cage.py --device cpu --scales 1 --offsets 0.019,0.0195,0.02,0.0205,0.021
    python benchmarks/bench_cage.py --device cpu --pairs "" --artist Beast.obj Beast_Cage.obj Beast_Cage_Deformed.obj

Per pair and scale (handles asked = scale x the artist's count, at least 8):

- time: ``make_cage`` wall time after a warm-up on a small sphere (the kernels compiled), and its stages;
- handles made; the package's cage checks (``check_cage``: closed, outward, manifold) and crossing face pairs (must
  be 0); vertices inside by the package's inside test (must be all);
- tightness: mean and max distance from the mesh's vertices to the cage over the mesh's diagonal, and the volume
  between them over the mesh's volume (both volumes counted on a grid of the cage's box, 96 cells along its longest
  side or ``--volume-cells``; the mesh's inside by its winding number, so open meshes have one, on the artist's
  cage's grid);
- expression: the artist's deformation (SMPL: ``cage_rpose`` -> ``cage_tpose``; the ogre: ``cage_deformed_tri``; the
  arm: every frame of ``bend_poses.npy``) applied with the artist's binding, then encoded with a binding to the made
  cage (least squares, every frame): RMS and max error over the mesh's diagonal (the source paper's Table 1 measure),
  beside the artist's own cage; the binding's partition of unity and linear precision; the model reduction
  1 - handles / vertices. Both bindings at ``--resolution`` (default 64), Stokes, the package's defaults.

``--artist MESH CAGE POSES`` (repeatable): another pair with an artist's cage, measured as the pairs above; POSES is
the artist's posed cage (a mesh file with the cage's vertices in the same order, faces ignored) or a ``.npy`` of
frames (F, L, 3). The artist's row gives the fraction of the mesh's vertices its cage encloses (artists' cages do not
always hold them all).

``--offsets F,F,...``: each pair's cages made at each of these offsets (fractions of the diagonal) instead of the
default, and a summary per pair and scale: the mean and range of RMS and max over the offsets. Small changes of the
offset change the cage's handles a little and its expression by more than that (a single offset's figure is one draw).

``--meshes FILES``: also meshes that have no artist's cage (any file ``bind`` reads), each made into a cage at
``--mesh-handles`` (default: chosen from its shape) and bound at ``--resolution``: handles asked and made, the offset
it was made at (raised from the default where the count was not reached), seconds (make), inside, crossing faces,
distances, PU and LP, notes.

``--synthetic SEEDS``: also the synthetic shapes of ``stress_pairs(seed, detail=1)`` (boxes, noisy ellipsoids, stars,
thin slabs, dumbbells with thin necks, tori; their cages taken as the meshes), ``--synthetic-handles`` each (40),
bound at n = 32: handles, seconds (make and bind), distances, PU and LP, notes.

Prints Markdown tables; ``--json`` writes every measure.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[1] / "tests"))  # the synthetic cages: tests/shapes.py
from common import ARM, PAIRS, SMPL, markdown_table, select_device  # noqa: E402


def artist_frames(name: str, artist_cage) -> np.ndarray:
    """(F, L, 3) the artist's cage poses of a pair."""
    if name == "smpl":
        return ws.load_surface(SMPL / "cage_tpose.obj").vertices[None]
    if name == "arm":
        return np.load(ARM / "bend_poses.npy")
    if name == "ogre":
        return ws.load_surface(PAIRS["ogre"][1].parent / "cage_deformed_tri.obj").vertices[None]
    raise ValueError(name)


def volumes(mesh, cage, device, cells: int = 96) -> tuple[float | None, float]:
    """(mesh volume, cage volume) counted on a grid over the cage's box, ``cells`` along its longest side: the mesh's
    inside by its winding number (None for ``mesh=None``: the cage's alone)."""
    from warp_stokes.geometry.cage import Cage

    lo, hi = cage.vertices.min(axis=0), cage.vertices.max(axis=0)
    h = (hi - lo).max() / cells
    axes = [np.arange(lo[k] + 0.5 * h, hi[k], h) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    in_cage, _ = ws.classify_points(cage, grid, device=device)
    if mesh is None:
        return None, float(in_cage.sum() * h ** 3)
    body = Cage(vertices=mesh.vertices, faces=mesh.faces, name="mesh")  # no checks: the inside test only
    in_mesh, _ = ws.classify_points(body, grid, device=device)
    return float(in_mesh.sum() * h ** 3), float(in_cage.sum() * h ** 3)


def expression(binding, targets: np.ndarray, diag: float) -> tuple[float, float]:
    """RMS and max over all frames and vertices of the least-squares fit's error, over the diagonal."""
    w = binding.weights.astype(np.float64)
    errors = []
    for target in targets:
        poses, *_ = np.linalg.lstsq(w, target, rcond=None)
        errors.append(np.linalg.norm(w @ poses - target, axis=1) / diag)
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(e ** 2))), float(e.max())


def artist_poses(path, artist_cage) -> np.ndarray:
    """(F, L, 3) an artist's cage poses from a posed cage file (its vertices, in the cage's order) or a .npy."""
    poses = np.asarray(np.load(path) if str(path).endswith(".npy") else ws.load_surface(path).vertices, dtype=float)
    if poses.size == 0 or poses.size % (3 * artist_cage.n_handles):
        raise SystemExit(f"{path}: not poses of the {artist_cage.n_handles}-handle cage ({poses.shape})")
    return poses.reshape(-1, artist_cage.n_handles, 3)


def measure(name: str, scales, device, resolution: int, offsets=(None,), files=None, cells: int = 96) -> list[dict]:
    """Rows of the artist's cage and the made ones for pair ``name``: one of PAIRS, or ``files`` = (mesh, cage,
    poses) as ``--artist`` takes them; volumes on grids of ``cells`` along the longest side."""
    from warp_stokes.geometry.cage import crossing_faces
    from warp_stokes.geometry.topology import bounding_diagonal

    mesh_path, cage_path = PAIRS[name] if files is None else files[:2]
    mesh = ws.load_surface(mesh_path)
    artist = ws.check_cage(cage_path)
    diag = bounding_diagonal(mesh.vertices)
    reference = ws.bind(mesh_path, cage_path, resolution=resolution, device=device)
    poses = artist_frames(name, artist) if files is None else artist_poses(files[2], artist)
    targets = np.stack([reference.deform(pose) for pose in poses])
    artist_rms, artist_max = expression(reference, targets, diag)
    mesh_volume, artist_volume = volumes(mesh, artist, device, cells)
    held, _ = ws.classify_points(artist, mesh.vertices, device=device)
    rows = [dict(pair=name, cage="artist", asked=artist.n_handles, handles=artist.n_handles, seconds=None,
                 inside=float(held.mean()), crossing=0, mean_distance=None, max_distance=None,
                 volume_between=(artist_volume - mesh_volume) / mesh_volume, rms=artist_rms, max=artist_max,
                 pu=reference.stats.partition_of_unity_error, lp=reference.stats.linear_precision_error,
                 reduction=1 - artist.n_handles / len(mesh.vertices), moved=float(
                     np.linalg.norm(targets - mesh.vertices, axis=2).max() / diag))]
    for scale, offset in [(scale, offset) for scale in scales for offset in offsets]:
        asked = max(8, int(round(scale * artist.n_handles)))  # a made cage's least count
        t = time.perf_counter()
        made = ws.make_cage(mesh_path, handles=asked, offset=offset, device=device)
        seconds = time.perf_counter() - t
        cage = made.cage
        inside, _ = ws.classify_points(cage, mesh.vertices, device=device)
        _, cage_volume = volumes(None, cage, device, cells)  # (the mesh's volume is the artist's row's)
        binding = ws.bind(mesh_path, cage, resolution=resolution, device=device)
        rms, worst = expression(binding, targets, diag)
        label = f"made x{scale:g}" + ("" if offset is None else f" at {100 * offset:g} %")
        rows.append(dict(pair=name, cage=label, scale=scale, offset=offset, asked=asked, handles=cage.n_handles,
                         seconds=seconds, stages={k: round(v, 3) for k, v in made.seconds.items()},
                         inside=float(inside.mean()),
                         crossing=int(len(crossing_faces(cage.vertices, cage.faces))),
                         mean_distance=made.distance[0], max_distance=made.distance[1],
                         volume_between=(cage_volume - mesh_volume) / mesh_volume, rms=rms, max=worst,
                         pu=binding.stats.partition_of_unity_error, lp=binding.stats.linear_precision_error,
                         reduction=1 - cage.n_handles / len(mesh.vertices), notes=made.notes))
        print(f"{name} {label}: {made.summary()}", file=sys.stderr, flush=True)
    return rows


def spread(rows: list[dict]) -> list[list]:
    """A row per pair and scale: the mean and range of the made cages' RMS and max errors over the offsets, in %."""
    out = []
    for key in dict.fromkeys((r["pair"], r["scale"]) for r in rows if "scale" in r):
        group = [r for r in rows if (r["pair"], r.get("scale")) == key]
        rms, worst = 100 * np.array([r["rms"] for r in group]), 100 * np.array([r["max"] for r in group])
        out.append([key[0], f"made x{key[1]:g}", len(group), f"{rms.mean():.3f}", f"{rms.min():.3f}-{rms.max():.3f}",
                    f"{worst.mean():.2f}", f"{worst.min():.2f}-{worst.max():.2f}"])
    return out


def meshes(paths, handles, device, resolution: int) -> list[dict]:
    """Cages made for meshes without one, and their bindings (see the module's text)."""
    from warp_stokes.geometry.cage import crossing_faces
    from warp_stokes.geometry.topology import bounding_diagonal

    rows = []
    for path in paths:
        mesh = ws.load_surface(path)
        t = time.perf_counter()
        made = ws.make_cage(path, handles=handles, device=device)
        seconds = time.perf_counter() - t
        inside, _ = ws.classify_points(made.cage, mesh.vertices, device=device)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            binding = ws.bind(path, made.cage, resolution=resolution, device=device)
        rows.append(dict(mesh=Path(path).name, vertices=len(mesh.vertices), asked=made.handles, chosen=made.chosen,
                         handles=made.cage.n_handles, offset=made.offset / bounding_diagonal(mesh.vertices),
                         seconds=seconds, inside=float(inside.mean()),
                         crossing=int(len(crossing_faces(made.cage.vertices, made.cage.faces))),
                         mean_distance=made.distance[0], max_distance=made.distance[1],
                         pu=binding.stats.partition_of_unity_error, lp=binding.stats.linear_precision_error,
                         notes=made.notes))
        print(f"{Path(path).name}: {made.summary()}", file=sys.stderr, flush=True)
    return rows


def synthetic(seeds, handles: int, device) -> list[dict]:
    from shapes import stress_pairs

    rows = []
    for seed in seeds:
        for pair in stress_pairs(seed=seed, detail=1):
            t = time.perf_counter()
            made = ws.make_cage(pair.cage, handles=handles, device=device)
            inside, _ = ws.classify_points(made.cage, pair.cage_vertices, device=device)
            binding = ws.bind(pair.cage, made.cage, resolution=32, device=device)
            rows.append(dict(shape=pair.name, seed=seed, handles=made.cage.n_handles, seconds=time.perf_counter() - t,
                             inside=float(inside.mean()), mean_distance=made.distance[0],
                             max_distance=made.distance[1], pu=binding.stats.partition_of_unity_error,
                             lp=binding.stats.linear_precision_error, notes=made.notes))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", default="arm,smpl,ogre")
    parser.add_argument("--scales", default="0.5,1,2")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--device", default=None)
    parser.add_argument("--synthetic", default="", help="seeds of stress_pairs, e.g. 0,1 (default: none)")
    parser.add_argument("--synthetic-handles", type=int, default=40)
    parser.add_argument("--meshes", nargs="*", default=[], help="mesh files without an artist's cage")
    parser.add_argument("--mesh-handles", type=int, default=None,
                        help="the handles asked for the --meshes (default: chosen from each one's shape)")
    parser.add_argument("--artist", nargs=3, action="append", default=[], metavar=("MESH", "CAGE", "POSES"),
                        help="another pair with an artist's cage: its mesh, cage and posed cage (or .npy of frames)")
    parser.add_argument("--offsets", default=None,
                        help="offsets (fractions of the diagonal) to make each pair's cages at, e.g. "
                             "0.019,0.0195,0.02,0.0205,0.021: how much the expression moves with small changes of the "
                             "cage, with a summary per pair and scale (default: the default offset only)")
    parser.add_argument("--volume-cells", type=int, default=96,
                        help="cells along the longest side of the grid the volumes are counted on (default 96)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    device, device_label = select_device(args.device)
    warnings.simplefilter("ignore")
    from shapes import latitude_longitude_sphere

    ws.make_cage(latitude_longitude_sphere(12, 16), handles=60, device=device)  # compile the kernels
    offsets = [float(x) for x in args.offsets.split(",")] if args.offsets else [None]
    scales = [float(x) for x in args.scales.split(",")]
    rows = []
    for name in filter(None, args.pairs.split(",")):
        rows += measure(name, scales, device, args.resolution, offsets, cells=args.volume_cells)
    for files in args.artist:
        name = Path(files[0]).stem
        while name in {row["pair"] for row in rows}:  # each pair's rows and summary under a name of its own
            name += "'"
        rows += measure(name, scales, device, args.resolution, offsets, files=files, cells=args.volume_cells)

    def pct(x):
        return "" if x is None else f"{100 * x:.2f}"

    print(f"device: {device_label}; the pairs' bindings at n = {args.resolution}, the synthetic shapes' at n = 32; "
          "distances and errors in % of the mesh's diagonal")
    if rows:
        print(markdown_table(
            ["pair", "cage", "asked", "handles", "s", "inside", "crossing", "dist mean", "dist max", "vol between %",
             "RMS", "max", "PU", "LP", "reduction"],
            [[r["pair"], r["cage"], r["asked"], r["handles"], "" if r["seconds"] is None else f"{r['seconds']:.2f}",
              f"{r['inside']:.4f}", r["crossing"], pct(r["mean_distance"]), pct(r["max_distance"]),
              f"{100 * r['volume_between']:.0f}", f"{100 * r['rms']:.3f}", f"{100 * r['max']:.2f}", f"{r['pu']:.1e}",
              f"{r['lp']:.1e}", f"{100 * r['reduction']:.1f}%"] for r in rows]))
    if len(offsets) > 1 and rows:
        print(markdown_table(["pair", "cage", "offsets", "RMS mean", "RMS min-max", "max mean", "max min-max"],
                             spread(rows)))
    shapes = synthetic([int(x) for x in filter(None, args.synthetic.split(","))], args.synthetic_handles, device)
    if shapes:
        print(markdown_table(
            ["shape", "seed", "handles", "s (make + bind)", "inside", "dist mean", "dist max", "PU", "LP", "notes"],
            [[r["shape"], r["seed"], r["handles"], f"{r['seconds']:.2f}", f"{r['inside']:.4f}", pct(r["mean_distance"]),
              pct(r["max_distance"]), f"{r['pu']:.1e}", f"{r['lp']:.1e}", len(r["notes"])] for r in shapes]))
    made = meshes(args.meshes, args.mesh_handles, device, args.resolution)
    if made:
        print(markdown_table(
            ["mesh", "vertices", "asked", "handles", "offset %", "s", "inside", "crossing", "dist mean", "dist max",
             "PU", "LP", "notes"],
            [[r["mesh"], r["vertices"], f"{r['asked']}{' (chosen)' if r['chosen'] else ''}", r["handles"],
              pct(r["offset"]), f"{r['seconds']:.2f}", f"{r['inside']:.4f}", r["crossing"], pct(r["mean_distance"]),
              pct(r["max_distance"]), f"{r['pu']:.1e}", f"{r['lp']:.1e}", len(r["notes"])] for r in made]))
    if args.json:
        Path(args.json).write_text(json.dumps({"pairs": rows, "synthetic": shapes, "meshes": made}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
