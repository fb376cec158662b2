"""A glTF animation evaluated as the glTF 2.0 specification says: each channel sampled (LINEAR, with spherical
linear interpolation of rotations; STEP; CUBICSPLINE's Hermite splines), the node hierarchy's world matrices at each
time, and each mesh primitive's vertices posed: morph targets by the node's weights, then linear blend skinning by
its skin's joint matrices ``world(joint) @ inverseBindMatrix`` (the skinned mesh node's own transform is ignored, as
the specification requires), or the node's world matrix for a mesh without a skin.

Matrices here act on column vectors (glTF's convention); arrays of them are (..., 4, 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BindingError
from .gltf_file import GltfFile

__all__ = ["Channel", "animation_channels", "key_times", "world_matrices", "posed_primitive", "quaternion_matrices"]

_WIDTH = {"translation": 3, "rotation": 4, "scale": 3}


@dataclass(frozen=True)
class Channel:
    """One animated property: node ``node``'s ``path`` (translation, rotation, scale or weights) at key ``times``
    (K,), ``values`` (K, width), or (K, 3, width) for CUBICSPLINE (in-tangent, value, out-tangent)."""

    node: int
    path: str
    times: np.ndarray
    values: np.ndarray
    interpolation: str

    def sample(self, times: np.ndarray) -> np.ndarray:
        """The property at ``times`` (F,) as (F, width): held at the first and last keys outside them.

        Examples
        --------
        >>> c = Channel(0, "translation", np.array([0.0, 1.0]), np.array([[0.0, 0, 0], [2.0, 0, 0]]), "LINEAR")
        >>> c.sample(np.array([-1.0, 0.25, 5.0]))[:, 0].tolist()
        [0.0, 0.5, 2.0]
        """
        keys = self.values[:, 1] if self.interpolation == "CUBICSPLINE" else self.values
        times = np.asarray(times, dtype=np.float64)
        if len(self.times) == 1:
            return np.repeat(keys[:1], len(times), axis=0)
        span = np.clip(np.searchsorted(self.times, times, side="right") - 1, 0, len(self.times) - 2)
        t0, t1 = self.times[span], self.times[span + 1]
        s = np.clip((times - t0) / (t1 - t0), 0.0, 1.0)[:, None]
        if self.interpolation == "STEP":
            return np.where(s >= 1.0, keys[span + 1], keys[span])
        if self.interpolation == "CUBICSPLINE":
            step = (t1 - t0)[:, None]
            value = ((2 * s**3 - 3 * s**2 + 1) * keys[span] + (s**3 - 2 * s**2 + s) * step * self.values[span, 2]
                     + (-2 * s**3 + 3 * s**2) * keys[span + 1] + (s**3 - s**2) * step * self.values[span + 1, 0])
        elif self.path == "rotation":
            value = _slerp(keys[span], keys[span + 1], s)
        else:
            value = (1.0 - s) * keys[span] + s * keys[span + 1]
        if self.path == "rotation":
            value = value / np.linalg.norm(value, axis=1, keepdims=True)
        return value


def _slerp(q0: np.ndarray, q1: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (F, 4) by ``s`` (F, 1), along the shorter arc."""
    q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    cosine = np.sum(q0 * q1, axis=1, keepdims=True)
    q1 = np.where(cosine < 0, -q1, q1)  # q and -q are one rotation: take the shorter way between them
    cosine = np.abs(cosine)
    angle = np.arccos(np.clip(cosine, -1.0, 1.0))
    sine = np.sin(angle)
    close = sine < 1e-8  # nearly the same rotation: the chord is the arc
    safe = np.where(close, 1.0, sine)
    w0 = np.where(close, 1.0 - s, np.sin((1.0 - s) * angle) / safe)
    w1 = np.where(close, s, np.sin(s * angle) / safe)
    return w0 * q0 + w1 * q1


