"""Rigged characters built in code for the tests of rigged animation in, and an independent evaluation of a glTF's
skinning to hold ``ws.load_frames`` against.

- :class:`SkinnedGltf` writes a skinned (and morphed) glTF with pygltflib: any joint tree, rest transforms, inverse
  bind matrices, influence sets stored as floats or normalised integers, sparse morph targets, animations of every
  interpolation, and a glTF with its buffer in a file beside it.
- :func:`reference_frames` evaluates a glTF's animation with pygltflib and numpy only, its own way: accessors read
  element by element, channels sampled one time at a time, rotations interpolated as powers of the relative
  quaternion (``q0 (q0⁻¹ q1)^s``) and turned into matrices by Rodrigues' formula, world matrices by recursion from
  the roots, each vertex skinned by its blended matrix. None of it calls the package.
- :func:`write_usd_skel` builds a UsdSkel asset with pxr: a skinned cylinder with a blend shape, two animations, an
  unskinned prop moved by its transform and a rigidly skinned hat.
"""

from __future__ import annotations

import base64
import bisect
import os
import re

import numpy as np

FLOAT, UBYTE, USHORT = 5126, 5121, 5123
_NUMPY = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_SIZE = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def cylinder(rings: int = 7, around: int = 8, height: float = 3.0, radius: float = 0.3):
    """A closed cylinder along +y from 0 to ``height``: points (V, 3) and triangles."""
    points = [(radius * np.cos(a), y, radius * np.sin(a))
              for y in np.linspace(0, height, rings) for a in np.linspace(0, 2 * np.pi, around, endpoint=False)]
    faces = []
    for r in range(rings - 1):
        for k in range(around):
            a, b = r * around + k, r * around + (k + 1) % around
            faces += [(a, b, b + around), (a, b + around, a + around)]
    bottom, top = len(points), len(points) + 1
    points += [(0.0, 0.0, 0.0), (0.0, height, 0.0)]
    for k in range(around):
        faces += [(bottom, (k + 1) % around, k)]
        faces += [(top, (rings - 1) * around + k, (rings - 1) * around + (k + 1) % around)]
    return np.array(points), np.array(faces)


def trs_matrix(translation=(0, 0, 0), rotation=(0, 0, 0, 1), scale=(1, 1, 1)) -> np.ndarray:
    """T @ R @ S (column vectors), the rotation by Rodrigues' formula from the quaternion's axis and angle."""
    matrix = np.eye(4)
    matrix[:3, :3] = rodrigues(np.asarray(rotation, dtype=np.float64)) * np.asarray(scale, dtype=np.float64)
    matrix[:3, 3] = translation
    return matrix


