"""What each command does, once its arguments are parsed (:mod:`warp_stokes.cli` parses them): checks of the
outputs before any work, then the library's functions. Heavy modules are imported inside the functions."""

from __future__ import annotations

import importlib.util
import os
import sys
import time
import warnings

__all__ = ["format_stats", "listed", "announce_compilation", "cage_command", "bind_command",
           "deform_command", "animate_command", "encode_command", "sweep_command", "show_command", "batch_command"]


def _resolution_choice(choice) -> str:
    """"; resolution 70, auto: ..." for the bind's table; nothing for a number the user gave."""
    if choice is None or choice.requested != "auto" or choice.chosen is None:
        return ""
    why = ("" if choice.needed <= choice.chosen and choice.chosen == 64 else
           f": the cage's folded edges need {choice.needed}"
           + (f", capped at {choice.cap} on this device" if choice.needed > choice.chosen else ""))
    return f"; resolution {choice.chosen}, auto{why}"


def format_stats(stats) -> str:
    """A binding's stats (:class:`warp_stokes.binding.stats.BindStats`) as a short two-column table."""
    seconds = ("seconds", ", ".join(f"{k} {v:.2f}" for k, v in stats.seconds.items()))
    exactness = [("partition of unity", f"max |sum w - 1| = {stats.partition_of_unity_error:.2e}"),
                 ("linear precision", f"max |W C - P| = {stats.linear_precision_error:.2e} x diagonal")]
    if stats.grid is None:  # mean value coordinates: no grid, no solve
        rows = [("device", stats.device), ("method", "mean value coordinates at the vertices (no grid)"),
                ("handles", str(stats.handles)),
                ("vertices", f"{stats.vertices} ({stats.vertices_outside_cage} outside the cage)"),
                *exactness, seconds]
    else:
        grid, solver = stats.grid, stats.solver
        rows = [
            ("device", stats.device),
            ("method", {"harmonic": "harmonic coordinates (7-point Laplace)"}.get(
                stats.method, "Stokes coordinates (biharmonic)")),
            ("grid", " x ".join(str(s) for s in grid.shape) + f"  (h = {grid.spacing:.4g}"
             + _resolution_choice(stats.resolution) + ")"),
            ("nodes", f"{grid.interior_nodes} interior, {grid.ring_nodes} ring"
             + (f" ({grid.cut_off_nodes} inside, cut off by thin wedges of the cage)" if grid.cut_off_nodes else "")
             + f", {grid.band_nodes} band"),
            ("handles", str(stats.handles)),
            ("vertices", f"{stats.vertices} ({stats.vertices_outside_cage} outside the cage, "
                         f"{stats.vertices_beyond_band} beyond the band)"),
            ("solver", f"{solver.preconditioner}, {len(solver.levels)} level(s), {solver.chunks} chunk(s)"
             + (f" on {solver.threads} threads" if solver.threads > 1 else "") + ", "
             f"{solver.iterations} iterations, residual {solver.residual:.2e}, "
             + ("converged" if solver.converged else "NOT converged")
             + (f" (after {len(solver.recoveries)} fault(s) of its preconditioner, with "
                f"{solver.preconditioners[-1]})" if solver.recoveries else "")),
            ("memory", f"{stats.memory_estimate_bytes / 2**20:.0f} MiB (estimate)"),
            *exactness, seconds,
        ]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def listed(items: list, most: int = 6) -> str:
    """``items`` joined by commas, the first ``most`` of a longer list and how many more: one short line.

    Examples
    --------
    >>> listed(["a", "b"]), listed([str(k) for k in range(9)], most=3)
    ('a, b', '0, 1, 2 and 6 more')
    """
    shown = ", ".join(items[:most])
    return shown if len(items) <= most else f"{shown} and {len(items) - most} more"


def announce_compilation(device, harmonic: bool = False) -> None:
    """One line on stderr before a first run's kernel compilation (see
    :func:`warp_stokes.kernel_cache.announce_compilation`)."""
    from warp_stokes.device import Backend
    from warp_stokes.kernel_cache import announce_compilation as announce

    announce(Backend.of(device).device, harmonic=harmonic)


