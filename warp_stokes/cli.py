"""Command line: ``warp-stokes bind | deform | animate | encode | batch | sweep``."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import warnings

__all__ = ["main", "format_stats"]


def format_stats(stats: dict) -> str:
    """The stats of a binding as a short two-column table."""
    sec = stats["seconds"]
    rows = [
        ("device", stats["device"]),
        ("grid", " x ".join(str(s) for s in stats["grid_shape"]) + f"  (h = {stats['spacing']:.4g})"),
        ("nodes", f"{stats['interior_nodes']} interior, {stats['ring_nodes']} ring, {stats['band_nodes']} band"),
        ("handles", str(stats["handles"])),
        ("vertices", f"{stats['vertices']} ({stats['vertices_outside_cage']} outside the cage, "
                     f"{stats['vertices_beyond_band']} beyond the band)"),
        ("solver", f"{stats['solver']}, {len(stats['levels'])} level(s), {stats['chunks']} chunk(s), "
                   f"{stats['iterations']} iterations, residual {stats['residual']:.2e}, "
                   + ("converged" if stats["converged"] else "NOT converged")),
        ("memory", f"{stats['memory_estimate_bytes'] / 2**20:.0f} MiB (estimate)"),
        ("partition of unity", f"max |sum w - 1| = {stats['partition_of_unity_error']:.2e}"),
        ("linear precision", f"max |W C - P| = {stats['linear_precision_error']:.2e} x diagonal"),
        ("seconds", ", ".join(f"{k} {v:.2f}" for k, v in sec.items())),
    ]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print(f"warning: {message}", file=sys.stderr)


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (exit code 2), as every other error of the command."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _number(kind, low=None, high=None, low_open=False):
    """An argparse type: ``kind`` (int or float) within [low, high] (low excluded with ``low_open``)."""

    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if value != value or (low is not None and (value <= low if low_open else value < low)) or (
                high is not None and value > high):
            bound = (f"> {low:g}" if low_open else f">= {low:g}") if low is not None else ""
            bound += (" and " if bound and high is not None else "") + (f"<= {high:g}" if high is not None else "")
            raise argparse.ArgumentTypeError(f"must be {bound}, got {text}")
        return value

    parse.__name__ = kind.__name__  # what argparse names in "invalid int value"
    return parse


def _check_output(path: str, inputs=(), folder: bool = False) -> None:
    """Before any work: the output's folder exists and is writable, the output is not one of the inputs, and it
    is not an existing folder (or, with ``folder``, not an existing file)."""
    from warp_stokes.errors import WarpStokesError

    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise WarpStokesError(f"{path}: the output folder {parent} does not exist")
    try:  # a real file, not os.access: root passes that test in read-only and virtual (/proc) folders
        with tempfile.NamedTemporaryFile(prefix=".tmp-", dir=parent):
            pass
    except OSError as exc:
        raise WarpStokesError(f"{path}: the output folder {parent} takes no new files ({exc.strerror})") from None
    if folder:
        if os.path.exists(path) and not os.path.isdir(path):
            raise WarpStokesError(f"{path}: the output exists and is not a folder")
        if os.path.isdir(path) and not os.access(path, os.W_OK | os.X_OK):
            raise WarpStokesError(f"{path}: the output folder is not writable")
    elif os.path.isdir(path):
        raise WarpStokesError(f"{path}: the output is a folder, not a file")
    for source in inputs:
        if source and os.path.exists(path) and os.path.exists(source) and os.path.samefile(path, source):
            raise WarpStokesError(f"{path}: the output is the input {source}; choose another output name")


def _announce_compilation(device) -> None:
    """One line before a first run's kernel compilation (20-40 s), so that a silent wait is not taken for a hang."""
    from warp_stokes.device import kernels_compiled, resolve_device

    resolved = resolve_device(device)
    if not kernels_compiled(resolved):
        print(f"warp-stokes: compiling the kernels for {resolved.alias} (first run on this machine, 20-40 s; "
              "later runs load them from Warp's cache)", file=sys.stderr, flush=True)


def _bind(args) -> int:
    import warp_stokes as ws

    _check_output(args.output, (args.mesh, args.cage))
    _announce_compilation(args.device)
    budget = None if args.memory_gb is None else args.memory_gb * 2**30
    binding = ws.bind(args.mesh, args.cage, resolution=args.resolution, device=args.device, tol=args.tol,
                      max_iterations=args.max_iterations, solver=args.solver, memory_budget=budget,
                      boundary=args.boundary, sampling=args.sampling, cage_prim=args.cage_prim,
                      mesh_prims=args.mesh_prim, rest_time=args.rest_time)
    binding.save(args.output)
    print(format_stats(binding.stats))
    if len(binding.parts) > 1:
        print(f"{len(binding.parts)} meshes: " + ", ".join(f"{p['path']} ({p['vertices']})" for p in binding.parts))
    print(f"wrote {args.output}")
    if not binding.stats["converged"]:
        print(f"warp-stokes: error: the solver did not converge to tol {args.tol:g}; {args.output} holds its last "
              "iterate (raise --max-iterations or --tol)", file=sys.stderr)
        return 1
    return 0


