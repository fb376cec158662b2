"""Does Blender play the Fox's encoded walk within the error the commands print? The rigged glTF Fox is encoded as
cage poses and animated, as a user would (the command line), and each output is imported into an empty Blender
scene, evaluated at several frames and compared with the cage deformation it stands for and with the Fox's own
skinned animation.

    pip install "bpy==4.5.*"          # Blender 4.5 LTS as a Python module: Python 3.11 only, about 370 MB
    pip install -e ".[gltf]"          # the package in the same interpreter (the commands run as its children)
    python benchmarks/check_blender_fox.py                       # the Walk, poses as .npy; --all-frames for every one
    python benchmarks/check_blender_fox.py --poses usda --animation Run

Input: ``../shared/data/fox_gltf/Fox.glb`` (``--fox``; 1,728 vertices, a skin of 24 joints, one textured material,
animations Survey, Walk and Run). The commands, each a child process (``python -m warp_stokes.cli``), in ``--out``:

    warp-stokes encode auto Fox.glb --animation Walk -o fox_walk_poses.npy --device cpu
    warp-stokes animate fox_walk_poses.binding.npz fox_walk_poses.npy -o fox_walk.usda --device cpu
    warp-stokes animate fox_walk_poses.binding.npz fox_walk_poses.npy -o fox_walk.glb --device cpu

``encode auto`` makes a cage for the Fox at rest, binds it (beside the poses: ``.cage.obj``, ``.binding.npz``),
reads the animation's skinned frames and fits a cage pose to each; it prints the fit's RMS error (mean and largest
over the frames) and its largest vertex error, over the *cage's* bounding diagonal. ``animate`` writes baked points
(``.usda``: no error, the points are ``deform``'s) and a glTF skin (8 influences, non-negative: it prints the skin's
largest and RMS distance from ``deform`` over the poses, over the *mesh's* diagonal). Poses written as ``.npy`` hold
the positions alone, so ``animate`` numbers them 1, 2, ... at 24 fps: in Blender the outputs play the Fox's frame k
at frame k + 1, one frame after the input plays it; ``--poses usda`` keeps the animation's times (frame k at k).

Each output, and the input ``Fox.glb`` itself, is imported in a fresh child process of this script
(``bpy.ops.wm.usd_import`` with ``apply_unit_conversion_scale=False`` and ``scale=1``; ``bpy.ops.import_scene.gltf``
with ``disable_bone_shape=True``, the scene's fps set to the file's rate first; for the input the armature's action
is set to the animation's), and its mesh objects are evaluated through the depsgraph at the first, middle and last
pose's frame, and the frame of the largest encoding error (``--all-frames``: every one). The frames are read from the
files: USD time codes are Blender frames; a glTF key at ``t`` seconds is at Blender frame ``t * fps``; both checked
against what Blender keyed (the imported action's keys, the stage's time range).

Spaces (as ``check_blender_skin.py``): Blender is Z-up; a Y-up stage is rotated (x, y, z) -> (x, -z, y) by the
importer, a glTF by the same after the ``CageSkeleton`` node's matrix (identity here). Blender's points are mapped
back, and the mesh data Blender made (times ``matrix_world``) is matched to the file's points it holds: a skin's
rest mesh, the binding's; for baked points (a MeshSequenceCache modifier) the stage's points at its first time code,
which the file holds in the binding's order. In order where Blender kept the order (it did for every file here),
else by nearest position (glTF importers may split vertices at seams).

Reported per file and frame, over the rest mesh's bounding diagonal: the largest and median distance of Blender's
vertices from (a) ``binding.deform(pose)`` (what ``animate`` reports against) and (b) the Fox's own skinned frame
(``warp_stokes.load_frames(Fox.glb, animation=...)``, what the encoding approximates), beside what the commands
printed (encode's figures converted from the cage's diagonal to the mesh's) and the encoding's own error at that
frame (``deform`` against (b), computed here). Expected: (a) within ``animate``'s printed error (baked points about
1e-7), (b) within encode's printed largest vertex error plus that. Below: the materials and images Blender shows
per file (``check_blender_looks.py``'s count: materials on the meshes, those whose Base Color shows an image with
pixels, images with pixels), the printed lines and the importers' warnings.

``bpy`` is a benchmark extra only, never a dependency of the package or its tests.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_common import (FOX, Y_UP_TO_Z_UP, accessor_floats, bpy_missing, cage_skeleton_matrix,  # noqa: E402
                            evaluated_points_at_frames, fcurve_groups, key_frames, materials_shown, nearest_targets,
                            open_in_empty_scene, points_in_blender, print_problem_and_messages, run_cli,
                            usd_stage_to_blender, world_points)
from common import WORK, table_head, table_row  # noqa: E402

#: what encode and animate print (figures over a diagonal)
_ENCODED = re.compile(r"RMS error over the cage's diagonal: mean (\S+), max (\S+) \(frame (\S+)\); largest vertex "
                      r"error (\S+) \(frame (\S+)\)")
_SKIN = re.compile(r"max (\S+), RMS (\S+) of the diagonal")


# ---------------------------------------------------------------------------------------------------------------
# the child: one file in Blender


def _child(path: str, frames: list[float], fps: float, action: str, out: str) -> dict:
    """Import ``path`` into an empty scene (its armature playing ``action`` where one is named), evaluate its mesh
    objects at ``frames`` (Blender frames); write the points (Blender world space) to ``out`` (npz) and return what
    was found: objects, keys, materials and images."""
    import bpy

    scene, result = open_in_empty_scene(path, fps)
    meshes = sorted((o for o in scene.objects if o.type == "MESH" and o.name != "Cage"), key=lambda o: o.name)
    armatures = [o for o in scene.objects if o.type == "ARMATURE"]
    info = dict(result=sorted(result), objects=sorted(f"{o.name} ({o.type})" for o in scene.objects),
                meshes=[o.name for o in meshes], modifiers={o.name: [m.type for m in o.modifiers] for o in meshes},
                scene_fps=scene.render.fps / scene.render.fps_base, frame_range=[scene.frame_start, scene.frame_end],
                actions=sorted(a.name for a in bpy.data.actions), keys=None)
    if armatures:
        arm = armatures[0]
        if action:  # the input: play the named animation (the importer makes an action per glTF animation)
            chosen = [a for a in bpy.data.actions if a.name == action or a.name.startswith(action + "_")]
            if not chosen:
                raise SystemExit(f"no action named {action!r} among {info['actions']}")
            arm.animation_data_create()
            arm.animation_data.action = chosen[0]
            if hasattr(arm.animation_data, "action_slot") and len(getattr(chosen[0], "slots", [])):
                arm.animation_data.action_slot = chosen[0].slots[0]
        playing = arm.animation_data.action if arm.animation_data else None
        info["action"] = playing.name if playing is not None else None
        if playing is not None:
            keys = set()
            for curve in (c for group in fcurve_groups(playing) for c in group):
                # every curve's keys: the Fox's curves are keyed at different frames
                keys.update(np.round(key_frames(curve), 4).tolist())
            info["keys"] = sorted(keys)
    info.update(**materials_shown(meshes), images_in_file=len([i for i in bpy.data.images if i.size[0] > 0]))
    if not meshes:
        np.savez(out)
        return info
    arrays = {"rest": np.concatenate([world_points(o.data.vertices, o.matrix_world) for o in meshes])}
    info["vertices"] = [len(o.data.vertices) for o in meshes]
    arrays.update(evaluated_points_at_frames(scene, meshes, frames))
    np.savez(out, **arrays)
    return info


# ---------------------------------------------------------------------------------------------------------------
# the parent: the commands, then each file in Blender


def _usd_file(path: str) -> tuple[np.ndarray, np.ndarray, float, str]:
    """The expected map from the file's world space to Blender's (the importer rotates a Y-up stage to Z-up; with
    ``apply_unit_conversion_scale=False`` it does not scale), the points' time codes and the stage's rate."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(path)
    conversion, up, mpu = usd_stage_to_blender(stage)
    mesh = next(UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and p.GetName() != "Cage")
    codes = np.asarray(mesh.GetPointsAttr().GetTimeSamples(), dtype=np.float64)
    rate = float(stage.GetTimeCodesPerSecond())
    del stage
    return conversion, codes, rate, f"upAxis {up}, metersPerUnit {mpu:g}, {rate:g} fps"


