"""What the Blender checks share (``check_blender_fox.py``, ``check_blender_skin.py``, ``check_blender_looks.py``):
importing a file into an empty Blender scene and reading back its points, keys, materials and images (in the child
process that imports ``bpy``), and on the parent's side the child's run, the importers' messages, the maps from a
file's space to Blender's and the nearest-vertex match.

The scripts import it as ``from blender_common import ...`` after putting their own folder first on ``sys.path``.
Nothing here imports ``bpy``, ``pxr`` or ``pygltflib`` at import time: ``bpy`` only in the functions the child calls
(Blender's own USD library must not meet the ``pxr`` module with which the parent reads the files), and the parent's
readers take an opened stage or glTF.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
import tempfile

import numpy as np

from common import DATA, REPO

INSTALL = 'pip install "bpy==4.5.*" (Blender 4.5 LTS as a Python module; Python 3.11 only)'
#: the rigged glTF Fox of the shared data (1,728 vertices, one textured material, animations Survey, Walk and Run)
FOX = DATA / "fox_gltf" / "Fox.glb"

#: the importers' map from Y-up to Blender's Z-up: (x, y, z) -> (x, -z, y)
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])

#: importer output lines worth reporting (warnings and errors), and known noise
_MESSAGE = re.compile(r"warn|error|couldn't|could not|invalid|unsupported|mismatch|fail|ignor", re.I)
_NOISE = re.compile(r"^\d\d:\d\d:\d\d \| INFO:|took [\d.]+ ms|^Read blend|^Blender quit|pyrna_enum_to_py")


# ---------------------------------------------------------------------------------------------------------------
# in the child: Blender


def open_in_empty_scene(path: str, fps: float | None = None, keep_units: bool = True):
    """Import ``path`` into an empty Blender scene (factory settings).

    Parameters
    ----------
    path : str
        A glTF/GLB (``import_scene.gltf`` with ``disable_bone_shape=True``: no mesh for the bones' shape), an OBJ
        (``wm.obj_import``) or anything else, read as USD (``wm.usd_import``).
    fps : float, optional
        The scene's rate, set before the import (the glTF importer keys time ``t`` at frame ``t * fps``): ``fps`` as
        the nearest whole number over ``fps_base``. None keeps the factory rate.
    keep_units : bool
        USD: import with ``apply_unit_conversion_scale=False`` and ``scale=1``, so that Blender keeps the stage's
        units; False: the importer's defaults.

    Returns
    -------
    scene : bpy.types.Scene
        The scene the file was imported into.
    result : set of str
        What the import operator returned (``{"FINISHED"}``).
    """
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    if fps is not None:
        scene.render.fps, scene.render.fps_base = max(1, round(fps)), max(1, round(fps)) / fps
    if path.endswith((".glb", ".gltf")):
        result = bpy.ops.import_scene.gltf(filepath=path, disable_bone_shape=True)
    elif path.endswith(".obj"):
        result = bpy.ops.wm.obj_import(filepath=path)
    elif keep_units:
        result = bpy.ops.wm.usd_import(filepath=path, apply_unit_conversion_scale=False, scale=1.0)
    else:
        result = bpy.ops.wm.usd_import(filepath=path)
    return scene, result


def world_points(vertices, matrix_world) -> np.ndarray:
    """The positions of Blender mesh vertices in world space.

    Parameters
    ----------
    vertices : bpy_prop_collection of MeshVertex
        A mesh's ``vertices``.
    matrix_world : mathutils.Matrix
        The 4x4 matrix of the object the mesh belongs to.

    Returns
    -------
    numpy.ndarray
        ``(V, 3)`` float64: each vertex's ``co`` times ``matrix_world``.
    """
    co = np.empty(3 * len(vertices))
    vertices.foreach_get("co", co)
    m = np.array(matrix_world)
    return co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]


def evaluated_points_at_frames(scene, objects, frames) -> dict[str, np.ndarray]:
    """The mesh objects' vertices as the depsgraph evaluates them at each of ``frames``, in world space.

    Parameters
    ----------
    scene : bpy.types.Scene
        The scene holding ``objects``; its current frame is left at the last of ``frames``.
    objects : list of bpy.types.Object
        Mesh objects; their points are concatenated in this order.
    frames : sequence of float
        Blender frames; a fractional frame is set as a subframe.

    Returns
    -------
    dict of str to numpy.ndarray
        ``"frame{k}"``: the ``(V, 3)`` points at ``frames[k]`` (``evaluated_get(depsgraph).to_mesh()`` times the
        evaluated ``matrix_world``), V the objects' vertices together.
    """
    import bpy

    arrays = {}
    for k, frame in enumerate(frames):
        whole = int(np.floor(frame))
        scene.frame_set(whole, subframe=float(frame - whole))
        graph = bpy.context.evaluated_depsgraph_get()
        points = []
        for o in objects:
            evaluated = o.evaluated_get(graph)
            points.append(world_points(evaluated.to_mesh().vertices, evaluated.matrix_world))
            evaluated.to_mesh_clear()
        arrays[f"frame{k}"] = np.concatenate(points)
    return arrays


def fcurve_groups(action) -> list[list]:
    """The F-curves of an action, by where they are kept.

    Parameters
    ----------
    action : bpy.types.Action
        A legacy action (its own ``fcurves``) or a layered one (Blender 4.4 on: curves in the channel bags of its
        layers' strips).

    Returns
    -------
    list of list of bpy.types.FCurve
        The action's own curves as one group where it has any, else one group per channel bag (empty where it has
        neither).
    """
    curves = action.fcurves if hasattr(action, "fcurves") else []
    if len(curves):
        return [list(curves)]
    return [list(bag.fcurves) for layer in getattr(action, "layers", []) for strip in layer.strips
            for bag in strip.channelbags]


def key_frames(curve) -> np.ndarray:
    """The frames of an F-curve's keys, float64, in the curve's order."""
    co = np.zeros(len(curve.keyframe_points) * 2)
    curve.keyframe_points.foreach_get("co", co)
    return co[0::2]


def base_colour_image(material):
    """The image a material shows as its colour.

    Parameters
    ----------
    material : bpy.types.Material

    Returns
    -------
    bpy.types.Image or None
        The image of an Image Texture node that feeds a Principled BSDF's Base Color (directly or through other
        nodes), where it has pixels; else None.
    """
    if not material.use_nodes:
        return None
    for node in material.node_tree.nodes:
        if node.type != "BSDF_PRINCIPLED":
            continue
        todo, seen = [link.from_node for link in node.inputs["Base Color"].links], set()
        while todo:
            upstream = todo.pop()
            if upstream.name in seen:
                continue
            seen.add(upstream.name)
            if upstream.type == "TEX_IMAGE" and upstream.image is not None and upstream.image.size[0] > 0:
                return upstream.image
            todo += [link.from_node for socket in upstream.inputs for link in socket.links]
    return None


def materials_shown(objects) -> dict:
    """The materials on mesh objects and the images they show.

    Parameters
    ----------
    objects : list of bpy.types.Object
        Mesh objects.

    Returns
    -------
    dict
        ``materials``: the names of the materials in the objects' slots, sorted; ``textured``: those that show an
        image (``base_colour_image``), sorted; ``images``: by image name, its ``size`` and the ``mean`` of its pixels
        (5 decimals: the same image decoded gives the same mean).
    """
    used = {slot.material for o in objects for slot in o.material_slots if slot.material is not None}
    textured, images = [], {}
    for material in sorted(used, key=lambda m: m.name):
        shown = base_colour_image(material)
        if shown is not None:
            textured.append(material.name)
            pixels = np.empty(len(shown.pixels), dtype=np.float32)
            shown.pixels.foreach_get(pixels)
            images[shown.name] = {"size": list(shown.size), "mean": round(float(pixels.mean()), 5)}
    return {"materials": sorted(m.name for m in used), "textured": textured, "images": images}


# ---------------------------------------------------------------------------------------------------------------
# in the parent


def bpy_missing(script: str) -> bool:
    """Whether Blender's Python module is missing (found, not imported: Blender's own USD library must not meet the
    ``pxr`` module with which the parent reads or writes the files); if so, says so on stderr, naming ``script``."""
    if importlib.util.find_spec("bpy") is None:
        print(f"{script} needs Blender's Python module: {INSTALL}", file=sys.stderr)
        return True
    return False


def run_cli(*args, cwd=None) -> str:
    """``warp-stokes ARGS`` as a user runs it: a child process (``python -m warp_stokes.cli``) on this checkout.

    Parameters
    ----------
    *args : str
        The command line after ``warp-stokes``.
    cwd : path-like, optional
        The folder it runs in (default: this process's).

    Returns
    -------
    str
        What it printed (stdout, then stderr), stripped.

    Raises
    ------
    RuntimeError
        Where it exits other than 0, with the end of what it printed.
    """
    proc = subprocess.run([sys.executable, "-m", "warp_stokes.cli", *args], cwd=cwd, capture_output=True,
                          text=True, env=dict(os.environ, PYTHONPATH=str(REPO)))
    if proc.returncode != 0:
        raise RuntimeError(f"warp-stokes {' '.join(args)} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return (proc.stdout + proc.stderr).strip()


def importer_messages(printed: str) -> list[str]:
    """The lines of a child's output that are warnings or errors, less known noise and the last line (the child's
    JSON)."""
    return [line.strip() for line in printed.splitlines()[:-1] if _MESSAGE.search(line) and not _NOISE.search(line)]


def print_problem_and_messages(notes: dict) -> None:
    """Print a file's problem, where ``notes`` has one (``"problem"``), and the importer's messages (``"messages"``,
    from ``points_in_blender``) as indented Markdown list items; a line saying there were none where there were
    none."""
    if notes.get("problem"):
        print(f"  - PROBLEM: {notes['problem']}")
    for message in notes["messages"]:
        print(f"  - importer: {message}")
    if not notes["messages"]:
        print("  - importer: no warnings or errors printed")


def points_in_blender(script: str, path: str, frames, fps: float, *extra: str) -> tuple[dict, dict, list[str]]:
    """One file in Blender, in a child process of ``script``: ``script --child PATH FRAMES FPS *EXTRA OUT``.

    Parameters
    ----------
    script : str
        The check whose ``--child`` imports the file, evaluates it at the frames, writes its points to ``OUT`` (npz)
        and prints what it found as JSON on its last line.
    path : str
        The file.
    frames : sequence of float
        Blender frames, passed as their ``repr`` joined by commas.
    fps : float
        The scene's rate.
    *extra : str
        Further arguments, before ``OUT``.

    Returns
    -------
    info : dict
        The child's JSON.
    arrays : dict of str to numpy.ndarray
        What it wrote to ``OUT``.
    messages : list of str
        The importer's warnings and errors (``importer_messages``).

    Raises
    ------
    RuntimeError
        Where the child exits other than 0.
    """
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "points.npz")
        at = ",".join(repr(float(f)) for f in frames)
        proc = subprocess.run([sys.executable, script, "--child", path, at, repr(fps), *extra, out],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"Blender failed on {path}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
        info = json.loads(proc.stdout.strip().splitlines()[-1])
        arrays = dict(np.load(out))
    return info, arrays, importer_messages(proc.stdout + proc.stderr)


def usd_stage_to_blender(stage) -> tuple[np.ndarray, str, float]:
    """The expected map from a stage's world space to Blender's, read from the stage.

    Parameters
    ----------
    stage : pxr.Usd.Stage

    Returns
    -------
    matrix : numpy.ndarray
        4x4: ``Y_UP_TO_Z_UP`` for a Y-up stage (the importer rotates it), else the identity; no scale (the import
        with ``apply_unit_conversion_scale=False``).
    up : str
        The stage's up axis.
    meters_per_unit : float
    """
    from pxr import UsdGeom

    up, mpu = str(UsdGeom.GetStageUpAxis(stage)), float(UsdGeom.GetStageMetersPerUnit(stage))
    return (Y_UP_TO_Z_UP if up == "Y" else np.eye(4)), up, mpu


def cage_skeleton_matrix(gltf) -> np.ndarray | None:
    """The 4x4 matrix of a glTF's ``CageSkeleton`` node (what ``write_skin`` puts between the binding's space and
    the file's: identity, or an asset's conversion to Y-up metres); identity where the node has none, None where
    there is no such node."""
    root = next((n for n in gltf.nodes if n.name == "CageSkeleton"), None)
    if root is None:
        return None
    return np.eye(4) if not root.matrix else np.asarray(root.matrix, dtype=np.float64).reshape(4, 4).T


def accessor_floats(gltf, blob: bytes, index: int) -> np.ndarray:
    """The float32 values of a glTF accessor (flat), from the file's binary blob ``gltf.binary_blob()``."""
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    return np.frombuffer(blob, dtype=np.float32, count=accessor.count,
                         offset=(view.byteOffset or 0) + (accessor.byteOffset or 0))


def nearest_targets(points: np.ndarray, targets: np.ndarray, chunk: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """Each point's nearest target, by brute force in chunks (no scipy needed).

    Parameters
    ----------
    points : numpy.ndarray
        ``(N, 3)``.
    targets : numpy.ndarray
        ``(M, 3)``.
    chunk : int
        Points per chunk (the chunk's distances to every target are held at once).

    Returns
    -------
    index : numpy.ndarray
        ``(N,)`` int64: the nearest target's index.
    distance : numpy.ndarray
        ``(N,)``: the distance to it.
    """
    index, distance = np.empty(len(points), dtype=np.int64), np.empty(len(points))
    t2 = np.sum(targets**2, axis=1)
    for s in range(0, len(points), chunk):
        p = points[s : s + chunk]
        d2 = np.sum(p**2, axis=1)[:, None] + t2[None] - 2 * p @ targets.T
        k = np.argmin(d2, axis=1)
        index[s : s + chunk] = k
        distance[s : s + chunk] = np.linalg.norm(p - targets[k], axis=1)
    return index, distance