def _deform(args) -> int:
    import trimesh

    import warp_stokes as ws

    ext = os.path.splitext(args.output)[1].lower().lstrip(".")
    if ext not in ("obj", "ply", "off", "stl", "glb"):
        raise ws.WarpStokesError(f"{args.output}: unsupported mesh format {ext!r} (use obj, ply, off, stl or glb)")
    _check_output(args.output, (args.binding, args.cage))
    binding = ws.load_binding(args.binding, device=args.device)
    vertices = binding.deform(_pose(args.cage, binding.n_handles))
    mesh = trimesh.Trimesh(vertices=vertices, faces=binding.mesh_faces, process=False)
    from warp_stokes.io.files import atomic_output

    with atomic_output(args.output, "." + ext) as tmp:
        mesh.export(tmp, file_type=ext)
    print(f"wrote {args.output} ({len(vertices)} vertices)")
    return 0


def _pose(source: str, n_handles: int):
    """A deformed cage file, or plain handle positions: a .npy array of shape (L, 3)."""
    import numpy as np

    from warp_stokes.errors import BindingError

    if not source.lower().endswith(".npy"):
        return source
    try:
        positions = np.load(source, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise BindingError(f"{source}: not a readable .npy array ({exc})") from None
    if positions.shape != (n_handles, 3):
        raise BindingError(f"{source}: positions of shape {positions.shape}; the bound cage needs ({n_handles}, 3)")
    if not np.isfinite(positions).all():
        raise BindingError(f"{source}: the positions contain NaN or infinite values")
    return positions.astype(np.float64)


def _animate(args) -> int:
    import warp_stokes as ws

    _check_output(args.output, (args.binding, args.poses, args.asset))
    binding = ws.load_binding(args.binding, device=args.device)
    poses = ws.load_poses(args.poses, binding.cage_faces, binding.n_handles, binding.cage_source_index,
                          cage_prim=args.cage_prim)
    ws.write_animation(args.output, binding, poses, fps=args.fps, with_cage=args.with_cage,
                       with_weights=args.with_weights, up_axis=args.up_axis, meters_per_unit=args.meters_per_unit,
                       asset=args.asset)
    from pxr import Usd

    stage = Usd.Stage.Open(args.output)
    form = f"a layer over {stage.GetRootLayer().subLayerPaths[0]}" if binding.asset or args.asset else "a stage"
    print(f"wrote {args.output} ({form}): {len(poses.frames)} frames ({poses.frames.min():g} to "
          f"{poses.frames.max():g}) at {stage.GetTimeCodesPerSecond():g} fps, {binding.n_vertices} vertices in "
          f"{len(binding.parts)} mesh(es)")
    return 0


def _encode(args) -> int:
    import numpy as np

    import warp_stokes as ws
    from warp_stokes.binding.encode import encode_poses
    from warp_stokes.io.files import atomic_output
    from warp_stokes.io.frames import load_mesh_frames
    from warp_stokes.io.usd import write_cage_poses

    ext = os.path.splitext(args.output)[1].lower()
    if ext not in (".npy", ".usd", ".usda", ".usdc"):
        raise ws.WarpStokesError(f"{args.output}: the poses are written as .npy or USD (.usd, .usda, .usdc)")
    _check_output(args.output, (args.binding, args.frames))
    binding = ws.load_binding(args.binding, device="cpu")
    prims = args.mesh_prim or ([p["path"] for p in binding.parts] if binding.asset else None)
    frames = load_mesh_frames(args.frames, binding.mesh_faces, binding.n_vertices, prims=prims)
    poses, rms = encode_poses(binding, frames, smoothness=args.smooth)
    if ext == ".npy":
        with atomic_output(args.output, ext) as tmp, open(tmp, "wb") as fh:
            np.save(fh, poses.positions)
    else:
        write_cage_poses(args.output, binding.cage_vertices, binding.cage_faces, poses)
    worst = int(np.argmax(rms))
    print(f"wrote {args.output}: {len(rms)} cage poses; RMS error over the cage's diagonal: mean {rms.mean():.2e}, "
          f"max {rms[worst]:.2e} (frame {poses.frames[worst]:g})")
    return 0


def _resolutions(text: str) -> list:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of integers") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give resolutions >= 1, e.g. 16,24,32")
    return values