class SkinnedGltf:
    """A glTF being written: binary data, accessors and the document's objects (pygltflib)."""

    def __init__(self):
        from pygltflib import GLTF2, Asset, Scene

        self.gltf = GLTF2(asset=Asset(version="2.0"), scenes=[Scene(nodes=[])], scene=0)
        self.blob = b""

    def accessor(self, data, component=FLOAT, kind=None, normalized=False, sparse_of: int | None = None) -> int:
        """An accessor of ``data`` stored as ``component``; with ``sparse_of`` (a count), a sparse accessor of that
        many zero elements with ``data`` (rows, values) substituted."""
        from pygltflib import Accessor, AccessorSparseIndices, AccessorSparseValues, BufferView, Sparse

        def view(array) -> int:
            raw = np.ascontiguousarray(array).tobytes()
            self.gltf.bufferViews.append(BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(raw)))
            self.blob += raw + b"\0" * (-len(raw) % 4)
            return len(self.gltf.bufferViews) - 1

        if sparse_of is not None:
            rows, values = data
            values = np.asarray(values, dtype=_NUMPY[component])
            sparse = Sparse(count=len(rows), indices=AccessorSparseIndices(bufferView=view(np.asarray(rows, "<u2")),
                                                                           componentType=USHORT),
                            values=AccessorSparseValues(bufferView=view(values)))
            width = values.shape[1] if values.ndim == 2 else 1
            self.gltf.accessors.append(Accessor(componentType=component, count=sparse_of, sparse=sparse,
                                                type=kind or {1: "SCALAR", 3: "VEC3", 4: "VEC4"}[width]))
            return len(self.gltf.accessors) - 1
        array = np.asarray(data)
        if component != FLOAT and normalized:  # normalised integers: the value times the largest integer
            largest = np.iinfo(np.dtype(_NUMPY[component])).max
            array = np.round(array * largest)
        array = array.astype(_NUMPY[component])
        width = 1 if array.ndim == 1 else int(np.prod(array.shape[1:]))
        accessor = Accessor(bufferView=view(array), componentType=component, count=len(array), normalized=normalized,
                            type=kind or {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}[width])
        if kind is None and width == 3 and component == FLOAT:
            accessor.min, accessor.max = array.min(axis=0).tolist(), array.max(axis=0).tolist()
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def node(self, name: str, parent: int | None = None, root: bool = False, **fields) -> int:
        from pygltflib import Node

        self.gltf.nodes.append(Node(name=name, **{k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                                  for k, v in fields.items()}))
        index = len(self.gltf.nodes) - 1
        if parent is not None:
            self.gltf.nodes[parent].children.append(index)
        if root:
            self.gltf.scenes[0].nodes.append(index)
        return index

    def mesh(self, name: str, primitives: list[dict], weights=None) -> int:
        """A mesh of primitives given as dicts: points, faces, and optional joints/weights (V, 4S) with their
        component types, morph targets (a list of (V, 3) arrays or ("sparse", rows, values))."""
        from pygltflib import Attributes, Mesh, Primitive

        built = []
        for p in primitives:
            attributes = Attributes(POSITION=self.accessor(np.asarray(p["points"], dtype=np.float32)))
            joints, weights_of = p.get("joints"), p.get("weights")
            if joints is not None:
                for s in range(joints.shape[1] // 4):
                    setattr(attributes, f"JOINTS_{s}", self.accessor(joints[:, 4 * s:4 * s + 4],
                                                                     p.get("joint_type", UBYTE)))
                    weight_type = p.get("weight_type", FLOAT)
                    setattr(attributes, f"WEIGHTS_{s}", self.accessor(weights_of[:, 4 * s:4 * s + 4], weight_type,
                                                                      normalized=weight_type != FLOAT))
            targets = []
            for target in p.get("targets", []):
                if isinstance(target, tuple):
                    targets.append({"POSITION": self.accessor(target[1:], sparse_of=len(p["points"]))})
                else:
                    targets.append({"POSITION": self.accessor(np.asarray(target, dtype=np.float32))})
            built.append(Primitive(attributes=attributes, targets=targets or None, mode=4,
                                   indices=self.accessor(np.asarray(p["faces"]).ravel().astype(np.uint16),
                                                         USHORT, "SCALAR")))
        self.gltf.meshes.append(Mesh(name=name, primitives=built, weights=weights))
        return len(self.gltf.meshes) - 1

    def skin(self, joints: list[int], inverse_bind: np.ndarray) -> int:
        from pygltflib import Skin

        stored = np.asarray(inverse_bind, dtype=np.float32).transpose(0, 2, 1).reshape(len(joints), 16)
        self.gltf.skins.append(Skin(joints=joints, inverseBindMatrices=self.accessor(stored, kind="MAT4")))
        return len(self.gltf.skins) - 1

    def animation(self, name: str, channels: list[tuple]) -> None:
        """An animation of (node, path, times, values (K, width) or (K, 3, width) for CUBICSPLINE, interpolation)."""
        from pygltflib import Animation, AnimationChannel, AnimationChannelTarget, AnimationSampler

        animation = Animation(name=name)
        for node, path, times, values, interpolation in channels:
            values = np.asarray(values, dtype=np.float32)
            sampler = AnimationSampler(input=self.accessor(np.asarray(times, dtype=np.float32)),
                                       output=self.accessor(values.reshape(-1), kind="SCALAR") if path == "weights"
                                       else self.accessor(values.reshape(-1, values.shape[-1])),
                                       interpolation=interpolation)
            sampler_input = self.gltf.accessors[sampler.input]
            sampler_input.min, sampler_input.max = [float(np.min(times))], [float(np.max(times))]
            animation.samplers.append(sampler)
            animation.channels.append(AnimationChannel(sampler=len(animation.samplers) - 1,
                                                       target=AnimationChannelTarget(node=node, path=path)))
        self.gltf.animations.append(animation)

    def save(self, path) -> str:
        """Write ``.glb`` (the data in its binary chunk) or ``.gltf`` (the data in ``NAME.bin`` beside it)."""
        from pygltflib import Buffer

        path = str(path)
        if path.endswith(".glb"):
            self.gltf.buffers = [Buffer(byteLength=len(self.blob))]
            self.gltf.set_binary_blob(self.blob)
            self.gltf.save_binary(path)
        else:
            name = os.path.splitext(os.path.basename(path))[0] + ".bin"
            with open(os.path.join(os.path.dirname(path), name), "wb") as fh:
                fh.write(self.blob)
            self.gltf.buffers = [Buffer(byteLength=len(self.blob), uri=name)]
            self.gltf.save_json(path)
        return path


# --- the independent evaluation --------------------------------------------------------------------------------

def _buffers(gltf, path: str) -> list[bytes]:
    out = []
    for buffer in gltf.buffers:
        if buffer.uri is None:
            out.append(gltf.binary_blob())
        elif buffer.uri.startswith("data:"):
            out.append(base64.b64decode(buffer.uri.split(",", 1)[1]))
        else:
            with open(os.path.join(os.path.dirname(str(path)), buffer.uri), "rb") as fh:
                out.append(fh.read())
    return out


def _elements(buffers, gltf, view_index, offset, component, width, count) -> np.ndarray:
    """``count`` elements read one by one from a buffer view (its stride, if any, stepped over)."""
    view = gltf.bufferViews[view_index]
    size = np.dtype(_NUMPY[component]).itemsize * width
    stride = view.byteStride or size
    data = buffers[view.buffer]
    start = (view.byteOffset or 0) + (offset or 0)
    return np.array([np.frombuffer(data, _NUMPY[component], width, start + k * stride) for k in range(count)])


def read_accessor(gltf, buffers, index: int) -> np.ndarray:
    """An accessor as float64 (count, width): normalised integers scaled, sparse values substituted."""
    accessor = gltf.accessors[index]
    width = _SIZE[accessor.type]
    if accessor.bufferView is None:
        values = np.zeros((accessor.count, width))
    else:
        values = _elements(buffers, gltf, accessor.bufferView, accessor.byteOffset, accessor.componentType, width,
                           accessor.count).astype(np.float64)
    if accessor.sparse is not None:
        sparse = accessor.sparse
        rows = _elements(buffers, gltf, sparse.indices.bufferView, sparse.indices.byteOffset,
                         sparse.indices.componentType, 1, sparse.count)[:, 0].astype(int)
        values[rows] = _elements(buffers, gltf, sparse.values.bufferView, sparse.values.byteOffset,
                                 accessor.componentType, width, sparse.count)
    if accessor.normalized:
        values = np.maximum(values / np.iinfo(np.dtype(_NUMPY[accessor.componentType])).max, -1.0)
    return values


def _multiply(a, b):
    """Quaternion product, (x, y, z, w)."""
    (ax, ay, az, aw), (bx, by, bz, bw) = a, b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def _power(q, s):
    """A unit quaternion raised to the power ``s``: its angle times s about its axis."""
    vector, w = q[:3], q[3]
    length = np.linalg.norm(vector)
    if length < 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0])
    half = np.arctan2(length, w)
    return np.concatenate([vector / length * np.sin(s * half), [np.cos(s * half)]])


