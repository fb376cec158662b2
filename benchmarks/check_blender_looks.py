"""Does Blender see the looks that warp-stokes writes? Each input is bound to a cage made for it and animated, and
the input and every output are imported into an empty Blender scene: the materials, the images and the texture
each material shows are compared.

    pip install "bpy==4.5.*"          # Blender 4.5 LTS as a Python module: Python 3.11 only, about 370 MB
    python benchmarks/check_blender_looks.py                    # the Fox, and two characters made in code
    python benchmarks/check_blender_looks.py char.glb other.obj # any textured glTF/GLB or OBJ with .mtl

Default inputs: ``../shared/data/fox_gltf/Fox.glb`` (one material, one embedded PNG) and two characters made by
``tests/looks_inputs.py``: a GLB of two parts with two materials (one textured, its image embedded) and an OBJ of
three parts with a ``.mtl`` of three materials (two textured, PNG files beside it). Each is bound on the CPU
(``bind MESH auto --handles 40 --resolution 12``) and written by ``animate`` as a glTF skin (``.glb``) and as a
standalone USD stage (``.usda``, its images beside it), over three poses (rest, moved, scaled).

Each file is imported in a child process of this script (``bpy.ops.import_scene.gltf``, ``bpy.ops.wm.obj_import``,
``bpy.ops.wm.usd_import``). Reported per file: the materials on the mesh objects, how many of them show an image (an
Image Texture node whose image has pixels, linked into the Principled BSDF's Base Color), the images with pixels
(size, and the mean of their pixels: the same image decoded gives the same mean), and the mesh objects without a
material. An output matches its input where it has as many materials and textured materials, and its images have the
input's sizes and pixel means.

``bpy`` is a benchmark extra only, never a dependency of the package or its tests.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_common import FOX, INSTALL, materials_shown, open_in_empty_scene, run_cli  # noqa: E402
from common import REPO  # noqa: E402


def _child(path: str, out: str) -> None:
    """Import ``path`` into an empty Blender scene and write what it shows (JSON) to ``out``."""
    scene, _ = open_in_empty_scene(path, keep_units=False)  # USD: the importer's own units
    meshes = [o for o in scene.objects if o.type == "MESH" and o.name != "Cage"]
    report = {**materials_shown(meshes), "meshes": len(meshes),
              "bare": sorted(o.name for o in meshes if not any(s.material for s in o.material_slots))}
    Path(out).write_text(json.dumps(report))


def blender_sees(path: Path) -> dict:
    """What Blender shows of ``path``, from a child process."""
    with tempfile.NamedTemporaryFile(suffix=".json") as out:
        result = subprocess.run([sys.executable, __file__, "--child", str(path), out.name], capture_output=True,
                                text=True)
        if result.returncode != 0:
            return {"error": result.stderr.strip().splitlines()[-1:]}
        return json.loads(Path(out.name).read_text())


def made_inputs(folder: Path) -> list[Path]:
    """The two characters made in code (``tests/looks_inputs.py``)."""
    sys.path.insert(0, str(REPO / "tests"))
    from looks_inputs import LooksCase, write_gltf_case, write_obj_case

    write_gltf_case(folder / "two.glb", LooksCase((0, 1), (True, False)))
    write_obj_case(folder / "three.obj", LooksCase((0, 1, 2), (True, False, True)))
    return [folder / "two.glb", folder / "three.obj"]


def outputs_of(mesh: Path, folder: Path) -> list[Path]:
    """``mesh`` bound to a made cage and animated over three poses, as a GLB skin and a USD stage."""
    import warp_stokes as ws

    stem = folder / mesh.stem
    run_cli("bind", str(mesh), "auto", "-o", f"{stem}.npz", "--handles", "40", "--resolution", "12",
            "--device", "cpu", "--quiet")
    cage = ws.load_binding(f"{stem}.npz", device="cpu").cage_vertices
    diagonal = float(np.linalg.norm(np.ptp(cage, axis=0)))
    np.save(f"{stem}_poses.npy", np.stack([cage, cage + [0.0, 0.1 * diagonal, 0.0], cage * 1.1]))
    found = []
    for ext in (".glb", ".usda"):
        output = Path(f"{stem}_out{ext}")
        run_cli("animate", f"{stem}.npz", f"{stem}_poses.npy", "-o", str(output), "--device", "cpu")
        found.append(output)
    return found


def matches(source: dict, output: dict) -> bool:
    """Whether an output shows what its input shows: as many materials and textured materials, the same images."""
    if "error" in source or "error" in output:
        return False
    same_images = sorted(map(json.dumps, source["images"].values())) == sorted(map(json.dumps,
                                                                                  output["images"].values()))
    return (len(source["materials"]) == len(output["materials"]) and len(source["textured"]) ==
            len(output["textured"]) and same_images and not output["bare"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("inputs", nargs="*", type=Path, help="textured glTF/GLB or OBJ files (default: see above)")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(*args.child)
        return 0
    if importlib.util.find_spec("bpy") is None:
        print(f"needs bpy: {INSTALL}")
        return 2
    folder = Path(tempfile.mkdtemp(prefix="blender_looks_"))
    inputs = args.inputs or ([FOX] if FOX.exists() else []) + made_inputs(folder)
    print("| file | materials | textured | images (size, pixel mean) | meshes without one | matches its input |\n"
          "|---|---|---|---|---|---|")
    failures = 0
    for mesh in inputs:
        source = blender_sees(mesh)
        rows = [(mesh, source, "(input)")]
        for output in outputs_of(mesh.resolve(), folder):
            seen = blender_sees(output)
            ok = matches(source, seen)
            failures += not ok
            rows.append((output, seen, "yes" if ok else "NO"))
        for path, seen, verdict in rows:
            if "error" in seen:
                print(f"| {path.name} | import failed: {seen['error']} | | | | {verdict} |")
                continue
            images = "; ".join(f"{v['size'][0]}x{v['size'][1]} {v['mean']}" for v in seen["images"].values())
            print(f"| {path.name} | {len(seen['materials'])} | {len(seen['textured'])} | {images or '-'} | "
                  f"{len(seen['bare'])} of {seen['meshes']} | {verdict} |")
    print(f"\nfiles in {folder}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
