"""Does Blender play the skins that ``warp_stokes.write_skin`` writes? Each file imported into an empty Blender
scene, evaluated at several frames, and compared with the cage deformation it stands for.

    pip install "bpy==4.5.*"          # Blender 4.5 LTS as a Python module: Python 3.11 only, about 370 MB
    python benchmarks/check_blender_skin.py --pairs arm,arm_usd          # add ,ogre for the ogre (26k vertices)

Pairs: ``arm`` (``examples/arm/arm.obj`` in ``arm_cage.obj``, the 24 poses of ``bend_poses.npy``), ``arm_usd`` (the
USD asset ``examples/arm/arm.usda``, cage prim ``/Arm/Rig/Cage``, its poses the time samples of that prim: Y-up, in
centimetres, the skin a layer over the asset) and ``ogre`` (``Ogre.obj`` in ``cage_tri.obj``, the one pose
``cage_deformed_tri.obj``). Each is bound on the CPU (``--resolution``, 64) and written four times: a UsdSkel rig with
all influences (signed weights, exact), the same with ``non_negative=True``, and glTF skins with 4 and 8 influences.

Each file is imported in a fresh child process of this script (``bpy.ops.wm.usd_import`` with
``apply_unit_conversion_scale=False`` and ``scale=1``, so that Blender keeps the stage's units;
``bpy.ops.import_scene.gltf`` with ``disable_bone_shape=True``); the scene is set to the first, middle and last pose's
frame (USD: the time code, which the importer keeps as the frame; glTF: time ``t = frame / fps`` of the file, at
Blender frame ``t * scene fps`` with the scene's fps set to the file's rate before the import; both checked against the
imported action's keys) and each skinned mesh (a mesh object with an Armature modifier) is evaluated through the
depsgraph (``evaluated_get(depsgraph).to_mesh()``, times ``matrix_world``).

Spaces: Blender is Z-up. The expected map from the binding's world space to Blender's is ``C = R`` for a Y-up USD
stage (R: (x, y, z) -> (x, -z, y), the importer's Y-up conversion on the root objects; no unit scale with the options
above) and ``C = R M`` for glTF (``M`` the ``CageSkeleton`` node's matrix read from the file: identity, or a USD asset's
Z-up/units conversion to Y-up metres; R the glTF importer's Y-up to Z-up). Blender's points are mapped back by
``C^-1``; the rest mesh (the imported mesh data times ``matrix_world``) is then checked against the binding's rest
mesh: a remaining offset (difference of bounding-box centres) is reported, vertices are matched by nearest rest
position (glTF splits vertices at UV seams; the match is brute force in numpy, no scipy needed), and a similarity
fitted to the matched rest points shows whether ``C`` was right (scale 1, no rotation, no translation).

Reported per file and frame: the largest and median distance of Blender's skinned vertices from
``binding.deform(pose)``, over the rest mesh's bounding-box diagonal, beside the ``SkinReport``'s own ``error.max``
(the skin file against the deformation, over all poses); the same largest distance with the rest offset removed; and
the weights: negative weights in the file against negative vertex-group weights in Blender, and the weights' sums per
vertex in Blender (Blender's Armature modifier divides by that sum). Below the table: per file, the importer's warnings
and errors (its printed output filtered), the objects it made, and the fitted similarity.

``bpy`` is a benchmark extra only, never a dependency of the package or its tests.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_common import (Y_UP_TO_Z_UP, accessor_floats, bpy_missing, cage_skeleton_matrix,  # noqa: E402
                            evaluated_points_at_frames, fcurve_groups, key_frames, nearest_targets,
                            open_in_empty_scene, points_in_blender, print_problem_and_messages,
                            usd_stage_to_blender, world_points)
from common import ARM, OGRE, WORK, table_head, table_row  # noqa: E402

#: the files written per pair: (label, file name after the pair's, write_skin keywords)
VARIANTS = [
    ("USD, all influences", "usd_signed.usd", {}),
    ("USD, all influences, non-negative", "usd_non_negative.usd", {"non_negative": True}),
    ("glTF, 4 influences", "gltf_4.glb", {"influences": 4}),
    ("glTF, 8 influences", "gltf_8.glb", {"influences": 8}),
]


# ---------------------------------------------------------------------------------------------------------------
# the child: one file in Blender


def _child(path: str, frames: list[float], fps: float, out: str) -> dict:
    """Import ``path`` into an empty scene, evaluate its skinned meshes at ``frames`` (Blender frames); write the
    points (Blender world space) to ``out`` (npz) and return what was found."""
    scene, result = open_in_empty_scene(path, fps)
    skinned = sorted((o for o in scene.objects if o.type == "MESH" and any(m.type == "ARMATURE" for m in o.modifiers)),
                     key=lambda o: o.name)
    armatures = [o for o in scene.objects if o.type == "ARMATURE"]
    info = dict(result=sorted(result), objects=sorted(f"{o.name} ({o.type})" for o in scene.objects),
                skinned=[o.name for o in skinned], scene_fps=scene.render.fps / scene.render.fps_base,
                frame_range=[scene.frame_start, scene.frame_end], keys=None, bones=None)
    if armatures:
        arm = armatures[0]
        info["bones"] = len(arm.data.bones)
        action = arm.animation_data.action if arm.animation_data else None
        if action is not None:
            groups = fcurve_groups(action)
            curves = groups[-1] if groups else []  # a layered action's: those of its last channel bag
            if len(curves):
                info["keys"] = key_frames(curves[0]).tolist()
                info["curves"] = len(curves)
    arrays = {}
    if not skinned:
        np.savez(out)
        return info
    rest, counts, negative, assigned, above_one, sums = [], [], 0, 0, 0, []
    for o in skinned:
        data = o.data
        rest.append(world_points(data.vertices, o.matrix_world))
        counts.append(len(data.vertices))
        for v in data.vertices:
            total = 0.0
            for g in v.groups:
                assigned += 1
                negative += g.weight < 0
                above_one += g.weight > 1
                total += g.weight
            sums.append(total)
    sums = np.asarray(sums)
    info.update(vertices=counts, negative_weights=int(negative), assigned_weights=int(assigned),
                weights_above_one=int(above_one), weight_sum_min=float(sums.min()), weight_sum_max=float(sums.max()),
                matrix_world=[np.array(o.matrix_world).round(6).tolist() for o in skinned])
    arrays["rest"] = np.concatenate(rest)
    arrays.update(evaluated_points_at_frames(scene, skinned, frames))
    np.savez(out, **arrays)
    return info


# ---------------------------------------------------------------------------------------------------------------
# the parent: bind, write, compare


def _load_pair(name: str, resolution: int):
    """(binding, poses) of a pair, bound on the CPU."""
    import warp_stokes as ws

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the arm's "resolution below 70" note: the check is of the skin, not the bind
        if name == "arm":
            b = ws.bind(ARM / "arm.obj", ARM / "arm_cage.obj", resolution=resolution, device="cpu")
            poses = ws.load_poses(ARM / "bend_poses.npy", b.cage_faces, b.n_handles, b.cage_source_index)
        elif name == "arm_usd":
            asset = str(ARM / "arm.usda")
            b = ws.bind(asset, cage_prim="/Arm/Rig/Cage", resolution=resolution, device="cpu")
            poses = ws.load_poses(asset, b.cage_faces, b.n_handles, b.cage_source_index, cage_prim="/Arm/Rig/Cage")
        elif name == "ogre":
            b = ws.bind(OGRE / "Ogre.obj", OGRE / "cage_tri.obj", resolution=resolution, device="cpu")
            pose = b._check_topology(ws.load_surface(OGRE / "cage_deformed_tri.obj"))  # one OBJ: checked, merged
            poses = ws.load_poses(pose[None], b.cage_faces, b.n_handles, b.cage_source_index)  # frame 1
        else:
            raise SystemExit(f"unknown pair {name!r} (known: arm, arm_usd, ogre)")
    return b, poses


def _usd_conversion(path: str) -> tuple[np.ndarray, str]:
    """The expected map from the file's world space to Blender's, from the stage's up axis (read from the file):
    the importer rotates a Y-up stage to Z-up; with ``apply_unit_conversion_scale=False`` it does not scale."""
    from pxr import Usd

    stage = Usd.Stage.Open(path)
    matrix, up, mpu = usd_stage_to_blender(stage)
    del stage
    return matrix, f"stage upAxis {up}, metersPerUnit {mpu:g} (kept: apply_unit_conversion_scale=False)"


def _gltf_file(path: str) -> tuple[np.ndarray, np.ndarray, str]:
    """The expected map from the binding's world space to Blender's (the glTF importer's Y-up to Z-up after the
    ``CageSkeleton`` node's matrix, read from the file) and the animation's key times (s), read from the file."""
    from pygltflib import GLTF2

    gltf = GLTF2().load(path)
    node = cage_skeleton_matrix(gltf)
    if node is None:
        raise RuntimeError(f"{path}: no CageSkeleton node (write_skin writes one)")
    times = accessor_floats(gltf, gltf.binary_blob(), gltf.animations[0].samplers[0].input).astype(np.float64)
    scale = np.cbrt(abs(np.linalg.det(node[:3, :3])))
    space = f"CageSkeleton matrix: scale {scale:g}, rotation {_angle(node[:3, :3] / scale):.0f} deg"
    return Y_UP_TO_Z_UP @ node, times, space


def _angle(rotation: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1))))


def _similarity(source: np.ndarray, target: np.ndarray) -> tuple[float, float, np.ndarray]:
    """The similarity ``target ~ s R source + t`` of least squares (Umeyama): (s, rotation angle in degrees, t)."""
    ms, mt = source.mean(axis=0), target.mean(axis=0)
    a, b = source - ms, target - mt
    u, sigma, vt = np.linalg.svd(b.T @ a / len(a))
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    rotation = u @ d @ vt
    s = float(np.trace(np.diag(sigma) @ d) / np.mean(np.sum(a**2, axis=1)))
    return s, _angle(rotation), mt - s * rotation @ ms


def _check_file(pair: str, label: str, path: str, binding, poses, report, skin) -> tuple[list, dict]:
    """Import one file in a child process and compare: (table rows, notes)."""
    rest = np.asarray(binding.mesh_vertices, dtype=np.float64)
    diagonal = float(np.linalg.norm(np.ptp(rest, axis=0)))
    n = len(poses.positions)
    picks = sorted({0, (n - 1) // 2, n - 1})
    frames = np.asarray(poses.frames, dtype=np.float64)
    # the rate write_skin used (no fps given): the poses', else the asset's, else 24
    rate = float(poses.time_codes_per_second or (binding.asset or {}).get("time_codes_per_second") or 24.0)
    if path.endswith((".glb", ".gltf")):
        conversion, times, space = _gltf_file(path)
        blender_frames = times * rate  # Blender keys time t at frame t * scene fps (the scene's fps set to rate)
    else:
        conversion, space = _usd_conversion(path)
        blender_frames = frames  # USD time codes are Blender frames
    info, data, messages = points_in_blender(__file__, path, blender_frames[picks], rate)
    notes = dict(file=path, space=space, info=info, messages=messages)
    if "rest" not in data:
        notes["problem"] = "no skinned mesh (a mesh object with an Armature modifier) was imported"
        return [[pair, label, "-", "-", "-", "-", "-", "-", f"{report.error.max:.2e}", "-", "-"]], notes
    back = np.linalg.inv(conversion)

    def to_binding(points):
        return points @ back[:3, :3].T + back[:3, 3]

    blender_rest = to_binding(data["rest"])
    centre = lambda p: (p.min(axis=0) + p.max(axis=0)) / 2  # noqa: E731
    offset = centre(blender_rest) - centre(rest)
    match, rest_distance = nearest_targets(blender_rest - offset, rest)
    s, angle, t = _similarity(blender_rest, rest[match])
    notes.update(rest_match_max=float(rest_distance.max() / diagonal), offset=offset.tolist(),
                 offset_over_diagonal=float(np.linalg.norm(offset) / diagonal),
                 similarity=f"scale {s:.6f}, rotation {angle:.4f} deg, translation {np.linalg.norm(t) / diagonal:.2e} "
                            "of the diagonal",
                 unmatched=int(len(rest) - len(np.unique(match))))
    expected_keys = blender_frames
    keys = info.get("keys")
    notes["keys"] = ("as expected" if keys is not None and len(keys) == len(expected_keys)
                     and np.allclose(keys, expected_keys, atol=1e-3)
                     else f"keys at {keys[:3] if keys else keys}... expected {expected_keys[:3].tolist()}...")
    negative_file = int(np.sum(skin.weights < 0))
    rows = []
    deformed = np.asarray(binding.deform(poses.positions[picks]), dtype=np.float64).reshape(len(picks), -1, 3)
    for j, k in enumerate(picks):
        points = to_binding(data[f"frame{j}"])
        distance = np.linalg.norm(points - deformed[j][match], axis=1) / diagonal
        shape = np.linalg.norm(points - offset - deformed[j][match], axis=1) / diagonal
        rows.append([pair, label, f"{blender_frames[k]:g} (pose {k + 1}/{n})",
                     f"{np.linalg.norm(offset) / diagonal:.1e}",
                     f"{distance.max():.2e}", f"{np.median(distance):.2e}", f"{shape.max():.2e}",
                     f"{rest_distance.max() / diagonal:.0e}", f"{report.error.max:.2e}",
                     f"{negative_file} / {info['negative_weights']}",
                     f"{info['weight_sum_min']:.3f}..{info['weight_sum_max']:.3f}"])
    return rows, notes


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pairs", nargs="+", default=["arm,arm_usd"], help="arm, arm_usd, ogre (comma or space separated)")
    p.add_argument("--resolution", type=int, default=64, help="bind resolution (64)")
    p.add_argument("--out", default=str(WORK / "blender_skin"), help="folder of the written skins")
    p.add_argument("--json", default=None, help="write the rows and notes to this file")
    p.add_argument("--child", nargs=4, help=argparse.SUPPRESS)  # FILE FRAMES FPS OUT: one file in Blender
    args = p.parse_args(argv)
    if args.child:
        path, frames, fps, out = args.child
        print(json.dumps(_child(path, [float(f) for f in frames.split(",")], float(fps), out)))
        return 0
    if bpy_missing("check_blender_skin.py"):
        return 2
    import warp_stokes as ws
    from warp_stokes.binding.skin import skin_weights

    pairs = [name for item in args.pairs for name in item.split(",") if name]
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    columns = ["pair", "file", "Blender frame (pose)", "rest offset / diag", "max / diag", "median / diag",
               "max / diag, offset removed", "rest match / diag", "SkinReport error.max",
               "negative weights: file / Blender", "Blender weight sums"]
    print(table_head(columns), flush=True)
    all_rows, all_notes = [], []
    for pair in pairs:
        binding, poses = _load_pair(pair, args.resolution)
        for label, name, keywords in VARIANTS:
            path = str(folder / f"{pair}-{name}")
            report = ws.write_skin(path, binding, poses, **keywords)
            skin = skin_weights(binding, report.influences, report.non_negative)  # the weights the file holds
            rows, notes = _check_file(pair, label, path, binding, poses, report, skin)
            notes.update(pair=pair, label=label, report=str(report), binding_vertices=len(binding.mesh_vertices))
            for row in rows:
                print(table_row(row), flush=True)
            all_rows += rows
            all_notes.append(notes)
    print()
    for notes in all_notes:
        info = notes["info"]
        print(f"- {notes['pair']}, {notes['label']}: `{notes['file']}`; {notes['space']}; "
              f"objects {', '.join(info['objects'])}; skinned {info['skinned']} with {info.get('vertices')} vertices "
              f"(binding: {notes['binding_vertices']}), {info.get('bones')} bones, scene fps {info['scene_fps']:g}, "
              f"keys {notes.get('keys')}; rest fit: {notes.get('similarity')}, "
              f"rest offset {np.round(notes.get('offset', [0, 0, 0]), 4).tolist()}; "
              f"weights in Blender: {info.get('assigned_weights')} assigned, {info.get('negative_weights')} negative, "
              f"{info.get('weights_above_one')} above one")
        if notes.get("offset_over_diagonal", 0.0) > 1e-4:
            notes["problem"] = (f"Blender places the skinned mesh {np.round(notes['offset'], 4).tolist()} (binding "
                                "space) away from where the file puts it: the shape plays, the placement does not")
        print_problem_and_messages(notes)
    if args.json:
        Path(args.json).write_text(json.dumps(dict(columns=columns, rows=all_rows, notes=all_notes), indent=1,
                                              default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
