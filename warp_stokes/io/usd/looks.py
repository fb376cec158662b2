"""The binding's looks (:mod:`..looks`) on a standalone stage: a ``UsdShade.Material`` per input material under
``/Root/Looks``, each a ``UsdPreviewSurface`` whose textures are ``UsdUVTexture`` shaders reading the ``st``
primvar (``UsdPrimvarReader_float2``), bound to each mesh (to subsets of its faces where a mesh has several).

glTF's metallic-roughness material maps onto ``UsdPreviewSurface`` input for input: base colour (factor, or the
texture scaled by it) to ``diffuseColor`` and its alpha to ``opacity``, ``metallicFactor`` and
``roughnessFactor`` (or the blue and green of their texture), ``emissiveFactor`` (or its texture), the normal and
occlusion textures. Each image the materials use is written beside the layer (``LAYER.IMAGE.png``) and named by a
relative asset path; USD's texture readers take PNG and JPEG, so an image of another type is left out with a warning.
A layer over a USD asset writes none of this: the asset's own materials come through composition.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from ..load import polygons_by_part
from ..looks import IMAGE_SUFFIXES
from ..outputs import atomic_output
from .common import prim_name

__all__ = ["StageLooks"]

# glTF sampler wrap modes -> UsdUVTexture's
_WRAP = {33071: "clamp", 33648: "mirror", 10497: "repeat"}
# (glTF texture slot, where it sits, UsdPreviewSurface input, UsdUVTexture output, colour space)
_SLOTS = (("baseColorTexture", "pbr", "diffuseColor", "rgb", "sRGB"),
          ("metallicRoughnessTexture", "pbr", "roughness", "g", "raw"),
          ("normalTexture", "material", "normal", "rgb", "raw"),
          ("emissiveTexture", "material", "emissiveColor", "rgb", "sRGB"),
          ("occlusionTexture", "material", "occlusion", "r", "raw"))
# UsdPreviewSurface's inputs that are not floats, by their type's name
_INPUT_TYPES = {"diffuseColor": "Color3f", "emissiveColor": "Color3f", "normal": "Normal3f"}


class StageLooks:
    """The looks of a standalone stage written at ``path``: the binding's looks with their images read, and the file
    beside the layer each image the stage uses is written to.

    Use: :meth:`outputs` with the layer in one output group, :meth:`write_images` inside it, :meth:`define` on the
    stage once its meshes are defined.
    """

    def __init__(self, path, binding):
        self.path = os.fspath(path)
        self.looks = None if binding.looks is None else binding.looks.resolved(binding.mesh_uvs is not None)
        self.images: dict = {}  # image number -> (output path, asset path)
        if self.looks is None:
            return
        stem = os.path.splitext(os.path.basename(self.path))[0]
        folder = os.path.dirname(self.path)
        used = {self.looks.textures[holder[key]["index"]].get("source") for material in self.looks.materials
                for holder, key in _usd_slots(material)}
        taken: set = set()
        for k, (image, _) in enumerate(self.looks.images):
            if k not in used:
                continue
            if image.mime not in IMAGE_SUFFIXES:
                warnings.warn(f"{self.path}: image {image.name or k} of the materials is {image.mime}, which USD's "
                              "texture readers do not take; the stage's materials are written without it",
                              stacklevel=3)
                continue
            label = image.name or f"image{k}"
            label = os.path.splitext(label)[0] if label.lower().endswith((".png", ".jpg", ".jpeg")) else label
            name = f"{stem}.{prim_name(label, f'image{k}', taken)}{IMAGE_SUFFIXES[image.mime]}"
            self.images[k] = (os.path.join(folder, name), f"./{name}")

    def outputs(self) -> list[str]:
        """The image files to write beside the layer."""
        return [output for output, _ in self.images.values()]

    def write_images(self) -> None:
        """Each image the stage uses, as read (its bytes unchanged), through the door out."""
        for k, (output, _) in self.images.items():
            with atomic_output(output) as tmp, open(tmp, "wb") as fh:
                fh.write(self.looks.images[k][1])

    def define(self, stage, binding, meshes: list) -> None:
        """The materials under ``/Root/Looks``, and each of ``meshes`` (a UsdGeom.Mesh per part of the binding)
        bound to its polygons' materials: the mesh itself where all its polygons have one, else a subset of its
        faces per material."""
        from pxr import UsdGeom, UsdShade

        if self.looks is None:
            return
        UsdGeom.Scope.Define(stage, "/Root/Looks")
        taken: set = set()
        materials = []
        for k, material in enumerate(self.looks.materials):
            name = prim_name(material.get("name"), f"Material{k}", taken)
            materials.append(self._material(stage, material, f"/Root/Looks/{name}"))
        slices = binding.part_slices()
        polygons = polygons_by_part(binding.mesh_face_counts, binding.mesh_face_indices, slices)
        face_materials = binding.mesh_face_materials
        for mesh, (faces, _) in zip(meshes, polygons):
            if face_materials is None or not len(faces):
                continue
            chosen = face_materials[faces]
            numbers = [int(m) for m in np.unique(chosen) if m >= 0]
            api = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
            if len(numbers) == 1 and (chosen >= 0).all():
                api.Bind(materials[numbers[0]])
                continue
            for number in numbers:
                subset = api.CreateMaterialBindSubset(
                    materials[number].GetPrim().GetName(), np.flatnonzero(chosen == number).astype(np.int32).tolist(),
                    UsdGeom.Tokens.face)
                UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(materials[number])

    def _material(self, stage, material: dict, path: str):
        """One glTF material as a UsdShade.Material with a UsdPreviewSurface (see the module docstring)."""
        from pxr import Gf, Sdf, UsdShade

        pbr = material.get("pbrMetallicRoughness") or {}
        factor = _floats(pbr.get("baseColorFactor"), [1.0, 1.0, 1.0, 1.0])
        emissive = _floats(material.get("emissiveFactor"), [0.0, 0.0, 0.0])
        metallic = _floats([pbr.get("metallicFactor")], [1.0])[0]  # (glTF's defaults: 1)
        roughness = _floats([pbr.get("roughnessFactor")], [1.0])[0]
        shade = UsdShade.Material.Define(stage, path)
        surface = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
        surface.CreateIdAttr("UsdPreviewSurface")
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*factor[:3]))
        surface.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(factor[3])
        surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(metallic)
        surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
        surface.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
        if material.get("alphaMode") == "MASK":
            cutoff = _floats([material.get("alphaCutoff")], [0.5])[0]
            surface.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(cutoff)
        shade.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
        reader = None
        for slot, where, target, channel, space in _SLOTS:
            info = (pbr if where == "pbr" else material).get(slot)
            image = self._image_of(info)
            if image is None:
                continue
            if reader is None:
                reader = UsdShade.Shader.Define(stage, f"{path}/stReader")
                reader.CreateIdAttr("UsdPrimvarReader_float2")
                reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
            scale, bias = _scale_and_bias(slot, factor, emissive, metallic, roughness, info)
            texture = UsdShade.Shader.Define(stage, f"{path}/{slot[0].upper()}{slot[1:]}")
            texture.CreateIdAttr("UsdUVTexture")
            texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(self.images[image][1]))
            texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
            texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(space)
            texture.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*scale))
            texture.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*bias))
            sampler = self._sampler_of(info)
            for axis in ("S", "T"):
                wrap = _WRAP.get(sampler.get(f"wrap{axis}", 10497), "repeat")
                texture.CreateInput(f"wrap{axis}", Sdf.ValueTypeNames.Token).Set(wrap)
            texture.CreateOutput(channel, Sdf.ValueTypeNames.Float3 if len(channel) == 3 else Sdf.ValueTypeNames.Float)
            kind = getattr(Sdf.ValueTypeNames, _INPUT_TYPES.get(target, "Float"))
            surface.CreateInput(target, kind).ConnectToSource(texture.ConnectableAPI(), channel)
            if slot == "metallicRoughnessTexture":  # the same texture: metallic in its blue
                texture.CreateOutput("b", Sdf.ValueTypeNames.Float)
                surface.GetInput("metallic").ConnectToSource(texture.ConnectableAPI(), "b")
            if slot == "baseColorTexture" and material.get("alphaMode") in ("BLEND", "MASK"):
                texture.CreateOutput("a", Sdf.ValueTypeNames.Float)
                surface.GetInput("opacity").ConnectToSource(texture.ConnectableAPI(), "a")
        return shade

    def _image_of(self, info) -> int | None:
        """The image number a glTF texture reference reads, where the stage writes that image."""
        if not isinstance(info, dict) or "index" not in info:
            return None
        image = self.looks.textures[info["index"]].get("source")
        return image if image in self.images else None

    def _sampler_of(self, info) -> dict:
        sampler = self.looks.textures[info["index"]].get("sampler")
        return self.looks.samplers[sampler] if sampler is not None else {}


def _usd_slots(material: dict):
    """The texture references of a glTF material that the stage's UsdPreviewSurface takes, as (holder, key)."""
    pbr = material.get("pbrMetallicRoughness") or {}
    for slot, where, *_ in _SLOTS:
        holder = pbr if where == "pbr" else material
        if isinstance(holder.get(slot), dict) and "index" in holder[slot]:
            yield holder, slot


def _floats(values, default: list) -> list:
    """``values`` as floats where they are as many finite numbers as ``default``, else ``default``."""
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        return list(default)
    return out if len(out) == len(default) and all(np.isfinite(out)) else list(default)


def _scale_and_bias(slot: str, factor, emissive, metallic, roughness, info) -> tuple[list, list]:
    """UsdUVTexture's scale and bias for a glTF texture: the factor glTF multiplies it by; a normal map's
    [0, 1] -> [-1, 1] (times its scale in x and y)."""
    if slot == "baseColorTexture":
        return list(factor), [0.0] * 4
    if slot == "emissiveTexture":
        return list(emissive) + [1.0], [0.0] * 4
    if slot == "metallicRoughnessTexture":
        return [1.0, roughness, metallic, 1.0], [0.0] * 4
    if slot == "normalTexture":
        strength = _floats([info.get("scale")], [1.0])[0]
        return [2.0 * strength, 2.0 * strength, 2.0, 1.0], [-strength, -strength, -1.0, 0.0]
    strength = _floats([info.get("strength")], [1.0])[0]  # occlusion: 1 + strength (r - 1)
    return [strength, strength, strength, 1.0], [1.0 - strength, 1.0 - strength, 1.0 - strength, 0.0]