def cage_command(args) -> int:
    import warp_stokes as ws
    from warp_stokes.io.inputs import inputs_of
    from warp_stokes.io.mesh_out import write_cage_file
    from warp_stokes.io.outputs import writing
    from warp_stokes.io.scene import is_usd

    ext = os.path.splitext(args.output)[1].lower().lstrip(".")
    layer = ext in ("usd", "usda", "usdc")
    if layer and not is_usd(args.mesh):
        raise ws.WarpStokesError(f"{args.output}: a cage layer goes over a USD asset, and {args.mesh} is not one; "
                                 "write obj, ply or off")
    if not layer and ext not in ("obj", "ply", "off"):  # formats that keep the handles' order (STL: a soup)
        raise ws.WarpStokesError(f"{args.output}: unsupported cage format {ext!r} (use obj, ply or off, or usd, "
                                 "usda or usdc for a layer over a USD asset)")
    if args.cage_prim is not None and not layer:
        raise ws.WarpStokesError("--cage-prim names the cage's prim in a USD layer (-o CAGE.usda)")
    with writing([args.output], inputs_of(args.mesh, error=ws.MeshError)):
        if layer:
            from warp_stokes.io.usd.cage_layer import check_cage_layer, write_cage_layer

            prim = check_cage_layer(args.output, args.mesh, args.cage_prim)
        made = ws.make_cage(args.mesh, handles=args.handles, offset=args.offset, device=args.device,
                            mesh_prims=args.mesh_prim)
        if layer:
            write_cage_layer(args.output, args.mesh, made.cage.vertices, made.cage.faces, prim)
        else:
            write_cage_file(args.output, made.cage.vertices, made.cage.faces)
    for note in made.notes:
        print(f"note: {note}")
    print(made.summary())
    print(f"wrote {args.output}" + (f": the cage is its prim {prim}, over {args.mesh}" if layer else ""))
    return 0


def made_cage_path(binding_path: str) -> str:
    """Where ``bind MESH auto -o B.npz`` writes the cage it made: ``B.cage.obj`` beside the binding."""
    return os.path.splitext(binding_path)[0] + ".cage.obj"


def bind_command(args) -> int:
    import warp_stokes as ws
    from warp_stokes.io.inputs import inputs_of
    from warp_stokes.io.mesh_out import write_cage_file
    from warp_stokes.io.outputs import writing

    if not args.output.lower().endswith(".npz"):  # a binding under another format's name misleads every reader
        raise ws.WarpStokesError(f"{args.output}: a binding is written as .npz")
    made_cage = made_cage_path(args.output) if args.cage == "auto" else None
    if made_cage is None and (args.handles is not None or args.offset is not None):
        raise ws.WarpStokesError("--handles and --offset shape a made cage: give the cage as auto")
    if made_cage is not None and args.cage_prim is not None:
        raise ws.WarpStokesError(f"cage 'auto' and a cage prim ({args.cage_prim}): give one of them")
    from warp_stokes.binding.spread import driver_device, spread_devices

    spread = spread_devices(args.device)
    outputs = ([made_cage] if made_cage is not None else []) + [args.output]  # the cage renamed first
    with writing(outputs, inputs_of(args.mesh, args.cage, error=ws.MeshError)):
        if spread is None:  # spread: the Ray workers compile, on their devices
            announce_compilation(args.device, harmonic=args.method == "harmonic")
        cage = args.cage
        if made_cage is not None and (args.handles is not None or args.offset is not None):
            from warp_stokes.io.scene import load_scene

            surface = load_scene(args.mesh, mesh_prims=args.mesh_prim, rest_time=args.rest_time,
                                 looks=False).surface()
            cage = ws.make_cage(surface, handles=args.handles, offset=args.offset,
                                device=args.device if spread is None else driver_device(spread))
        budget = None if args.memory_gb is None else args.memory_gb * 2**30
        from .progress import ProgressLine

        with ProgressLine(os.path.basename(args.mesh), enabled=False if args.quiet else None) as progress:
            binding = ws.bind(args.mesh, cage, resolution=args.resolution, device=args.device, tol=args.tol,
                              max_iterations=args.max_iterations, solver=args.solver, memory_budget=budget,
                              boundary=args.boundary, sampling=args.sampling, cage_prim=args.cage_prim,
                              mesh_prims=args.mesh_prim, rest_time=args.rest_time, method=args.method,
                              progress=progress, threads=args.threads)
        if made_cage is not None:
            write_cage_file(made_cage, binding.cage_vertices, binding.cage_faces)
        binding.save(args.output)
    print(format_stats(binding.stats))
    if made_cage is not None:
        record = binding.stats.made_cage
        print(f"made a cage of {record['handles']} handles: {made_cage}")
    if len(binding.parts) > 1:
        print(f"{len(binding.parts)} meshes: " + listed([f"{p['path']} ({p['vertices']})" for p in binding.parts]))
    print(f"wrote {args.output}")
    if not binding.stats.converged:
        stats = binding.stats
        print(f"warp-stokes: error: the solver did not reach tol {args.tol:g} (relative residual "
              f"{stats.solver.residual:.2g}); {args.output} holds weights with partition of unity within "
              f"{stats.partition_of_unity_error:.2g} and linear precision within "
              f"{stats.linear_precision_error:.2g} of the diagonal", file=sys.stderr)
        return 1
    return 0


