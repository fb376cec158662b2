"""Batch binding of many assets from a manifest (TOML or JSON), with animated USD where poses are given.

Manifest (TOML; JSON with the same keys works too, with ``"assets": [...]``)::

    [defaults]            # optional: applies to every asset that does not say otherwise
    resolution = 64
    fps = 24

    [[asset]]
    name = "arm"                  # optional: default is the mesh file's name without extension
    mesh = "arm/arm.obj"          # paths are relative to the manifest's folder
    cage = "arm/arm_cage.obj"
    poses = "arm/walk"            # optional: OBJ frames folder, .npy/.npz or USD (see load_poses)
    resolution = 48               # optional

    [[asset]]                     # a USD asset: all its mesh prims in one solve, the cage a prim of it
    mesh = "hero/hero.usd"
    cage_prim = "/Hero/Rig/Cage"  # in `cage` when given (a USD file), else in the asset
    mesh_prims = ["/Hero/Geo/Body", "/Hero/Geo/Cloth"]   # optional: default every mesh prim but the cage
    poses = "hero/hero.usd"       # the cage prim's time samples; the output is a layer over the asset

For each asset the batch writes ``OUTDIR/<name>.npz`` and, with poses, ``OUTDIR/<name>.usd``. A failing asset
is reported and the batch goes on; an asset whose outputs are newer than its inputs is skipped unless forced.
An asset's outputs are written under temporary names and renamed together at its end, so a killed batch leaves
an asset whole or missing (re-run, it completes what is missing and removes the killed run's temporary files).
One batch at a time writes to a folder: a lock file ``OUTDIR/.warp-stokes.lock`` holds the owner's pid, and a
second batch refuses the folder while that process lives (a lock left by a dead one is taken over).
``OUTDIR/summary.json`` holds the software version and, per asset, its status, error and warnings.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import sys
import time
import traceback
import warnings
from dataclasses import dataclass, field

from . import __version__
from .errors import WarpStokesError
from .io.files import atomic_output

__all__ = ["Asset", "read_manifest", "run_batch", "format_summary"]

ASSET_KEYS = {"name", "mesh", "cage", "poses", "resolution", "fps", "tol", "with_cage", "with_weights", "boundary",
              "sampling", "cage_prim", "mesh_prims", "rest_time"}


class ManifestError(WarpStokesError):
    """The manifest is unreadable or malformed."""


@dataclass
class Asset:
    name: str
    mesh: str
    cage: str | None = None
    poses: str | None = None
    resolution: int = 64
    fps: float | None = None
    cage_prim: str | None = None
    mesh_prims: list | None = None
    rest_time: float | None = None
    tol: float = 1e-6
    boundary: str = "local"
    sampling: str = "hermite"
    with_cage: bool = False
    with_weights: bool = False


@dataclass
class Result:
    name: str
    status: str  # "ok", "skipped" or "failed"
    vertices: int | None = None
    handles: int | None = None
    resolution: int | None = None
    seconds: float = 0.0
    error: str = ""
    outputs: list = field(default_factory=list)
    warnings: list = field(default_factory=list)


LOCK_NAME = ".warp-stokes.lock"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


@contextlib.contextmanager
def folder_lock(outdir: str):
    """Hold ``outdir``'s batch lock: created exclusively with this process's pid; a lock whose process is gone
    is taken over; one held by a live process is a WarpStokesError naming it."""
    path = os.path.join(outdir, LOCK_NAME)
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                with open(path, encoding="utf-8") as fh:
                    owner = int(fh.read().strip() or 0)
            except (OSError, ValueError):
                owner = 0
            if owner and owner != os.getpid() and _alive(owner):
                raise WarpStokesError(
                    f"{outdir}: another batch (pid {owner}) is writing to this folder; wait for it to finish "
                    f"(or remove {path} if that process is not a warp-stokes batch)") from None
            os.unlink(path)  # stale: its batch was killed
            continue
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(str(os.getpid()))
        break
    else:
        raise WarpStokesError(f"{outdir}: could not take the batch lock {path}")
    try:
        yield path
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)


def read_manifest(path) -> list[Asset]:
    """Read a batch manifest (``.toml`` or ``.json``); paths in it are taken relative to its folder.

    Raises
    ------
    ManifestError
        Naming the manifest and the problem (unreadable, unknown keys, missing mesh or cage, duplicate names).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ManifestError(f"{path}: no such file")
    try:
        if path.lower().endswith(".json"):
            with open(path, encoding="utf-8") as fh:
                data = json.load(fh)
        else:
            try:
                import tomllib
            except ModuleNotFoundError:  # Python 3.10
                import tomli as tomllib
            with open(path, "rb") as fh:
                data = tomllib.load(fh)
    except (ValueError, OSError) as exc:
        raise ManifestError(f"{path}: cannot read the manifest ({exc})") from None
    if not isinstance(data, dict):
        raise ManifestError(f"{path}: the manifest must be a table/object with a list of assets")
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
        unknown = set(merged) - ASSET_KEYS
        if unknown:
            raise ManifestError(f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(ASSET_KEYS)}")
        if not isinstance(merged.get("mesh"), str):
            raise ManifestError(f"{where}: 'mesh' (a path) is required")
        if merged.get("cage_prim") is not None and not isinstance(merged["cage_prim"], str):
            raise ManifestError(f"{where}: 'cage_prim' must be a prim path")
        if not isinstance(merged.get("cage"), str) and merged.get("cage_prim") is None:
            raise ManifestError(f"{where}: 'cage' (a path) or 'cage_prim' (a prim of the USD asset) is required")
        if merged.get("cage") is not None and not isinstance(merged["cage"], str):
            raise ManifestError(f"{where}: 'cage' must be a path")
        prims = merged.get("mesh_prims")
        if prims is not None and not (isinstance(prims, list) and prims and all(isinstance(p, str) for p in prims)):
            raise ManifestError(f"{where}: 'mesh_prims' must be a list of prim paths")
        if merged.get("poses") is not None and not isinstance(merged["poses"], str):
            raise ManifestError(f"{where}: 'poses' must be a path")
        if merged.get("boundary", "local") not in ("local", "mvc"):
            raise ManifestError(f"{where}: 'boundary' must be \"local\" or \"mvc\"")
        if merged.get("sampling", "hermite") not in ("hermite", "trilinear"):
            raise ManifestError(f"{where}: 'sampling' must be \"hermite\" or \"trilinear\"")
        for key, kind in (("resolution", int), ("fps", (int, float)), ("tol", (int, float)),
                          ("with_cage", bool), ("with_weights", bool), ("rest_time", (int, float))):
            if key in merged and (not isinstance(merged[key], kind) or (kind is int and isinstance(merged[key], bool))):
                raise ManifestError(f"{where}: '{key}' has the wrong type ({type(merged[key]).__name__})")
        for key in ("mesh", "cage", "poses"):
            if merged.get(key) is not None:
                merged[key] = os.path.join(base, merged[key])
        merged.setdefault("name", os.path.splitext(os.path.basename(merged["mesh"]))[0])
        name = str(merged["name"])
        if not name or any(c in name for c in '/\\:') or name.startswith("."):
            raise ManifestError(f"{where}: '{name}' cannot be a file name")
        if name in names:
            raise ManifestError(f"{where}: the name '{name}' is used twice")
        names.add(name)
        merged["name"] = name
        assets.append(Asset(**merged))
    return assets