def _sweep(args) -> int:
    from warp_stokes.device import resolve_device
    from warp_stokes.geometry.cage import check_cage
    from warp_stokes.sweep import format_sweep, sweep, write_sweep

    _check_output(args.output, (args.mesh, args.cage), folder=True)
    _announce_compilation(args.device)
    pose = None
    if args.pose:
        pose = _pose(args.pose, check_cage(args.cage).n_handles)
    rows = sweep(args.mesh, args.cage, args.resolutions, methods=args.methods.split(","), pose=pose,
                 device=resolve_device(args.device), tol=args.tol)
    print(format_sweep(rows))
    csv_path, json_path = write_sweep(rows, args.output)
    print(f"wrote {csv_path} and {json_path}")
    return 0


def _batch(args) -> int:
    from warp_stokes.batch import format_summary, run_batch

    _check_output(args.output, (args.manifest,), folder=True)
    if args.workers is None and args.ray_address is None:  # Ray workers compile in their own processes
        _announce_compilation(args.device)
    results = run_batch(args.manifest, args.output, force=args.force, device=args.device, workers=args.workers,
                        ray_address=args.ray_address)
    print(format_summary(results))
    failed = sum(r.status == "failed" for r in results)
    print(f"{len(results) - failed} of {len(results)} assets done, {failed} failed; "
          f"summary in {os.path.join(args.output, 'summary.json')}")
    return 1 if failed else 0


def main(argv=None) -> int:
    """Entry point of the ``warp-stokes`` command: its exit code (0 done, 1 not converged or an asset failed,
    2 bad input or a failed write, 130 interrupted)."""
    try:
        return _main(argv)
    except KeyboardInterrupt:
        # outputs are written under temporary names and renamed when complete: nothing half-written stays
        print("warp-stokes: interrupted; no output was left half-written", file=sys.stderr)
        return 130