def deform_command(args) -> int:
    import warp_stokes as ws
    from warp_stokes.io.inputs import inputs_of
    from warp_stokes.io.mesh_out import MESH_FORMATS, write_mesh_file
    from warp_stokes.io.outputs import writing

    ext = os.path.splitext(args.output)[1].lower().lstrip(".")
    if ext not in MESH_FORMATS:
        raise ws.WarpStokesError(f"{args.output}: unsupported mesh format {ext!r} (use obj, ply, off, stl or glb)")
    with writing([args.output], inputs_of(args.binding, args.cage, error=ws.BindingError)):
        binding = ws.load_binding(args.binding, device=args.device)
        if len(binding.mesh_faces) == 0 and ext in ("stl", "glb"):  # they keep triangles only
            raise ws.WarpStokesError(f"{args.output}: the bound mesh has no faces (a point set), which {ext} cannot "
                                     "hold; write obj, ply or off")
        vertices = binding.deform(pose_argument(args.cage, binding.n_handles))
        if ext == "glb" and importlib.util.find_spec("pygltflib") is not None:
            from warp_stokes.io.gltf import write_gltf_mesh  # parts, UVs and materials, as animate's glTF has them

            write_gltf_mesh(args.output, ".glb", binding, vertices)
        else:
            if ext == "glb" and binding.looks is not None:
                warnings.warn(f"{args.output}: written without the mesh's parts, UVs and materials, which need "
                              "pygltflib: pip install 'warp-stokes[gltf]'", stacklevel=2)
            write_mesh_file(args.output, vertices, binding.mesh_faces)
    print(f"wrote {args.output} ({len(vertices)} vertices)")
    return 0


def pose_argument(source: str, n_handles: int):
    """A deformed cage file, or plain handle positions: a .npy array of shape (L, 3)."""
    from warp_stokes.errors import BindingError
    from warp_stokes.io.door import read_numpy
    from warp_stokes.io.load import finite_coordinates
    from warp_stokes.io.poses import numeric

    if not source.lower().endswith(".npy"):
        return source
    positions = read_numpy(source, BindingError, "positions")
    if isinstance(positions, dict):
        raise BindingError(f"{source}: an archive, not a .npy array of positions")
    positions = numeric(positions, source, "the positions")
    if positions.shape != (n_handles, 3):
        raise BindingError(f"{source}: positions of shape {positions.shape}; the bound cage needs ({n_handles}, 3)")
    return finite_coordinates(positions, source, "position", BindingError)


