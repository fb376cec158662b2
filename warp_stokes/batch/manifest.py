"""Batch manifests (TOML, or JSON with the same keys): the assets to bind, checked before any work."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass

from ..arguments import FLOAT32_MAX, FLOAT32_TINY
from ..errors import WarpStokesError
from ..io.door import read_input, reason

__all__ = ["Asset", "ManifestError", "read_manifest", "ASSET_KEYS", "MADE_CAGE"]

ASSET_KEYS = {"name", "mesh", "cage", "poses", "resolution", "fps", "tol", "with_cage", "with_weights", "boundary",
              "sampling", "cage_prim", "mesh_prims", "rest_time", "method", "skin", "influences", "non_negative",
              "max_error", "handles", "offset"}
#: ``cage`` value for a cage made for the mesh (``warp-stokes cage``), written as ``<name>.cage.obj`` beside the
#: binding
MADE_CAGE = "auto"
#: the longest asset name, in bytes: its outputs' names (``<name>.cage.obj``) stay within the file systems' 255
NAME_BYTES = 240
#: ``skin`` values: the animation as a UsdSkel rig (``<name>.usd``) or a glTF skin (``<name>.glb`` / ``.gltf``)
SKINS = ("usd", "glb", "gltf")


class ManifestError(WarpStokesError):
    """The manifest is unreadable or malformed."""


@dataclass
class Asset:
    name: str
    mesh: str
    cage: str | None = None  # a path, or MADE_CAGE
    poses: str | None = None
    resolution: int | str = "auto"
    fps: float | None = None
    cage_prim: str | None = None
    mesh_prims: list | None = None
    rest_time: float | None = None
    tol: float = 1e-6
    boundary: str = "local"
    sampling: str = "hermite"
    method: str = "stokes"
    with_cage: bool = False
    with_weights: bool = False
    skin: str | None = None
    influences: int | None = None
    non_negative: bool | None = None
    max_error: float | None = None
    handles: int | None = None  # a made cage's (cage = "auto")
    offset: float | None = None


def _read_data(path: str) -> dict:
    """The manifest's contents, a JSON object or a TOML document."""
    raw = read_input(path, ManifestError, "manifest")
    try:
        text = raw.decode("utf-8-sig")
        if path.lower().endswith(".json"):
            data = json.loads(text)
        else:
            try:
                import tomllib
            except ModuleNotFoundError:  # Python 3.10
                import tomli as tomllib
            data = tomllib.loads(text)
    except (ValueError, RecursionError) as exc:  # UnicodeDecodeError and TOML's and JSON's errors are ValueErrors
        raise ManifestError(f"{path}: cannot read the manifest ({reason(exc)})") from None
    if not isinstance(data, dict):
        raise ManifestError(f"{path}: the manifest must be a table/object with a list of assets")
    return data