def quaternion_matrices(quaternions: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) in glTF's order (x, y, z, w), normalised first.

    Examples
    --------
    >>> turned = quaternion_matrices(np.array([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])) @ [1.0, 0.0, 0.0]
    >>> np.abs(np.round(turned, 12)).tolist()
    [0.0, 1.0, 0.0]
    """
    q = np.asarray(quaternions, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def animation_channels(document: GltfFile, animation: dict, name: str) -> list[Channel]:
    """The channels of ``animation`` (one entry of the document's animations, called ``name`` in messages), each
    checked: a node that exists, a known path, times that increase, as many values as the interpolation needs."""
    samplers = animation.get("samplers") or []
    channels = []
    for k, channel in enumerate(animation.get("channels") or []):
        target = channel.get("target") or {}
        path = target.get("path")
        if path not in ("translation", "rotation", "scale", "weights") or "node" not in target:
            continue  # a pointer or an extension's target (KHR_animation_pointer): not a node's transform
        node = target["node"]
        document.entry("nodes", node, f"animation {name}'s channel {k}")
        sampler_index = channel.get("sampler")
        if not isinstance(sampler_index, int) or not 0 <= sampler_index < len(samplers):
            raise BindingError(f"{document.path}: animation {name}'s channel {k} has no sampler {sampler_index!r}")
        sampler = samplers[sampler_index]
        interpolation = sampler.get("interpolation", "LINEAR")
        if interpolation not in ("LINEAR", "STEP", "CUBICSPLINE"):
            raise BindingError(f"{document.path}: animation {name}'s sampler {sampler_index} has interpolation "
                               f"{interpolation!r}; glTF has LINEAR, STEP and CUBICSPLINE")
        times = document.accessor(sampler.get("input"), f"animation {name}'s sampler {sampler_index}")
        values = document.accessor(sampler.get("output"), f"animation {name}'s sampler {sampler_index}")
        if times.ndim != 1 or len(times) == 0 or not np.isfinite(times).all() or np.any(np.diff(times) <= 0):
            raise BindingError(f"{document.path}: animation {name}'s sampler {sampler_index} has key times that are "
                               "not finite and increasing")
        per_key = 3 if interpolation == "CUBICSPLINE" else 1
        width = _WIDTH.get(path) or (values.size // max(1, len(times) * per_key))
        if values.size != len(times) * per_key * width or not np.isfinite(values).all():
            raise BindingError(f"{document.path}: animation {name}'s sampler {sampler_index} has {values.size} "
                               f"output numbers for {len(times)} keys of {path} ({interpolation}), or some not finite")
        shape = (len(times), 3, width) if per_key == 3 else (len(times), width)
        channels.append(Channel(node, path, times, values.reshape(shape), interpolation))
    return channels


def key_times(channels: list[Channel]) -> np.ndarray:
    """Every key time of the channels, increasing; times closer than float32 tells apart (1e-6 s, or one part in
    1e6 of the time) are one: channels keyed on one frame store its time rounded to float32 each its own way."""
    times = np.unique(np.concatenate([c.times for c in channels])) if channels else np.zeros(0)
    if len(times) < 2:
        return times
    keep = np.concatenate([[True], np.diff(times) > 1e-6 * np.maximum(1.0, np.abs(times[1:]))])
    return times[keep]


def _parents(document: GltfFile) -> np.ndarray:
    """Each node's parent (-1 for a root); a node with two parents, or a cycle, is one error (glTF's nodes form a
    forest)."""
    nodes = document.entries("nodes")
    parents = np.full(len(nodes), -1, dtype=np.int64)
    for n, node in enumerate(nodes):
        for child in node.get("children") or []:
            document.entry("nodes", child, f"node {n}'s children")
            if parents[child] >= 0 or child == n:
                raise BindingError(f"{document.path}: node {child} has two parents (glTF's nodes form a forest)")
            parents[child] = n
    return parents


def _hierarchy_order(document: GltfFile, parents: np.ndarray) -> list[int]:
    """The nodes, each after its parent; a cycle is one error."""
    children = [[] for _ in parents]
    for n, p in enumerate(parents):
        if p >= 0:
            children[p].append(n)
    order, stack = [], [n for n, p in enumerate(parents) if p < 0]
    while stack:
        n = stack.pop()
        order.append(n)
        stack.extend(children[n])
    if len(order) != len(parents):
        raise BindingError(f"{document.path}: its node hierarchy has a cycle")
    return order


def _rest_transforms(document: GltfFile) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Every node's translation, rotation and scale (N, 3/4/3) as the file sets them, and {node: 4 x 4} for nodes set
    by a matrix instead."""
    nodes = document.entries("nodes")
    translation, scale = np.zeros((len(nodes), 3)), np.ones((len(nodes), 3))
    rotation = np.tile([0.0, 0.0, 0.0, 1.0], (len(nodes), 1))
    matrices = {}
    for n, node in enumerate(nodes):
        try:
            if "matrix" in node:
                matrices[n] = np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T  # stored column-major
            translation[n] = node.get("translation", translation[n])
            rotation[n] = node.get("rotation", rotation[n])
            scale[n] = node.get("scale", scale[n])
        except (TypeError, ValueError):
            raise BindingError(f"{document.path}: node {n} has a transform that is not numbers of the right count") \
                from None
    if not (np.isfinite(translation).all() and np.isfinite(rotation).all() and np.isfinite(scale).all()
            and all(np.isfinite(m).all() for m in matrices.values())):
        raise BindingError(f"{document.path}: a node's transform is not finite")
    if np.any(np.linalg.norm(rotation, axis=1) == 0):
        raise BindingError(f"{document.path}: a node's rotation is the zero quaternion")
    return translation, rotation, scale, matrices