def animate_command(args) -> int:
    import warp_stokes as ws
    from warp_stokes.io.inputs import inputs_of
    from warp_stokes.io.outputs import writing

    keyed = args.key_frames is not None or args.inbetween is not None
    skinned = args.skeleton or os.path.splitext(args.output)[1].lower() in (".glb", ".gltf")
    skin_options = [name for name, value in (("--influences", args.influences), ("--non-negative", args.non_negative),
                                             ("--max-error", args.max_error)) if value not in (None, False)]
    if skin_options and not skinned:
        raise ws.WarpStokesError(f"{', '.join(skin_options)}: for a skin; add --skeleton (or write .glb / .gltf)")
    if skinned and args.with_weights:
        raise ws.WarpStokesError("--with-weights: a skin carries its weights as joint weights already")
    if args.interpolation is not None and not keyed:
        raise ws.WarpStokesError("--interpolation needs --key-frames or --inbetween (without them the poses are "
                                 "written as they are)")
    with writing([args.output], inputs_of(args.binding, args.poses, args.asset, error=ws.BindingError)):
        binding = ws.load_binding(args.binding, device=args.device)
        poses = ws.load_poses(args.poses, binding.cage_faces, binding.n_handles, binding.cage_source_index,
                              cage_prim=args.cage_prim)
        if args.key_frames is not None and len(args.key_frames) != len(poses.frames):
            raise ws.WarpStokesError(f"--key-frames: {len(args.key_frames)} frame numbers for {len(poses.frames)} "
                                     f"poses in {poses.name}; give one per pose")
        if keyed:  # the poses are keys: the frames between them are interpolated
            poses = ws.inbetween(poses, args.key_frames, args.inbetween, args.interpolation or "linear")
        if skinned:
            report = ws.write_skin(args.output, binding, poses, influences=args.influences,
                                   non_negative=True if args.non_negative else None, max_error=args.max_error,
                                   fps=args.fps, with_cage=args.with_cage, up_axis=args.up_axis,
                                   meters_per_unit=args.meters_per_unit, asset=args.asset)
        else:
            ws.write_animation(args.output, binding, poses, fps=args.fps, with_cage=args.with_cage,
                               with_weights=args.with_weights, up_axis=args.up_axis,
                               meters_per_unit=args.meters_per_unit, asset=args.asset)
    if skinned:
        print(report)
        return 0
    from warp_stokes.io.usd.common import animation_rate

    asset_rate = None
    if binding.asset is not None:  # the layer's rate and place, as its writer chose them
        from warp_stokes.io.usd.layer import asset_context

        asset_path, metadata = asset_context(args.output, binding, args.asset, None, None)
        asset_rate = metadata["time_codes_per_second"]
        form = f"a layer over {os.path.relpath(asset_path, os.path.dirname(os.path.abspath(args.output)))}"
    else:
        form = "a stage"
    print(f"wrote {args.output} ({form}): {len(poses.frames)} frames ({poses.frames.min():g} to "
          f"{poses.frames.max():g}) at {animation_rate(args.fps, poses, asset_rate):g} fps, {binding.n_vertices} "
          f"vertices in {len(binding.parts)} mesh(es)")
    return 0