def _checked_entry(merged: dict, where: str) -> None:
    """One asset's keys (defaults merged in): known, present where required, of the right types."""
    unknown = set(merged) - ASSET_KEYS
    if unknown:
        raise ManifestError(f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(ASSET_KEYS)}")
    if not isinstance(merged.get("mesh"), str):
        raise ManifestError(f"{where}: 'mesh' (a path) is required")
    if merged.get("cage_prim") is not None and not isinstance(merged["cage_prim"], str):
        raise ManifestError(f"{where}: 'cage_prim' must be a prim path")
    if not isinstance(merged.get("cage"), str) and merged.get("cage_prim") is None:
        raise ManifestError(f"{where}: 'cage' (a path, or \"auto\" to make one) or 'cage_prim' (a prim of the USD "
                            "asset) is required")
    if merged.get("cage") is not None and not isinstance(merged["cage"], str):
        raise ManifestError(f"{where}: 'cage' must be a path or \"auto\"")
    if merged.get("cage") == MADE_CAGE:
        if merged.get("cage_prim") is not None:
            raise ManifestError(f"{where}: cage \"auto\" and 'cage_prim': give one of them")
        if merged.get("poses") is not None:
            raise ManifestError(f"{where}: 'poses' move a cage's handles, and cage \"auto\" has none until it is "
                                "made; bind it, then animate poses of the made cage (<name>.cage.obj)")
    else:
        made_keys = [key for key in ("handles", "offset") if merged.get(key) is not None]
        if made_keys:
            raise ManifestError(f"{where}: {', '.join(repr(k) for k in made_keys)} shape a made cage: set cage = "
                                "\"auto\"")
    prims = merged.get("mesh_prims")
    if prims is not None and not (isinstance(prims, list) and prims and all(isinstance(p, str) for p in prims)):
        raise ManifestError(f"{where}: 'mesh_prims' must be a list of prim paths")
    if merged.get("poses") is not None and not isinstance(merged["poses"], str):
        raise ManifestError(f"{where}: 'poses' must be a path")
    if merged.get("boundary", "local") not in ("local", "mvc"):
        raise ManifestError(f"{where}: 'boundary' must be \"local\" or \"mvc\"")
    if merged.get("method", "stokes") not in ("stokes", "harmonic", "mvc"):
        raise ManifestError(f"{where}: 'method' must be \"stokes\", \"harmonic\" or \"mvc\"")
    if merged.get("sampling", "hermite") not in ("hermite", "trilinear"):
        raise ManifestError(f"{where}: 'sampling' must be \"hermite\" or \"trilinear\"")
    if merged.get("skin") is not None and merged["skin"] not in SKINS:
        raise ManifestError(f"{where}: 'skin' must be one of {', '.join(repr(s) for s in SKINS)} (a UsdSkel rig or a "
                            f"glTF skin instead of baked points), got {merged['skin']!r}")
    skin_keys = [key for key in ("influences", "non_negative", "max_error") if merged.get(key) is not None]
    if skin_keys and merged.get("skin") is None:
        raise ManifestError(f"{where}: {', '.join(repr(k) for k in skin_keys)} set without 'skin'")
    if merged.get("skin") is not None and merged.get("with_weights"):
        raise ManifestError(f"{where}: 'with_weights' with 'skin': a skin carries its weights as joint weights")
    if merged.get("skin") in ("glb", "gltf") and merged.get("with_cage"):
        raise ManifestError(f"{where}: 'with_cage' with a glTF skin: only a USD rig carries the cage")
    if merged.get("skin") is not None and merged.get("poses") is None:
        raise ManifestError(f"{where}: 'skin' animates the poses; give 'poses'")
    for key, kind in (("resolution", (int, str)), ("fps", (int, float)), ("tol", (int, float)),
                      ("with_cage", bool), ("with_weights", bool), ("rest_time", (int, float)),
                      ("influences", int), ("non_negative", bool), ("max_error", (int, float)), ("handles", int),
                      ("offset", (int, float))):
        value = merged.get(key)
        if key in merged and (not isinstance(value, kind) or (kind is not bool and isinstance(value, bool))):
            raise ManifestError(f"{where}: '{key}' has the wrong type ({type(merged[key]).__name__})")
    # the ranges the command line takes, checked before any work (not found per asset after others were bound)
    for key, ok, expected in (("resolution", lambda v: v == "auto" if isinstance(v, str) else 8 <= v <= 2048,
                               "\"auto\" or an integer from 8 to 2048"),
                              ("tol", lambda v: 0 < v <= 0.1, "in (0, 0.1]"),
                              ("fps", lambda v: math.isfinite(v) and v > 0, "a positive number"),
                              ("rest_time", math.isfinite, "a finite time code"),
                              ("influences", lambda v: v >= 1, "a positive integer"),
                              ("max_error", lambda v: math.isfinite(v) and v > 0,
                               "a positive fraction of the diagonal"),
                              ("handles", lambda v: v >= 8, "at least 8"),
                              ("offset", lambda v: math.isfinite(v) and 0 < v <= 0.5,
                               "a fraction of the diagonal in (0, 0.5]")):
        if key in merged and not ok(merged[key]):
            raise ManifestError(f"{where}: '{key}' must be {expected}, got {merged[key]!r}")
    for key in ("fps", "tol", "rest_time", "max_error", "offset"):  # as every number the package takes as a float
        value = merged.get(key)
        if isinstance(value, float) and value != 0 and not FLOAT32_TINY <= abs(value) <= FLOAT32_MAX:
            raise ManifestError(f"{where}: '{key}' must be within float32's range ({FLOAT32_TINY:.3g} to "
                                f"{FLOAT32_MAX:.3g}), got {value!r}")


def read_manifest(path) -> list[Asset]:
    """Read a batch manifest (``.toml`` or ``.json``); paths in it are taken relative to its folder.

    Raises
    ------
    ManifestError
        Naming the manifest and the problem (unreadable, unknown keys, missing mesh or cage, duplicate names).
    """
    path = os.fspath(path)
    data = _read_data(path)
    unknown = sorted(set(data) - {"defaults", "asset", "assets"})
    if unknown:  # a [default] table (for [defaults]) was ignored, and every asset bound with the built-in settings
        raise ManifestError(f"{path}: unknown top-level key(s) {unknown}; known: 'defaults', 'asset' (TOML) or "
                            "'assets' (JSON)")
    if "asset" in data and "assets" in data:
        raise ManifestError(f"{path}: both 'asset' and 'assets' lists; give the assets in one of them")
    defaults = data.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ManifestError(f"{path}: 'defaults' must be a table/object")
    entries = data.get("asset", data.get("assets"))
    if not isinstance(entries, list) or not entries:
        raise ManifestError(f"{path}: no assets (use [[asset]] tables in TOML, or an \"assets\" list in JSON)")
    base = os.path.dirname(os.path.abspath(path))
    assets, names = [], set()
    for k, entry in enumerate(entries):
        where = f"{path}: asset {k + 1}"
        if not isinstance(entry, dict):
            raise ManifestError(f"{where}: must be a table/object")
        merged = {**defaults, **entry}
        _checked_entry(merged, where)
        for key in ("mesh", "cage", "poses"):
            if merged.get(key) is not None and not (key == "cage" and merged[key] == MADE_CAGE):
                if "\0" in merged[key] or not merged[key]:
                    raise ManifestError(f"{where}: '{key}' {merged[key]!r} is not a path")
                merged[key] = os.path.join(base, merged[key])
        merged.setdefault("name", os.path.splitext(os.path.basename(merged["mesh"]))[0])
        name = merged["name"]
        if not isinstance(name, str) or not name or any(c in name for c in '/\\:') or name.startswith(".") or \
                not name.isprintable() or len(os.fsencode(name)) > NAME_BYTES:
            raise ManifestError(f"{where}: {name!r} cannot be a file name (printable, at most {NAME_BYTES} bytes, no "
                                "slash, backslash or colon, not starting with a dot)")
        if name in names:
            raise ManifestError(f"{where}: the name '{name}' is used twice")
        names.add(name)
        merged["name"] = name
        assets.append(Asset(**merged))
    return assets