def world_matrices(document: GltfFile, channels: list[Channel], times: np.ndarray) -> np.ndarray:
    """Every node's local-to-world matrix at each of ``times``: (F, N, 4, 4).

    Parameters
    ----------
    document : GltfFile
    channels : the animation's channels (:func:`animation_channels`); nodes they do not move keep their own
        transforms
    times : (F,) seconds
    """
    n_frames = len(times)
    translation, rotation, scale, matrices = _rest_transforms(document)
    properties = {name: np.repeat(value[None], n_frames, axis=0)
                  for name, value in (("translation", translation), ("rotation", rotation), ("scale", scale))}
    animated = set()
    for channel in channels:
        if channel.path != "weights":
            properties[channel.path][:, channel.node] = channel.sample(times)
            animated.add(channel.node)
    local = np.zeros((n_frames, len(translation), 4, 4))
    local[..., :3, :3] = quaternion_matrices(properties["rotation"]) * properties["scale"][:, :, None, :]
    local[..., :3, 3] = properties["translation"]
    local[..., 3, 3] = 1.0
    for n, matrix in matrices.items():
        if n not in animated:  # glTF: an animated node has no matrix; one that has both follows its animation
            local[:, n] = matrix
    parents = _parents(document)
    world = local.copy()
    for n in _hierarchy_order(document, parents):
        if parents[n] >= 0:
            world[:, n] = world[:, parents[n]] @ local[:, n]
    return world


def _morph_weights(document: GltfFile, node: int, mesh: dict, channels: list[Channel], times: np.ndarray,
                   n_targets: int) -> np.ndarray:
    """The morph target weights (F, n_targets) of a mesh node: its animation's weights channel, else the node's
    weights, else the mesh's, else zeros."""
    for channel in channels:
        if channel.node == node and channel.path == "weights":
            weights = channel.sample(times)
            if weights.shape[1] != n_targets:
                raise BindingError(f"{document.path}: node {node}'s weights channel has {weights.shape[1]} weights "
                                   f"for {n_targets} morph targets")
            return weights
    default = document.entries("nodes")[node].get("weights", mesh.get("weights"))
    weights = np.zeros(n_targets) if default is None else np.asarray(default, dtype=np.float64)
    if weights.shape != (n_targets,):
        raise BindingError(f"{document.path}: node {node} has {weights.size} morph weights for {n_targets} targets")
    return np.repeat(weights[None], len(times), axis=0)


def _influences(document: GltfFile, attributes: dict, n_vertices: int, n_joints: int, what: str):
    """Every JOINTS_n / WEIGHTS_n set of a primitive side by side: joint indices (V, 4S) and weights (V, 4S)
    normalised to sum one (a vertex of no weight keeps zeros)."""
    joints, weights, s = [], [], 0
    while f"JOINTS_{s}" in attributes and f"WEIGHTS_{s}" in attributes:
        joints.append(document.accessor(attributes[f"JOINTS_{s}"], f"{what}'s JOINTS_{s}", integers=True))
        weights.append(document.accessor(attributes[f"WEIGHTS_{s}"], f"{what}'s WEIGHTS_{s}"))
        s += 1
    if not joints:
        raise BindingError(f"{document.path}: {what} is skinned but has no JOINTS_0 and WEIGHTS_0")
    joints, weights = np.concatenate(joints, axis=1), np.concatenate(weights, axis=1)
    if joints.shape != (n_vertices, 4 * s) or weights.shape != joints.shape:
        raise BindingError(f"{document.path}: {what}'s joints and weights are not four per set for its {n_vertices} "
                           "vertices")
    if not np.isfinite(weights).all() or np.any(weights < 0):
        raise BindingError(f"{document.path}: {what} has weights that are negative or not finite")
    used = weights > 0
    if np.any(used & ((joints < 0) | (joints >= n_joints))):
        raise BindingError(f"{document.path}: {what} names joint {int(joints[used].max())}, its skin has {n_joints}")
    joints = np.where(used, joints, 0)
    total = weights.sum(axis=1, keepdims=True)
    return joints, weights / np.where(total > 0, total, 1.0), total[:, 0] > 0