def _mtime(path: str) -> float:
    if os.path.isdir(path):
        times = [os.path.getmtime(os.path.join(path, f)) for f in os.listdir(path)]
        return max(times + [os.path.getmtime(path)])
    return os.path.getmtime(path)


def _up_to_date(asset: Asset, outputs: list[str], manifest: str) -> bool:
    if not all(os.path.exists(o) for o in outputs):
        return False
    # the manifest counts as an input: a changed resolution or fps must redo the asset
    inputs = [p for p in (asset.mesh, asset.cage, asset.poses, manifest) if p]
    try:
        newest_input = max(_mtime(p) for p in inputs)
    except OSError:
        return False
    return min(os.path.getmtime(o) for o in outputs) > newest_input


def _progress(stream, k: int, total: int, name: str, stage: str) -> None:
    width = 20
    done = int(width * k / total)
    print(f"[{'#' * done}{'.' * (width - done)}] {k}/{total} {name}: {stage}", file=stream, flush=True)


def run_batch(manifest, outdir, force: bool = False, device=None, progress=True) -> list[Result]:
    """Bind every asset of a manifest, writing ``<name>.npz`` and, with poses, ``<name>.usd`` to ``outdir``.

    Parameters
    ----------
    manifest : path of a TOML or JSON manifest (see the module docstring)
    outdir : output folder (created if missing)
    force : bool, redo assets whose outputs are newer than their inputs
    device : None | str
    progress : True for progress lines on stderr, a text stream for them, or None/False for silence

    Returns
    -------
    list of Result, one per asset; ``summary.json`` in ``outdir`` holds the same

    Raises
    ------
    WarpStokesError
        When another live batch holds the folder's lock.
    """
    if progress is True:
        progress = sys.stderr
    assets = read_manifest(manifest)
    outdir = os.fspath(outdir)
    os.makedirs(outdir, exist_ok=True)
    with folder_lock(outdir):
        # temporary files of a batch killed in this folder (it held the lock, so none is being written now)
        for stale in glob.glob(os.path.join(outdir, ".tmp-*")):
            with contextlib.suppress(OSError):
                os.unlink(stale)
        results = _run_assets(assets, outdir, manifest, force, device, progress)
        _write_json(os.path.join(outdir, "summary.json"), {"warp_stokes_version": __version__,
                                                           "assets": [r.__dict__ for r in results]})
    return results