def encode_command(args) -> int:
    import numpy as np

    import warp_stokes as ws
    from warp_stokes.binding.encode import encode_poses
    from warp_stokes.io.frames import load_mesh_frames
    from warp_stokes.io.inputs import inputs_of
    from warp_stokes.io.outputs import atomic_output, writing
    from warp_stokes.io.usd import write_cage_poses

    ext = os.path.splitext(args.output)[1].lower()
    if ext not in (".npy", ".usd", ".usda", ".usdc"):
        raise ws.WarpStokesError(f"{args.output}: the poses are written as .npy or USD (.usd, .usda, .usdc)")
    if args.resolution is not None and args.binding != "auto":
        raise ws.WarpStokesError("--resolution is the resolution of the bind 'encode auto' makes; a binding given "
                                 "has its own")
    made = made_beside(args.output) if args.binding == "auto" else ()
    # with a cage made: the cage, its binding and the poses renamed together, once the frames are encoded
    with writing([*made, args.output], inputs_of(args.binding, args.frames, error=ws.BindingError)):
        if args.binding == "auto":
            binding = _bind_first_frame(args, *made)
        else:
            binding = ws.load_binding(args.binding, device=args.device)
        prims = args.mesh_prim or ([p["path"] for p in binding.parts] if binding.asset else None)
        frames = load_mesh_frames(args.frames, binding.mesh_faces, binding.n_vertices, prims=prims,
                                  animation=args.animation, fps=args.fps)
        poses, rms, largest = encode_poses(binding, frames, smoothness=args.smooth, return_max=True)
        if ext == ".npy":
            with atomic_output(args.output) as tmp, open(tmp, "wb") as fh:
                np.save(fh, poses.positions)
        else:
            write_cage_poses(args.output, binding.cage_vertices, binding.cage_faces, poses)
    if made:
        record = binding.stats.made_cage
        print(f"made a cage of {record['handles']} handles: {made[0]}; bound at n = "
              f"{binding.settings['resolution']}: {made[1]}")
    worst, farthest = int(np.argmax(rms)), int(np.argmax(largest))
    print(f"wrote {args.output}: {len(rms)} cage poses of {frames.name}; RMS error over the cage's diagonal: mean "
          f"{rms.mean():.2e}, max {rms[worst]:.2e} (frame {poses.frames[worst]:g}); largest vertex error "
          f"{largest[farthest]:.2e} (frame {poses.frames[farthest]:g})")
    return 0


def made_beside(output: str) -> tuple[str, str]:
    """Where ``encode auto FRAMES -o POSES`` writes the cage it made and its binding: beside the poses, as
    ``POSES.cage.obj`` and ``POSES.binding.npz`` (the stem of the poses' name)."""
    stem = os.path.splitext(output)[0]
    return stem + ".cage.obj", stem + ".binding.npz"


def _bind_first_frame(args, cage_path: str, binding_path: str):
    """For ``encode auto FRAMES``: the first frame of the sequence bound to a cage made for it; the cage and the
    binding written (in the command's group of outputs) beside the poses."""
    import warp_stokes as ws
    from warp_stokes.io.mesh_out import write_cage_file
    from warp_stokes.io.naming import natural_key
    from warp_stokes.io.scene import is_usd

    frames = args.frames
    if os.path.isdir(frames):
        names = sorted((f for f in os.listdir(frames) if f.lower().endswith(".obj")), key=natural_key)
        if not names:
            raise ws.BindingError(f"{frames}: the folder has no .obj frames")
        first = os.path.join(frames, names[0])
    elif is_usd(frames):
        first = frames  # its meshes at the earliest time sample (a UsdSkel asset's: its rest points)
    elif frames.lower().endswith((".glb", ".gltf")):
        first = frames  # its meshes at rest: the pose its skin is bound in
    else:
        raise ws.WarpStokesError(f"{frames}: 'encode auto' makes the cage around the first frame's surface: give a "
                                 "folder of OBJ frames, a USD file or a rigged glTF/GLB (an array of positions has no "
                                 "faces)")
    binding = ws.bind(first, "auto", device=args.device, mesh_prims=args.mesh_prim,
                      resolution=args.resolution or "auto")
    write_cage_file(cage_path, binding.cage_vertices, binding.cage_faces)
    binding.save(binding_path)
    return binding