def _parser() -> argparse.ArgumentParser:
    """The command line: one subcommand per stage of the data's way (bind, deform, animate) and batches of them."""
    from warp_stokes import __version__

    parser = _Parser(prog="warp-stokes", description="Stokes cage coordinates with NVIDIA Warp.")
    parser.add_argument("--version", action="version", version=f"warp-stokes {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for add in (_add_bind, _add_deform, _add_animate, _add_encode, _add_batch, _add_sweep):
        add(sub)
    return parser


def _add_bind(sub) -> None:
    p = sub.add_parser("bind", help="compute the weights of a mesh's vertices with respect to a cage")
    p.add_argument("mesh", help="mesh file (OBJ, PLY, OFF, STL, glTF/GLB, ...) or a USD asset (all its meshes)")
    p.add_argument("cage", nargs="?", default=None,
                   help="closed cage mesh file, or a USD file with --cage-prim (optional when --cage-prim names a prim "
                        "of the mesh's USD asset)")
    p.add_argument("--cage-prim", default=None, metavar="PATH", help="the cage's mesh prim in the USD stage")
    p.add_argument("--mesh-prim", action="append", default=None, metavar="PATH",
                   help="a mesh prim of the USD asset to bind (repeat for several; default: all but the cage)")
    p.add_argument("--rest-time", type=_number(float), default=None,
                   help="USD time code of the rest pose (default: the cage prim's first time sample)")
    p.add_argument("-o", "--output", required=True, help="binding file to write (.npz)")
    p.add_argument("--resolution", type=_number(int, 1), default=64, help="grid cells along the cage's longest axis (64)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N (default: CUDA when present, else CPU)")
    p.add_argument("--tol", type=_number(float, 0.0, 0.1, low_open=True), default=1e-6, help="solver tolerance (1e-6)")
    p.add_argument("--max-iterations", type=_number(int, 1), default=None, help="solver iteration limit")
    p.add_argument("--solver", choices=["multigrid", "jacobi"], default="multigrid",
                   help="CG preconditioner (multigrid)")
    p.add_argument("--memory-gb", type=_number(float, 0.0, low_open=True), default=None,
                   help="memory budget in GiB (default: 90%% of free GPU memory, half the free RAM on CPU)")
    p.add_argument("--boundary", choices=["local", "mvc"], default="local",
                   help="boundary data: local to each node's closest cage point (default) or mean value coordinates")
    p.add_argument("--sampling", choices=["hermite", "trilinear"], default="hermite",
                   help="weights at the vertices: C1 tricubic Hermite of values and gradients (default) or trilinear")
    p.set_defaults(run=_bind)


def _add_deform(sub) -> None:
    p = sub.add_parser("deform", help="deform the bound mesh with a deformed cage and write it")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("cage", help="deformed cage with the bound cage's topology (faces in any order), or its "
                                "vertex positions as a .npy array of shape (L, 3)")
    p.add_argument("-o", "--output", required=True, help="mesh file to write (obj, ply, off, stl, glb)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=_deform)


def _add_animate(sub) -> None:
    p = sub.add_parser("animate", help="write the bound mesh, deformed by a sequence of cage poses, as animated USD")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("poses", help="cage poses: a folder of OBJ frames, a .npy/.npz array (F, L, 3) or a USD file "
                                 "(one pose per time sample of --cage-prim)")
    p.add_argument("-o", "--output", required=True, help="USD file to write (.usd/.usdc binary, .usda text); for a "
                                                         "binding of a USD asset, a layer over it")
    p.add_argument("--cage-prim", default=None, metavar="PATH",
                   help="the cage's prim in the poses' USD file (default: the first mesh with the cage's point count)")
    p.add_argument("--asset", default=None, help="the bound USD asset, where it is not at the path the binding records")
    p.add_argument("--fps", type=_number(float, 0.0, low_open=True), default=None,
                   help="time codes per second (default: the poses' USD stage's, else 24)")
    p.add_argument("--with-cage", action="store_true", help="also write the animated cage (/Root/Cage)")
    p.add_argument("--with-weights", action="store_true", help="write the weights as a primvar")
    p.add_argument("--up-axis", choices=["Y", "Z"], default=None, help="stage up axis (Y; over an asset, the asset's)")
    p.add_argument("--meters-per-unit", type=_number(float, 0.0, low_open=True), default=None,
                   help="stage metersPerUnit (1.0; over an asset, the asset's)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=_animate)


def _add_encode(sub) -> None:
    p = sub.add_parser("encode", help="the cage poses that best reproduce a sequence of meshes (least squares)")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("frames", help="meshes with the bound mesh's topology: a folder of OBJ frames, a .npy/.npz array "
                                  "(F, V, 3) or a USD file (time samples)")
    p.add_argument("-o", "--output", required=True, help="poses to write: .npy (F, L, 3) or USD (an animated cage)")
    p.add_argument("--smooth", type=_number(float, 0.0), default=0.0,
                   help="weight of each handle's squared change between consecutive frames (0)")
    p.add_argument("--mesh-prim", action="append", default=None, metavar="PATH",
                   help="for USD frames: the mesh prim(s) to read (default: the binding's parts, else the first "
                        "mesh with the bound mesh's point count)")
    p.set_defaults(run=_encode)


def _add_sweep(sub) -> None:
    p = sub.add_parser("sweep", help="bind at several resolutions (and with MVC) and tabulate cost and convergence")
    p.add_argument("mesh", help="mesh file")
    p.add_argument("cage", help="closed cage mesh file")
    p.add_argument("--resolutions", type=_resolutions, required=True, help="comma-separated, e.g. 16,24,32")
    p.add_argument("--methods", default="stokes", help="comma-separated: stokes, mvc (default stokes)")
    p.add_argument("--pose", default=None, help="a deformed cage (file or .npy (L, 3)): adds the conformal "
                                                "distortion's 95th percentile")
    p.add_argument("-o", "--output", required=True, help="folder for sweep.csv and sweep.json")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.add_argument("--tol", type=_number(float, 0.0, 0.1, low_open=True), default=1e-6, help="solver tolerance")
    p.set_defaults(run=_sweep)


def _add_batch(sub) -> None:
    p = sub.add_parser("batch", help="bind (and animate) every asset of a TOML or JSON manifest")
    p.add_argument("manifest", help="manifest file (.toml or .json); see the README")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--force", action="store_true", help="redo assets whose outputs are up to date")
    p.add_argument("--workers", type=_number(int, 1), default=None,
                   help="bind in N Ray worker processes on a local Ray cluster (on a GPU host, default one per GPU); "
                        'needs pip install "warp-stokes[ray]"')
    p.add_argument("--ray-address", default=None, metavar="ADDRESS",
                   help="join this Ray cluster (e.g. auto) instead of starting one")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=_batch)


def _main(argv) -> int:
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a bad argument (one line on stderr already)
        return exc.code if isinstance(exc.code, int) else 2
    from warp_stokes.errors import WarpStokesError

    # warnings are shown once the command has run, so that bad input ends in its one-line error alone
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            rc = args.run(args)
        except (WarpStokesError, OSError) as exc:
            print(f"warp-stokes: error: {exc}", file=sys.stderr)
            return 2

    shown = set()
    for w in caught:
        if str(w.message) not in shown:
            shown.add(str(w.message))
            _show_warning(w.message, w.category, w.filename, w.lineno)
    return rc


if __name__ == "__main__":
    sys.exit(main())