def _skinned(document: GltfFile, skin_index: int, attributes: dict, points: np.ndarray, world: np.ndarray,
             node: int, what: str) -> np.ndarray:
    """Linear blend skinning of ``points`` (F, V, 3) by skin ``skin_index`` at each frame's world matrices."""
    skin = document.entry("skins", skin_index, what)
    joint_nodes = skin.get("joints") or []
    for joint in joint_nodes:
        document.entry("nodes", joint, f"skin {skin_index}'s joints")
    if "inverseBindMatrices" in skin:
        inverse_bind = document.accessor(skin["inverseBindMatrices"], f"skin {skin_index}'s inverseBindMatrices")
        if inverse_bind.shape != (len(joint_nodes), 16):
            raise BindingError(f"{document.path}: skin {skin_index} has {len(inverse_bind)} inverse bind matrices "
                               f"for {len(joint_nodes)} joints")
        inverse_bind = inverse_bind.reshape(-1, 4, 4).transpose(0, 2, 1)  # stored column-major
    else:
        inverse_bind = np.broadcast_to(np.eye(4), (len(joint_nodes), 4, 4))
    joints, weights, weighted = _influences(document, attributes, points.shape[1], len(joint_nodes), what)
    joint_matrices = world[:, joint_nodes] @ inverse_bind  # (F, J, 4, 4)
    posed = np.zeros_like(points)
    for frame in range(len(points)):
        for k in range(joints.shape[1]):
            m = joint_matrices[frame, joints[:, k]]  # (V, 4, 4)
            moved = np.einsum("vij,vj->vi", m[:, :3, :3], points[frame]) + m[:, :3, 3]
            posed[frame] += weights[:, k, None] * moved
    if not weighted.all():  # no weight at all (glTF asks for a sum of one): the vertex follows its node, unskinned
        rigid = world[:, node]
        loose = points[:, ~weighted]
        posed[:, ~weighted] = np.einsum("fij,fvj->fvi", rigid[:, :3, :3], loose) + rigid[:, None, :3, 3]
    return posed


def posed_primitive(document: GltfFile, node: int, mesh_index: int, primitive_index: int,
                    channels: list[Channel], times: np.ndarray, world: np.ndarray) -> np.ndarray:
    """The world-space vertices (F, V, 3) of one primitive of node ``node``'s mesh at each of ``times``.

    Parameters
    ----------
    document : GltfFile
    node, mesh_index, primitive_index : the mesh node, its mesh and the primitive
    channels : the animation's channels
    times : (F,) seconds
    world : (F, N, 4, 4) the nodes' world matrices at those times (:func:`world_matrices`)

    Returns
    -------
    (F, V, 3) float64: morphed by the node's weights, then skinned by its skin, or moved by its world matrix
    """
    mesh = document.entry("meshes", mesh_index, f"node {node}")
    primitives = mesh.get("primitives") or []
    primitive = primitives[primitive_index]
    what = f"mesh {mesh.get('name', mesh_index)!r} (primitive {primitive_index})"
    attributes = primitive.get("attributes") or {}
    if "POSITION" not in attributes:
        raise BindingError(f"{document.path}: {what} has no POSITION")
    base = document.accessor(attributes["POSITION"], f"{what}'s POSITION")
    targets = primitive.get("targets") or []
    points = np.repeat(base[None], len(times), axis=0)
    if targets:
        weights = _morph_weights(document, node, mesh, channels, times, len(targets))
        for k, target in enumerate(targets):
            if "POSITION" in target:
                offsets = document.accessor(target["POSITION"], f"{what}'s morph target {k}")
                if offsets.shape != base.shape:
                    raise BindingError(f"{document.path}: {what}'s morph target {k} has {len(offsets)} positions for "
                                       f"{len(base)} vertices")
                points += weights[:, k, None, None] * offsets[None]
    skin = document.entries("nodes")[node].get("skin")
    if skin is not None:
        return _skinned(document, skin, attributes, points, world, node, what)
    matrix = world[:, node]
    return np.einsum("fij,fvj->fvi", matrix[:, :3, :3], points) + matrix[:, None, :3, 3]