def sweep_command(args) -> int:
    from warp_stokes.device import Backend
    from warp_stokes.errors import WarpStokesError
    from warp_stokes.geometry.cage import check_cage
    from warp_stokes.io.inputs import inputs_of
    from warp_stokes.io.outputs import output_folder, writing
    from warp_stokes.sweep import format_sweep, plot_sweep, sweep, write_sweep

    device = Backend.of(args.device)
    names = ("sweep.csv", "sweep.json", "convergence.png", "cost.png")
    with output_folder(args.output) as folder, writing([os.path.join(folder, n) for n in names],
                                                       inputs_of(args.mesh, args.cage, args.pose)):
        announce_compilation(device, harmonic="harmonic" in args.methods.split(","))
        pose = None
        if args.pose:
            pose = pose_argument(args.pose, check_cage(args.cage).n_handles)
        rows = sweep(args.mesh, args.cage, args.resolutions, methods=args.methods.split(","), pose=pose,
                     device=device, tol=args.tol, threads=args.threads)
        csv_path, json_path = write_sweep(rows, folder)
        pictures = None
        if any(r["method"] != "mvc" for r in rows) and len(args.resolutions) > 1:
            try:
                pictures = plot_sweep(rows, folder)
            except WarpStokesError as exc:  # matplotlib is an optional extra: the table stands without the pictures
                print(f"no pictures: {exc}", file=sys.stderr)
    print(format_sweep(rows))
    print(f"wrote {csv_path} and {json_path}")
    if pictures is not None:
        print(f"drew {pictures[0]} and {pictures[1]}")
    failed = [r for r in rows if r.get("error")]
    for r in failed:
        print(f"warp-stokes: error: {r['method']} at resolution {r['resolution']}: {r['error']}", file=sys.stderr)
    return 1 if failed else 0


def show_command(args) -> int:
    from warp_stokes.errors import WarpStokesError

    if (args.handle is None) == (args.pose is None and args.error is None and not args.with_cage):
        raise WarpStokesError("give --handle L (a weight slice) or --pose/--error/--with-cage (the mesh), not both or "
                              "neither")
    if args.handle is None and args.slice is not None:
        raise WarpStokesError("--slice goes with --handle")
    if args.handle is not None and args.view is not None:
        raise WarpStokesError("--view goes with --pose, --error or --with-cage")
    if not args.output.lower().endswith(".png"):
        raise WarpStokesError(f"{args.output}: the picture is written as .png")
    import numpy as np

    import warp_stokes as ws
    from warp_stokes.io.inputs import inputs_of
    from warp_stokes.io.outputs import writing
    from warp_stokes.show import show_mesh, show_weights

    with writing([args.output], inputs_of(args.binding, args.pose, args.error)):
        binding = ws.load_binding(args.binding, device=args.device)
        if args.handle is not None:
            if args.handle >= binding.n_handles:
                raise WarpStokesError(f"--handle {args.handle}: the binding has handles 0 to {binding.n_handles - 1}")
            axis, fraction = args.slice or ("z", 0.5)
            announce_compilation(args.device)
            s = show_weights(binding, args.handle, args.output, axis, fraction, device=args.device)
        else:
            pose = None if args.pose is None else pose_argument(args.pose, binding.n_handles)
            drawn = show_mesh(binding, args.output, pose=pose, reference=args.error, view=args.view or "front",
                              with_cage=args.with_cage)
    if args.handle is not None:
        values = s.image[~np.isnan(s.image)]
        where = f"handle {args.handle} ({s.method}) on {axis} = {fraction:g} of the cage ({axis} = {s.position:.6g})"
        if values.size:
            print(f"wrote {args.output}: {where}: weights {values.min():.6g} to {values.max():.6g} at {values.size} "
                  f"{'pixels' if s.resolution is None else 'nodes'} inside the cage")
        else:
            print(f"wrote {args.output}: {where}: the plane misses the cage's inside")
        return 0
    cage = f" and the cage's {drawn['cage_edges']} edges" if args.with_cage else ""
    if drawn["range"] is None:
        print(f"wrote {args.output}: {len(drawn['values'])} triangles{cage}")
    else:
        from warp_stokes.show.mesh import COLOUR_PERCENTILE

        print(f"wrote {args.output}: {len(drawn['values'])} triangles{cage}, {drawn['label']} coloured from "
              f"{drawn['range'][0]:.6g} to {drawn['range'][1]:.6g} (the {COLOUR_PERCENTILE}th percentile; the largest "
              f"{drawn['max']:.6g})")
    return 0