def _usd_points(path: str) -> dict:
    """The points of the stage's (first, non-cage) mesh, in the stage's space (the file's order): its default value
    (``"default"``) and each time sample (by time code)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(path)
    mesh = next(UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and p.GetName() != "Cage")
    attribute = mesh.GetPointsAttr()
    points = {"default": np.asarray(attribute.Get(Usd.TimeCode.Default()), dtype=np.float64)}
    for code in attribute.GetTimeSamples():
        points[code] = np.asarray(attribute.Get(Usd.TimeCode(code)), dtype=np.float64)
    del stage
    return points


def _gltf_file(path: str, animation: str | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """The expected map from the binding's world space to Blender's (Y-up to Z-up after the ``CageSkeleton`` node's
    matrix, where there is one) and the key times (s) of the animation (named, else the first), read from the
    file: every sampler's inputs together."""
    from pygltflib import GLTF2

    gltf = GLTF2().load(path)
    found = cage_skeleton_matrix(gltf)
    node = np.eye(4) if found is None else found
    chosen = next(a for a in gltf.animations if animation is None or a.name == animation)
    blob, times = gltf.binary_blob(), set()
    for sampler in chosen.samplers:
        times.update(accessor_floats(gltf, blob, sampler.input).tolist())
    scale = np.cbrt(abs(np.linalg.det(node[:3, :3])))
    space = "no CageSkeleton node" if found is None else f"CageSkeleton matrix: scale {scale:g}"
    return Y_UP_TO_Z_UP @ node, np.asarray(sorted(times), dtype=np.float64), space


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--fox", default=str(FOX), help="the rigged glTF (default: fox_gltf/Fox.glb of the shared data)")
    p.add_argument("--animation", default="Walk", help="its animation to encode (Walk)")
    p.add_argument("--poses", choices=("npy", "usda"), default="npy", help="how encode writes the poses (npy)")
    p.add_argument("--all-frames", action="store_true", help="check every frame, not four")
    p.add_argument("--out", default=str(WORK / "blender_fox"), help="folder of the commands' files")
    p.add_argument("--json", default=None, help="write the rows and notes to this file")
    p.add_argument("--child", nargs=5, help=argparse.SUPPRESS)  # FILE FRAMES FPS ACTION OUT: one file in Blender
    args = p.parse_args(argv)
    if args.child:
        path, frames, fps, action, out = args.child
        print(json.dumps(_child(path, [float(f) for f in frames.split(",")], float(fps), action, out)))
        return 0
    if bpy_missing("check_blender_fox.py"):
        return 2
    import warp_stokes as ws
    from warp_stokes.geometry.topology import bounding_diagonal

    fox = str(Path(args.fox).resolve())
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"fox_{args.animation.lower()}"
    poses_file = f"{stem}_poses.{args.poses}"
    binding_file = f"{stem}_poses.binding.npz"
    printed = {"encode": run_cli("encode", "auto", fox, "--animation", args.animation, "-o", poses_file,
                                 "--device", "cpu", cwd=folder)}
    outputs = [f"{stem}.usda", f"{stem}.glb"]
    for name in outputs:
        printed[name] = run_cli("animate", binding_file, poses_file, "-o", name, "--device", "cpu", cwd=folder)
    encoded = _ENCODED.search(printed["encode"])
    if encoded is None:
        raise RuntimeError(f"encode printed no error figures:\n{printed['encode']}")
    rms_mean, rms_max, _, largest, _ = (float(v) for v in encoded.groups())

    binding = ws.load_binding(str(folder / binding_file), device="cpu")
    poses = ws.load_poses(str(folder / poses_file), binding.cage_faces, binding.n_handles, binding.cage_source_index)
    truth = ws.load_frames(fox, animation=args.animation)
    rest = np.asarray(binding.mesh_vertices, dtype=np.float64)
    diagonal = float(np.linalg.norm(np.ptp(rest, axis=0)))
    cage_diagonal = float(bounding_diagonal(binding.cage_vertices))
    to_mesh = cage_diagonal / diagonal  # encode's figures are over the cage's diagonal
    n = len(poses.positions)
    if len(truth.positions) != n:
        raise RuntimeError(f"{n} poses for {len(truth.positions)} frames of the animation")
    deformed = np.asarray(binding.deform(poses.positions), dtype=np.float64).reshape(n, -1, 3)
    target = np.asarray(truth.positions, dtype=np.float64)
    fit = np.linalg.norm(deformed - target, axis=2)  # (F, V): the encoding's own error
    fit_rms_cage = np.sqrt(np.mean(fit**2, axis=1)) / cage_diagonal
    worst = int(np.argmax(fit.max(axis=1)))
    picks = list(range(n)) if args.all_frames else sorted({0, (n - 1) // 2, n - 1, worst})
    skin = _SKIN.search(printed[f"{stem}.glb"])
    skin_max = float(skin.group(1)) if skin else float("nan")
    printed_a = {f"{stem}.usda": 0.0, f"{stem}.glb": skin_max}  # baked points: deform's own (no figure printed)

    columns = ["file", "Blender frame (pose; the Fox's frame)", "(a) to deform: max / diag", "median / diag",
               "printed by animate", "(b) to the Fox's skin: max / diag", "median / diag",
               "encode alone at this frame: max / diag", "printed bound for (b)", "within"]
    print(table_head(columns), flush=True)
    rows, notes = [], []
    files = [(name, str(folder / name), "") for name in outputs] + [("Fox.glb (the input)", fox, args.animation)]
    for label, path, action in files:
        if path.endswith((".glb", ".gltf")):
            conversion, times, space = _gltf_file(path, action or None)
            rate = float(truth.time_codes_per_second if action else poses.time_codes_per_second or 24.0)
            blender_frames = times * rate  # Blender keys time t at frame t * scene fps (the scene's fps set to rate)
        else:
            conversion, blender_frames, rate, space = _usd_file(path)  # time codes are Blender frames
        if len(blender_frames) != n:
            raise RuntimeError(f"{path}: {len(blender_frames)} frames for {n} poses")
        info, data, messages = points_in_blender(__file__, path, blender_frames[picks], rate, action)
        note = dict(file=label, path=path, space=space, info=info, messages=messages)
        notes.append(note)
        keys = info.get("keys")
        if keys is not None:
            note["keys"] = ("as expected" if len(keys) == n and np.allclose(keys, blender_frames, atol=1e-3)
                            else f"keys at {keys[:4]}... expected {np.round(blender_frames[:4], 4).tolist()}...")
        else:
            expected = [float(blender_frames[0]), float(blender_frames[-1])]
            same = np.allclose(info["frame_range"], expected)
            note["keys"] = f"no action; the scene's range {info['frame_range']}" + (
                " as expected" if same else f", the points' time codes {expected[0]:g} to {expected[1]:g}")
        if "rest" not in data:
            note["problem"] = "no mesh imported"
            continue
        back = np.linalg.inv(conversion)
        to_binding = lambda q: q @ back[:3, :3].T + back[:3, 3]  # noqa: E731
        blender_rest = to_binding(data["rest"])
        # the mesh data Blender made: the rest pose for a skin; for baked points (a MeshSequenceCache), points the
        # stage holds (at its first time code), in the binding's order
        reference, held = rest, "rest"
        if not path.endswith((".glb", ".gltf")):  # which of the file's points Blender holds (the nearest to them)
            stored = _usd_points(path)
            code = min(stored, key=lambda c: np.abs(blender_rest - stored[c]).max() if len(stored[c]) == len(
                blender_rest) else np.inf)
            reference, held = stored[code], f"points at time code {code:g}" if code != "default" else "rest"
        if len(blender_rest) == len(rest) and np.abs(blender_rest - reference).max() < 1e-5 * diagonal:
            match, note["match"] = np.arange(len(rest)), f"in order (Blender's mesh data: the file's {held})"
        else:
            match, distance = nearest_targets(blender_rest, reference)
            note["match"] = (f"nearest vertex of the file's {held}: {len(blender_rest)} vertices to {len(rest)}, "
                             f"farthest {distance.max() / diagonal:.1e} of the diagonal, "
                             f"{len(rest) - len(np.unique(match))} binding vertices unmatched")
        is_input = bool(action)
        for j, k in enumerate(picks):
            points = to_binding(data[f"frame{j}"])
            to_deform = np.linalg.norm(points - deformed[k][match], axis=1) / diagonal
            to_truth = np.linalg.norm(points - target[k][match], axis=1) / diagonal
            alone = fit[k].max() / diagonal
            bound_a = printed_a.get(label)
            bound_b = largest * to_mesh + (bound_a or 0.0)
            if is_input:  # the input against its own skinning as load_frames evaluates it
                within = "yes" if to_truth.max() < 1e-5 else "NO"
            else:
                ok_a = to_deform.max() <= max(bound_a, 1e-6) * 1.001
                ok_b = to_truth.max() <= bound_b * 1.001
                within = f"(a) {'yes' if ok_a else 'NO'}, (b) {'yes' if ok_b else 'NO'}"
            row = [label, f"{blender_frames[k]:g} ({k + 1}/{n}; {truth.frames[k]:g})",
                   "-" if is_input else f"{to_deform.max():.2e}", "-" if is_input else f"{np.median(to_deform):.2e}",
                   "-" if is_input else ("none (baked)" if bound_a == 0.0 else f"{bound_a:.2e}"),
                   f"{to_truth.max():.2e}", f"{np.median(to_truth):.2e}", f"{alone:.2e}",
                   "-" if is_input else f"{bound_b:.2e}", within]
            print(table_row(row), flush=True)
            rows.append(row)
    print()
    print(f"- encode (the fit's error over the cage's diagonal, {cage_diagonal:.4g}; the mesh's is {diagonal:.4g}, "
          f"so x {to_mesh:.3f} over the mesh's): RMS mean {rms_mean:.2e}, max {rms_max:.2e}, largest vertex "
          f"{largest:.2e} (over the mesh's diagonal {largest * to_mesh:.2e}); computed here from the poses: RMS mean "
          f"{fit_rms_cage.mean():.2e}, max {fit_rms_cage.max():.2e}, largest vertex "
          f"{fit.max() / cage_diagonal:.2e} (frame {truth.frames[worst]:g})")
    for name, text in printed.items():
        for line in text.splitlines():
            print(f"- printed by {'encode' if name == 'encode' else 'animate -o ' + name}: `{line}`")
    for note in notes:
        info = note["info"]
        images = "; ".join(f"{v['size'][0]}x{v['size'][1]} mean {v['mean']}" for v in info["images"].values())
        print(f"- {note['file']}: {note['space']}; objects {', '.join(info['objects'])}; meshes {info['meshes']} "
              f"with {info.get('vertices')} vertices (binding: {len(rest)}), modifiers {info['modifiers']}; action "
              f"{info.get('action')}, keys {note['keys']}; match {note.get('match')}; materials "
              f"{len(info['materials'])}, textured {len(info['textured'])}, images with pixels "
              f"{info['images_in_file']} ({images or '-'})")
        print_problem_and_messages(note)
    if args.json:
        Path(args.json).write_text(json.dumps(dict(columns=columns, rows=rows, notes=notes, printed=printed),
                                              indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