def slerp(q0, q1, s):
    """``q0 (q0⁻¹ q1)^s`` along the shorter arc."""
    q0, q1 = q0 / np.linalg.norm(q0), q1 / np.linalg.norm(q1)
    if np.dot(q0, q1) < 0:
        q1 = -q1
    inverse = np.array([-q0[0], -q0[1], -q0[2], q0[3]])
    return _multiply(q0, _power(_multiply(inverse, q1), s))


def rodrigues(q) -> np.ndarray:
    """The rotation matrix of a quaternion (x, y, z, w) from its axis and angle."""
    q = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    length = np.linalg.norm(q[:3])
    if length < 1e-15:
        return np.eye(3)
    axis, angle = q[:3] / length, 2 * np.arctan2(length, q[3])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _sample(times, values, interpolation, path, t):
    """One channel at one time, the keys held beyond the ends."""
    keys = values[:, 1] if interpolation == "CUBICSPLINE" else values
    if t <= times[0]:
        return keys[0]
    if t >= times[-1]:
        return keys[-1]
    k = bisect.bisect_right(list(times), t) - 1
    step = times[k + 1] - times[k]
    s = (t - times[k]) / step
    if interpolation == "STEP":
        return keys[k]
    if interpolation == "CUBICSPLINE":
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        value = h00 * keys[k] + h10 * step * values[k, 2] + h01 * keys[k + 1] + h11 * step * values[k + 1, 0]
        return value / np.linalg.norm(value) if path == "rotation" else value
    if path == "rotation":
        return slerp(keys[k], keys[k + 1], s)
    return keys[k] + s * (keys[k + 1] - keys[k])