def batch_command(args) -> int:
    from warp_stokes.batch import format_summary, pace, run_batch

    results = run_batch(args.manifest, args.output, force=args.force, device=args.device, workers=args.workers,
                        ray_address=args.ray_address)
    print(format_summary(results))
    timing = pace(results, process_started())
    if timing:
        print(timing)
    failed = sum(r.status == "failed" for r in results)
    short = sum(r.status == "not converged" for r in results)
    print(f"{len(results) - failed} of {len(results)} assets done, {failed} failed"
          + (f", {short} written without reaching the solver's tolerance" if short else "")
          + f"; summary in {os.path.join(args.output, 'summary.json')}")
    return 1 if failed or short else 0


def edit_command(args) -> int:
    import time

    from warp_stokes.edit.server import require_viser

    require_viser()  # before any work
    import warp_stokes as ws
    from warp_stokes.edit import CageEditor
    from warp_stokes.edit.server import EditorServer
    from warp_stokes.io.outputs import check_output_target

    from warp_stokes.io.inputs import inputs_of

    output = args.output or "edited.npz"
    if os.path.splitext(output)[1].lower() not in (".npy", ".npz", ".usd", ".usda", ".usdc", ".glb", ".gltf"):
        raise ws.WarpStokesError(f"{output}: the editor saves poses as .npy or .npz, the mesh as USD (.usd, .usda, "
                                 ".usdc) or a glTF skin (.glb, .gltf)")
    check_output_target(output, inputs_of(args.binding, args.poses, error=ws.BindingError))
    _check_listen(args.host, args.port)
    binding = ws.load_binding(args.binding, device="cpu")
    poses = None if args.poses is None else ws.load_poses(args.poses, binding.cage_faces, binding.n_handles,
                                                           binding.cage_source_index, cage_prim=args.cage_prim)
    editor = CageEditor(binding, poses, scheme=args.scheme, interpolation=args.interpolation)
    editor.binding_path, editor.poses_path = args.binding, args.poses  # a save never replaces either
    server = EditorServer(editor, host=args.host, port=args.port, output=output)
    where = "" if args.host in ("127.0.0.1", "localhost", "::1") else " (reachable from other machines)"
    print(f"editing {args.binding} ({binding.n_vertices} vertices, {binding.n_handles} handles) at {server.url}"
          f"{where}; the page's Save writes {output}; Ctrl-C stops", flush=True)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:  # how an editor is left: not an error
        unsaved = editor.unsaved
        print("stopped" + (f"; {unsaved} edit(s) since the last save were not written" if unsaved else ""))
        return 0
    finally:
        server.stop()


def _check_listen(host: str, port: int) -> None:
    """The address can be listened on (a name that resolves, an address of this machine): else one line, before
    the server starts (viser would wait for it for ever). A port taken is left to the server, which takes the next."""
    import socket

    from warp_stokes.errors import WarpStokesError

    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise WarpStokesError(f"--host {host}: not an address or a name this machine resolves ({exc})") from None
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        try:
            probe.bind((address[0], 0))  # an ephemeral port: whether the address is this machine's
        except OSError as exc:
            raise WarpStokesError(f"--host {host}: this machine cannot listen there ({exc.strerror or exc})") from None


def process_started() -> float:
    """When this process started, in seconds since the epoch (Linux's ``/proc``: the command's start, Python's
    included); elsewhere, or where ``/proc`` gives a time that cannot be this process's start, when this module was
    imported."""
    try:
        with open("/proc/self/stat", encoding="ascii") as fh:
            ticks = int(fh.read().rsplit(")", 1)[1].split()[19])  # field 22, starttime: clock ticks after boot
        with open("/proc/uptime", encoding="ascii") as fh:  # seconds after boot, to the hundredth (btime: whole ones)
            now, uptime = time.time(), float(fh.read().split()[0])
        started = now - uptime + ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return _IMPORTED
    # a container may show its own uptime beside the host's start ticks: a start after this module's import, or
    # long before, is not this process's
    return started if _IMPORTED - 600 <= started <= _IMPORTED else _IMPORTED


_IMPORTED = time.time()