def _run_assets(assets, outdir, manifest, force, device, progress) -> list[Result]:
    results = []
    for k, asset in enumerate(assets):
        npz = os.path.join(outdir, f"{asset.name}.npz")
        usd = os.path.join(outdir, f"{asset.name}.usd")
        outputs = [npz] + ([usd] if asset.poses else [])
        result = Result(asset.name, "ok", resolution=asset.resolution, outputs=outputs)
        start = time.perf_counter()
        # the outputs under temporary names until the asset is complete, then renamed together
        pending = {path: os.path.join(outdir, f".tmp-{os.path.basename(path)}") for path in outputs}
        caught = []
        try:
            if not force and _up_to_date(asset, outputs, os.fspath(manifest)):
                result.status = "skipped"
                if progress:
                    _progress(progress, k + 1, len(assets), asset.name, "up to date, skipped")
                results.append(result)
                continue
            if progress:
                _progress(progress, k, len(assets), asset.name, "checking the cage")
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                _bind_asset(asset, pending, device, progress, k, len(assets), result)
            for path, tmp in pending.items():
                os.replace(tmp, path)
        except Exception as exc:  # keep going: one asset's failure is reported, not raised
            result.status = "failed"
            known = isinstance(exc, (ValueError, OSError))
            result.error = str(exc) if known else f"{type(exc).__name__}: {exc}"
            if not known and progress:
                traceback.print_exc(file=progress)
        finally:
            for tmp in pending.values():  # an asset is written whole or not at all
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
        # what the bind warned of, in the summary and (once the command has run) on stderr
        result.warnings = list(dict.fromkeys(str(w.message) for w in caught))
        for message in result.warnings:
            warnings.warn(message, stacklevel=2)
        result.seconds = time.perf_counter() - start
        if progress:
            _progress(progress, k + 1, len(assets), asset.name, result.status)
        results.append(result)
    return results


def _bind_asset(asset, pending: dict, device, progress, k: int, total: int, result: Result) -> None:
    """Check, bind and (with poses) animate one asset, writing its outputs to their temporary names
    (``pending``: final path -> temporary path, the binding first)."""
    from .binding import bind
    from .geometry.cage import check_cage
    from .io.poses import load_poses
    from .io.scene import is_usd
    from .io.usd import write_animation
    from .io.usd.asset import read_cage_prim

    npz, *usd = pending
    if asset.cage_prim is not None and (asset.cage is None or is_usd(asset.cage)):
        cage = check_cage(read_cage_prim(asset.cage or asset.mesh, asset.cage_prim, asset.rest_time))
    else:
        cage = check_cage(asset.cage)
    poses = None
    if asset.poses:
        if progress:
            _progress(progress, k, total, asset.name, "reading poses")
        poses = load_poses(asset.poses, cage.faces, cage.n_handles, cage.source_index,
                           cage_prim=asset.cage_prim if is_usd(asset.poses) else None)
    if progress:
        _progress(progress, k, total, asset.name, f"binding at resolution {asset.resolution}")
    binding = bind(asset.mesh, cage, resolution=asset.resolution, device=device, tol=asset.tol,
                   boundary=asset.boundary, sampling=asset.sampling, cage_prim=asset.cage_prim,
                   mesh_prims=asset.mesh_prims, rest_time=asset.rest_time)
    result.vertices, result.handles = binding.n_vertices, binding.n_handles
    if not binding.stats["converged"]:
        raise WarpStokesError(
            f"the solver did not converge (residual {binding.stats['residual']:.2g}, identity error "
            f"{binding.stats['identity_error']:.2g}, tol {asset.tol:g})"
        )
    binding.save(pending[npz])
    if poses is not None:
        if progress:
            _progress(progress, k, total, asset.name, f"writing {len(poses.frames)} frames of USD")
        write_animation(pending[usd[0]], binding, poses, fps=asset.fps, with_cage=asset.with_cage,
                        with_weights=asset.with_weights)


def _write_json(path: str, data) -> None:
    with atomic_output(path, ".json") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=1)


def format_summary(results: list[Result]) -> str:
    """The batch results as a table: asset, status, vertices, handles, resolution, seconds, error."""
    head = ("asset", "status", "vertices", "handles", "resolution", "seconds", "error")
    rows = [head] + [
        (r.name, r.status, str(r.vertices or "-"), str(r.handles or "-"), str(r.resolution or "-"),
         f"{r.seconds:.2f}", r.error)
        for r in results
    ]
    widths = [max(len(row[c]) for row in rows) for c in range(len(head) - 1)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row[:-1], widths)) + "  " + row[-1] for row in rows]
    return "\n".join(line.rstrip() for line in lines)