def _natural(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def reference_frames(path, animation: str | None, times) -> np.ndarray:
    """Every mesh node of the scene (by the natural order of the node names, primitives in file order) posed by the
    animation at ``times`` (seconds): (F, V, 3). With ``animation`` None, the meshes as ``bind`` reads them: their
    positions moved by their nodes' transforms, unskinned (one frame)."""
    from pygltflib import GLTF2

    gltf = GLTF2().load(str(path))
    buffers = _buffers(gltf, path)
    chosen = next(a for a in gltf.animations if a.name == animation) if animation is not None else None
    channels = []
    for channel in chosen.channels if chosen is not None else []:
        sampler = chosen.samplers[channel.sampler]
        keys = read_accessor(gltf, buffers, sampler.input)[:, 0]
        values = read_accessor(gltf, buffers, sampler.output)
        width = {"translation": 3, "rotation": 4, "scale": 3}.get(channel.target.path)
        per_key = 3 if sampler.interpolation == "CUBICSPLINE" else 1
        width = width or values.size // (len(keys) * per_key)
        shaped = values.reshape((len(keys), 3, width) if per_key == 3 else (len(keys), width))
        channels.append((channel.target.node, channel.target.path, keys, shaped, sampler.interpolation))
    parent = {child: n for n, node in enumerate(gltf.nodes) for child in node.children or []}
    scene = gltf.scenes[gltf.scene or 0]
    mesh_nodes = []

    def collect(n):
        if gltf.nodes[n].mesh is not None:
            mesh_nodes.append(n)
        for child in gltf.nodes[n].children or []:
            collect(child)

    for root in scene.nodes:
        collect(root)
    mesh_nodes.sort(key=lambda n: _natural(gltf.nodes[n].name or str(n)))
    frames = []
    for t in times:
        trs = {n: {"translation": node.translation or [0, 0, 0], "rotation": node.rotation or [0, 0, 0, 1],
                   "scale": node.scale or [1, 1, 1], "weights": getattr(node, "weights", None)}
               for n, node in enumerate(gltf.nodes)}
        for node, path_name, keys, values, interpolation in channels:
            trs[node][path_name] = _sample(keys, values, interpolation, path_name, t)
        animated = {c[0] for c in channels if c[1] != "weights"}

        def world(n):
            node = gltf.nodes[n]
            if node.matrix is not None and n not in animated:
                local = np.array(node.matrix, dtype=np.float64).reshape(4, 4).T
            else:
                local = trs_matrix(trs[n]["translation"], trs[n]["rotation"], trs[n]["scale"])
            return local if n not in parent else world(parent[n]) @ local

        parts = []
        for n in mesh_nodes:
            node, mesh = gltf.nodes[n], gltf.meshes[gltf.nodes[n].mesh]
            for primitive in mesh.primitives:
                points = read_accessor(gltf, buffers, primitive.attributes.POSITION)
                morph = trs[n]["weights"] if trs[n]["weights"] is not None else mesh.weights
                morph = None if animation is None else morph  # bind reads the positions as stored
                for k, target in enumerate(primitive.targets or []):
                    if morph is not None and "POSITION" in target:
                        points = points + morph[k] * read_accessor(gltf, buffers, target["POSITION"])
                homogeneous = np.concatenate([points, np.ones((len(points), 1))], axis=1)
                if node.skin is None or animation is None:
                    parts.append((homogeneous @ world(n).T)[:, :3])
                    continue
                skin = gltf.skins[node.skin]
                stored = read_accessor(gltf, buffers, skin.inverseBindMatrices)
                joint_matrices = np.array([world(j) for j in skin.joints]) @ stored.reshape(-1, 4, 4).transpose(0, 2, 1)
                joints, weights, s = [], [], 0
                while getattr(primitive.attributes, f"JOINTS_{s}", None) is not None:
                    joints.append(read_accessor(gltf, buffers, getattr(primitive.attributes, f"JOINTS_{s}")))
                    weights.append(read_accessor(gltf, buffers, getattr(primitive.attributes, f"WEIGHTS_{s}")))
                    s += 1
                joints, weights = np.concatenate(joints, axis=1).astype(int), np.concatenate(weights, axis=1)
                blended = np.einsum("vk,vkij->vij", weights, joint_matrices[joints]) / weights.sum(1)[:, None, None]
                parts.append(np.einsum("vij,vj->vi", blended, homogeneous)[:, :3])
        frames.append(np.concatenate(parts))
    return np.stack(frames)


def key_times_of(path, animation: str) -> np.ndarray:
    """The distinct key times of an animation's samplers."""
    from pygltflib import GLTF2

    gltf = GLTF2().load(str(path))
    buffers = _buffers(gltf, path)
    chosen = next(a for a in gltf.animations if a.name == animation)
    return np.unique(np.concatenate([read_accessor(gltf, buffers, s.input)[:, 0] for s in chosen.samplers]))


def write_usd_skel(path, blend_shape: bool = True) -> str:
    """A UsdSkel asset: /Char (a SkelRoot moved by +0.5 x) with /Char/Skel (3 joints up +y), the animations
    /Char/Bend (the skeleton's own) and /Char/Twist (rotations keyed every 2 time codes, a blend shape's weight every
    5), /Char/Body (a cylinder skinned with 2 influences per point, a blend shape "bulge"), /Char/Prop (an unskinned
    triangle moved by its translate, keyed at 0 and 10) and /Char/Hat (rigidly skinned to the last joint)."""
    from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, "Y")
    stage.SetTimeCodesPerSecond(24)
    root = UsdSkel.Root.Define(stage, "/Char")
    stage.SetDefaultPrim(root.GetPrim())
    UsdGeom.Xformable(root).AddTranslateOp().Set(Gf.Vec3d(0.5, 0, 0))
    skeleton = UsdSkel.Skeleton.Define(stage, "/Char/Skel")
    joints = ["a", "a/b", "a/b/c"]
    skeleton.CreateJointsAttr(joints)
    skeleton.CreateRestTransformsAttr([Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, y, 0)) for y in (0, 1, 1)])
    skeleton.CreateBindTransformsAttr([Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, y, 0)) for y in (0, 1, 2)])
    animations = []
    for name, sign in (("Bend", 1.0), ("Twist", -1.0)):
        animation = UsdSkel.Animation.Define(stage, f"/Char/{name}")
        animation.CreateJointsAttr(joints)
        animation.CreateTranslationsAttr().Set(Vt.Vec3fArray([(0, 0, 0), (0, 1, 0), (0, 1, 0)]))
        animation.CreateScalesAttr().Set(Vt.Vec3hArray([(1, 1, 1)] * 3))
        rotations = animation.CreateRotationsAttr()
        for t in range(0, 11, 2):
            bend, twist = sign * 0.1 * t / 2, sign * 0.1 * t / 3
            rotations.Set(Vt.QuatfArray([Gf.Quatf(1), Gf.Quatf(np.cos(bend), Gf.Vec3f(0, 0, np.sin(bend))),
                                         Gf.Quatf(np.cos(twist), Gf.Vec3f(np.sin(twist), 0, 0))]), t)
        if blend_shape:
            animation.CreateBlendShapesAttr(["bulge"])
            weights = animation.CreateBlendShapeWeightsAttr()
            for t in range(0, 11, 5):
                weights.Set(Vt.FloatArray([sign * t / 10]), t)
        animations.append(animation)
    UsdSkel.BindingAPI.Apply(skeleton.GetPrim()).CreateAnimationSourceRel().SetTargets([animations[0].GetPath()])
    points, faces = cylinder()
    body = UsdGeom.Mesh.Define(stage, "/Char/Body")
    body.CreatePointsAttr(Vt.Vec3fArray(points.tolist()))
    body.CreateFaceVertexCountsAttr([3] * len(faces))
    body.CreateFaceVertexIndicesAttr(faces.ravel().tolist())
    binding = UsdSkel.BindingAPI.Apply(body.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skeleton.GetPath()])
    lower = np.minimum(points[:, 1].astype(int), 2)
    share = 0.5 * (points[:, 1] - lower)
    binding.CreateJointIndicesPrimvar(False, 2).Set(np.stack([lower, np.minimum(lower + 1, 2)], 1).ravel().tolist())
    binding.CreateJointWeightsPrimvar(False, 2).Set(np.stack([1 - share, share], 1).ravel().tolist())
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1))
    if blend_shape:
        shape = UsdSkel.BlendShape.Define(stage, "/Char/Body/bulge")
        shape.CreateOffsetsAttr(Vt.Vec3fArray([(0.2, 0, 0)] * 8))
        shape.CreatePointIndicesAttr(Vt.IntArray(list(range(16, 24))))
        binding.CreateBlendShapesAttr(["bulge"])
        binding.CreateBlendShapeTargetsRel().SetTargets([shape.GetPath()])
    prop = UsdGeom.Mesh.Define(stage, "/Char/Prop")
    prop.CreatePointsAttr(Vt.Vec3fArray([(0, 0, 0), (1, 0, 0), (0, 1, 0)]))
    prop.CreateFaceVertexCountsAttr([3])
    prop.CreateFaceVertexIndicesAttr([0, 1, 2])
    translate = prop.AddTranslateOp()
    for t in (0, 10):
        translate.Set(Gf.Vec3d(0.1 * t, 0, 0), t)
    hat = UsdGeom.Mesh.Define(stage, "/Char/Hat")  # rigidly skinned: one joint for the whole prim
    hat.CreatePointsAttr(Vt.Vec3fArray([(0, 3, 0), (0.4, 3, 0), (0, 3.4, 0), (0, 3, 0.4)]))
    hat.CreateFaceVertexCountsAttr([3, 3, 3, 3])
    hat.CreateFaceVertexIndicesAttr([0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3])
    rigid = UsdSkel.BindingAPI.Apply(hat.GetPrim())
    rigid.CreateSkeletonRel().SetTargets([skeleton.GetPath()])
    rigid.CreateJointIndicesPrimvar(True, 1).Set([2])
    rigid.CreateJointWeightsPrimvar(True, 1).Set([1.0])
    stage.GetRootLayer().Save()
    return str(path)


__all__ = ["SkinnedGltf", "cylinder", "trs_matrix", "rodrigues", "slerp", "read_accessor", "reference_frames",
           "key_times_of", "write_usd_skel"]
