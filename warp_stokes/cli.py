"""Command line: ``warp-stokes bind | deform | animate | batch``."""

from __future__ import annotations

import argparse
import os
import sys
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


def _bind(args) -> int:
    import warp_stokes as ws

    budget = None if args.memory_gb is None else args.memory_gb * 2**30
    binding = ws.bind(args.mesh, args.cage, resolution=args.resolution, device=args.device, tol=args.tol,
                      max_iterations=args.max_iterations, solver=args.solver, memory_budget=budget,
                      boundary=args.boundary, sampling=args.sampling)
    binding.save(args.output)
    print(format_stats(binding.stats))
    print(f"wrote {args.output}")
    if not binding.stats["converged"]:
        print(f"warp-stokes: error: the solver did not converge to tol {args.tol:g}; {args.output} holds its last "
              "iterate (raise --max-iterations or --tol)", file=sys.stderr)
        return 1
    return 0


def _deform(args) -> int:
    import trimesh

    import warp_stokes as ws

    binding = ws.load_binding(args.binding, device=args.device)
    vertices = binding.deform(args.cage)
    mesh = trimesh.Trimesh(vertices=vertices, faces=binding.mesh_faces, process=False)
    ext = os.path.splitext(args.output)[1].lower().lstrip(".")
    if ext not in ("obj", "ply", "off", "stl", "glb"):
        raise ws.WarpStokesError(f"{args.output}: unsupported mesh format {ext!r} (use obj, ply, off, stl or glb)")
    from warp_stokes.files import atomic_output

    with atomic_output(args.output, "." + ext) as tmp:
        mesh.export(tmp, file_type=ext)
    print(f"wrote {args.output} ({len(vertices)} vertices)")
    return 0


def _animate(args) -> int:
    import warp_stokes as ws

    binding = ws.load_binding(args.binding, device=args.device)
    poses = ws.load_poses(args.poses, binding.cage_faces, binding.n_handles, binding.cage_source_index)
    ws.write_animation(args.output, binding, poses, fps=args.fps, with_cage=args.with_cage,
                       with_weights=args.with_weights, up_axis=args.up_axis, meters_per_unit=args.meters_per_unit)
    print(f"wrote {args.output}: {len(poses.frames)} frames ({poses.frames.min():g} to {poses.frames.max():g}) "
          f"at {args.fps:g} fps, {binding.n_vertices} vertices")
    return 0


def _batch(args) -> int:
    from warp_stokes.batch import format_summary, run_batch

    results = run_batch(args.manifest, args.output, force=args.force, device=args.device)
    print(format_summary(results))
    failed = sum(r.status == "failed" for r in results)
    print(f"{len(results) - failed} of {len(results)} assets done, {failed} failed; "
          f"summary in {os.path.join(args.output, 'summary.json')}")
    return 1 if failed else 0


def main(argv=None) -> int:
    """Entry point of the ``warp-stokes`` command."""
    parser = argparse.ArgumentParser(prog="warp-stokes", description="Stokes cage coordinates with NVIDIA Warp.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("bind", help="compute the weights of a mesh's vertices with respect to a cage")
    p.add_argument("mesh", help="mesh file (OBJ, PLY, OFF, STL, glTF/GLB, ...)")
    p.add_argument("cage", help="closed cage mesh file")
    p.add_argument("-o", "--output", required=True, help="binding file to write (.npz)")
    p.add_argument("--resolution", type=int, default=64, help="grid cells along the cage's longest axis (64)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N (default: CUDA when present, else CPU)")
    p.add_argument("--tol", type=float, default=1e-6, help="solver tolerance (1e-6)")
    p.add_argument("--max-iterations", type=int, default=None, help="solver iteration limit")
    p.add_argument("--solver", choices=["multigrid", "jacobi"], default="multigrid",
                   help="CG preconditioner (multigrid)")
    p.add_argument("--memory-gb", type=float, default=None,
                   help="memory budget in GiB (default: 90%% of free GPU memory, half the free RAM on CPU)")
    p.add_argument("--boundary", choices=["local", "mvc"], default="local",
                   help="boundary data: local to each node's closest cage point (default) or mean value coordinates")
    p.add_argument("--sampling", choices=["hermite", "trilinear"], default="hermite",
                   help="weights at the vertices: C1 tricubic Hermite of values and gradients (default) or trilinear")
    p.set_defaults(run=_bind)

    p = sub.add_parser("deform", help="deform the bound mesh with a deformed cage and write it")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("cage", help="deformed cage with the bound cage's topology")
    p.add_argument("-o", "--output", required=True, help="mesh file to write (obj, ply, off, stl, glb)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=_deform)

    p = sub.add_parser("animate", help="write the bound mesh, deformed by a sequence of cage poses, as animated USD")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("poses", help="cage poses: a folder of OBJ frames, a .npy/.npz array (F, L, 3) or a USD file")
    p.add_argument("-o", "--output", required=True, help="USD file to write (.usd/.usdc binary, .usda text)")
    p.add_argument("--fps", type=float, default=24.0, help="time codes per second (24)")
    p.add_argument("--with-cage", action="store_true", help="also write the animated cage (/Root/Cage)")
    p.add_argument("--with-weights", action="store_true", help="write the weights as a primvar")
    p.add_argument("--up-axis", choices=["Y", "Z"], default="Y", help="stage up axis (Y)")
    p.add_argument("--meters-per-unit", type=float, default=1.0, help="stage metersPerUnit (1.0)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=_animate)

    p = sub.add_parser("batch", help="bind (and animate) every asset of a TOML or JSON manifest")
    p.add_argument("manifest", help="manifest file (.toml or .json); see the README")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--force", action="store_true", help="redo assets whose outputs are up to date")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=_batch)

    args = parser.parse_args(argv)
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
