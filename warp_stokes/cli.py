"""Command line: ``warp-stokes bind MESH CAGE -o BINDING.npz`` and ``warp-stokes deform BINDING CAGE -o OUT``."""

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


def _bind(args) -> int:
    import warp_stokes as ws

    budget = None if args.memory_gb is None else int(args.memory_gb * 2**30)
    binding = ws.bind(args.mesh, args.cage, resolution=args.resolution, device=args.device, tol=args.tol,
                      max_iterations=args.max_iterations, solver=args.solver, memory_budget=budget)
    binding.save(args.output)
    print(format_stats(binding.stats))
    print(f"wrote {args.output}")
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
    folder = os.path.dirname(os.path.abspath(args.output))
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix="." + ext, dir=folder)
    os.close(fd)
    try:
        mesh.export(tmp, file_type=ext)
        os.replace(tmp, args.output)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    print(f"wrote {args.output} ({len(vertices)} vertices)")
    return 0


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
    p.set_defaults(run=_bind)

    p = sub.add_parser("deform", help="deform the bound mesh with a deformed cage and write it")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("cage", help="deformed cage with the bound cage's topology")
    p.add_argument("-o", "--output", required=True, help="mesh file to write (obj, ply, off, stl, glb)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=_deform)

    args = parser.parse_args(argv)
    warnings.showwarning = _show_warning
    from warp_stokes.errors import WarpStokesError

    try:
        return args.run(args)
    except (WarpStokesError, OSError) as exc:
        print(f"warp-stokes: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
