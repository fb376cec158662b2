"""One asset of a batch: what it reads (its inputs' full set), whether its outputs are up to date with them, and its
bind and animation written whole (one group of outputs) or not at all; a failure of any kind is its
:class:`Result`. :mod:`.run` goes through the assets in this process, :mod:`.distributed` on Ray workers."""

from __future__ import annotations

import json
import os
import time
import traceback
import warnings
from dataclasses import dataclass, field

from .. import __version__
from ..errors import WarpStokesError
from ..io.door import reading
from ..io.inputs import InputSet, inputs_of
from ..io.outputs import writing
from .manifest import MADE_CAGE, Asset

__all__ = ["Result", "asset_inputs", "inputs_digest", "digest_now", "outputs_of", "earlier_records", "skipped", "up_to_date",
           "bind_one", "warn_for", "progress_line"]


@dataclass
class Result:
    name: str
    status: str  # "ok", "not converged" (written: exact weights, a residual short of tol), "skipped" or "failed"
    vertices: int | None = None
    handles: int | None = None
    resolution: int | None = None
    seconds: float = 0.0
    error: str = ""
    outputs: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    host: str = ""  # where it was bound: machine, process and Warp device
    pid: int | None = None
    device: str = ""
    skin_error: dict | None = None  # a skin's distance from the deformation: max, rms (over the diagonal), influences
    finished: float | None = None  # when its bind ended (seconds since the epoch, the binding host's clock)


def asset_inputs(asset: Asset) -> InputSet:
    """Every file an asset makes the batch read: its mesh, cage and poses, each USD file's whole layer stack, a
    folder of frames and its frames (:func:`warp_stokes.io.inputs.inputs_of`)."""
    read = InputSet()
    for role, source in (("mesh", asset.mesh), ("cage", _cage_file(asset)), ("poses", asset.poses)):
        read = read.union(inputs_of(source, error=WarpStokesError, role=f"{role} of asset {asset.name!r}"))
    return read


def inputs_digest(asset: Asset, inputs: InputSet) -> str:
    """What an asset's outputs depend on, as one SHA-256: the contents of every file in ``inputs``, the asset's entry
    in the manifest (its settings) and this version of warp-stokes. A binding written by the batch records it; a
    later run redoes the asset when it differs (a sublayer edited, a resolution changed)."""
    import dataclasses
    import hashlib

    entry = json.dumps(dataclasses.asdict(asset), sort_keys=True, default=str)
    return hashlib.sha256(f"{__version__}\0{entry}\0{inputs.digest()}".encode()).hexdigest()


def _up_to_date(outputs: list[str], digest: str) -> bool:
    """Whether every output exists and the binding records ``digest`` and a solve that converged (one that did not
    is redone, and said so again, rather than skipped)."""
    if not all(os.path.isfile(o) for o in outputs):
        return False
    import numpy as np

    from ..binding.stats import BindStats

    try:  # the batch's own output, not an input: read directly
        with np.load(outputs[0], allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
        recorded, converged = meta.get("batch_inputs"), BindStats.from_record(meta["stats"]).converged
    except Exception:  # unreadable or not a binding: redo it
        return False
    return recorded == digest and converged is True


def _cage_file(asset: Asset) -> str | None:
    """The cage file the asset reads (None for a made cage or a cage prim of the mesh's asset)."""
    return None if asset.cage == MADE_CAGE else asset.cage


def progress_line(stream, k: int, total: int, name: str, stage: str) -> None:
    width = 20
    done = int(width * k / total)
    print(f"[{'#' * done}{'.' * (width - done)}] {k}/{total} {name}: {stage}", file=stream, flush=True)


def outputs_of(asset: Asset, outdir: str) -> list[str]:
    """The files an asset writes: ``<name>.npz`` and, with poses, ``<name>.usd`` (baked points, or a UsdSkel rig with
    ``skin = "usd"``) or the glTF skin ``<name>.glb`` / ``.gltf``; with ``cage = "auto"``, the cage made for it,
    ``<name>.cage.obj``."""
    npz = os.path.join(outdir, f"{asset.name}.npz")
    ext = asset.skin if asset.skin in ("glb", "gltf") else "usd"
    return [npz] + ([os.path.join(outdir, f"{asset.name}.{ext}")] if asset.poses else []) + (
        [os.path.join(outdir, f"{asset.name}.cage.obj")] if asset.cage == MADE_CAGE else [])


def earlier_records(outdir: str) -> dict:
    """The records of the assets in ``outdir/summary.json`` by name (empty when there is none, or it is unreadable)."""
    try:
        with open(os.path.join(outdir, "summary.json"), encoding="utf-8") as fh:
            return {r["name"]: r for r in json.load(fh)["assets"] if isinstance(r, dict) and "name" in r}
    except Exception:  # no summary yet, or not one of ours: nothing to keep
        return {}


def digest_now(asset: Asset, inputs: InputSet | None) -> str | None:
    """:func:`inputs_digest` of the asset as its inputs are now; None where they could not be read (the bind then
    says what is wrong)."""
    if inputs is None:
        return None
    try:
        return inputs_digest(asset, inputs)
    except WarpStokesError:  # an input gone or unreadable meanwhile
        return None


def skipped(asset: Asset, outdir: str, force: bool, digest: str | None, earlier: dict | None = None
            ) -> Result | None:
    """The asset's result when its outputs are up to date (and not ``force``): they exist and the binding records
    ``digest``, that of the asset's inputs as they are now (:func:`digest_now`); else None. Status "skipped", with
    the record of the run that wrote its outputs (resolution, vertices, handles, seconds, warnings, where it was
    bound) from ``earlier`` (:func:`earlier_records`) where it has one."""
    outputs = outputs_of(asset, outdir)
    if force or digest is None or not _up_to_date(outputs, digest):
        return None
    result = Result(asset.name, "skipped", resolution=_grid_resolution(asset), outputs=outputs)
    record = (earlier or {}).get(asset.name, {})
    for key in ("resolution", "vertices", "handles", "seconds", "warnings", "host", "pid", "device"):
        if record.get(key) is not None:  # (the resolution "auto" chose, too)
            setattr(result, key, record[key])
    return result


def up_to_date(assets: list[Asset], outdir: str, force: bool, inputs: dict) -> tuple[list, list]:
    """Each asset's :func:`digest_now` (hashed once: the skip and the binding's record both use it) and its
    :func:`skipped` Result where its outputs are up to date, else None. ``inputs``: asset name -> InputSet (an asset
    missing there could not be read: never skipped)."""
    earlier = earlier_records(outdir)
    digests = [digest_now(asset, inputs.get(asset.name)) for asset in assets]
    return digests, [skipped(asset, outdir, force, digest, earlier) for asset, digest in zip(assets, digests)]


def _grid_resolution(asset: Asset) -> int | None:
    """The asset's grid resolution; None for mean value coordinates (no grid)."""
    return None if asset.method == "mvc" else asset.resolution


def bind_one(asset: Asset, outdir: str, device, progress=None, k: int = 0, total: int = 1,
             threads: int | None = None, inputs: InputSet | None = None, unreadable: str | None = None,
             digest: str | None = None) -> Result:
    """Check, bind and (with poses) animate one asset; its outputs are written together (one group of
    :func:`warp_stokes.io.outputs.writing`: the cage, the animation, the binding last), whole or not at all, and
    never over one of its inputs. A failure of any kind is its Result, not an exception; what the bind warned of is
    in ``Result.warnings``. ``threads``: a CPU bind's threads (default: every core). ``inputs``: the asset's input
    set (read here when not given); ``unreadable``: why its inputs could not be read (the asset then fails);
    ``digest``: their :func:`inputs_digest` where the caller has it already (hashed here otherwise)."""
    import socket

    outputs = outputs_of(asset, outdir)
    result = Result(asset.name, "ok", resolution=_grid_resolution(asset), outputs=outputs, host=socket.gethostname(),
                    pid=os.getpid())
    start = time.perf_counter()
    caught = []
    try:
        if unreadable is not None:
            raise WarpStokesError(unreadable)
        if progress:
            progress_line(progress, k, total, asset.name, "checking the cage")
        inputs = asset_inputs(asset) if inputs is None else inputs
        digest = inputs_digest(asset, inputs) if digest is None else digest
        order = outputs[2:] + outputs[1:2] + outputs[:1]  # the binding renamed last: never one without its cage
        with warnings.catch_warnings(record=True) as caught, reading(), writing(order, inputs):
            warnings.simplefilter("always")
            _bind_asset(asset, outputs, device, progress, k, total, result, threads, digest)
    except Exception as exc:  # keep going: one asset's failure is reported, not raised
        result.status = "failed"
        result.outputs = []  # none was written
        known = isinstance(exc, (ValueError, OSError))
        result.error = str(exc) if known else f"{type(exc).__name__}: {exc}"
        if not known and progress:
            traceback.print_exc(file=progress)
    result.warnings = list(dict.fromkeys(str(w.message) for w in caught))
    result.seconds = time.perf_counter() - start
    result.finished = time.time()
    return result


def warn_for(result: Result) -> None:
    """What an asset's bind warned of, warned of again naming the asset (the summary keeps the messages as they
    were); on stderr once the command has run."""
    for message in result.warnings:
        warnings.warn(f"{result.name}: {message}", stacklevel=3)


def _bind_asset(asset, outputs: list, device, progress, k: int, total: int, result: Result,
                threads: int | None = None, digest: str | None = None) -> None:
    """Check, bind and (with poses) animate one asset, writing ``outputs`` (:func:`outputs_of`: the binding first)
    within the asset's group of outputs; the binding records ``digest``."""
    from ..binding.pipeline import bind
    from ..geometry.cage import check_cage
    from ..io.poses import load_poses
    from ..io.mesh_out import write_cage_file
    from ..io.scene import is_usd
    from ..io.usd import write_animation
    from ..io.usd.asset import read_cage_prim

    npz, *usd = outputs
    if asset.cage == MADE_CAGE:
        from ..binding.spread import driver_device, spread_devices
        from ..geometry.cage_making import make_cage
        from ..io.scene import load_scene

        usd, made = [], usd[0]
        if progress:
            progress_line(progress, k, total, asset.name, "making a cage")
        surface = load_scene(asset.mesh, mesh_prims=asset.mesh_prims, rest_time=asset.rest_time,
                             looks=False).surface()
        spread = spread_devices(device)
        cage = make_cage(surface, handles=asset.handles, device=device if spread is None else driver_device(spread),
                         offset=asset.offset)  # bind records it
    elif asset.cage_prim is not None and (asset.cage is None or is_usd(asset.cage)):
        cage = check_cage(read_cage_prim(asset.cage or asset.mesh, asset.cage_prim, asset.rest_time))
    else:
        cage = check_cage(asset.cage)
    poses = None
    if asset.poses:
        if progress:
            progress_line(progress, k, total, asset.name, "reading poses")
        poses = load_poses(asset.poses, cage.faces, cage.n_handles, cage.source_index,
                           cage_prim=asset.cage_prim if is_usd(asset.poses) else None)
    if progress:
        progress_line(progress, k, total, asset.name, "binding by mean value coordinates" if asset.method == "mvc"
                      else f"binding at resolution {asset.resolution}")
    binding = bind(asset.mesh, cage, resolution=asset.resolution, device=device, tol=asset.tol,
                   boundary=asset.boundary, sampling=asset.sampling, method=asset.method, cage_prim=asset.cage_prim,
                   mesh_prims=asset.mesh_prims, rest_time=asset.rest_time, threads=threads)
    result.vertices, result.handles = binding.n_vertices, binding.n_handles
    result.resolution = binding.settings["resolution"]  # the number "auto" chose
    result.device = binding.stats.device
    if not binding.stats.converged:  # exact weights (bind raises otherwise), a residual short of tol: written
        stats = binding.stats
        result.status = "not converged"
        result.error = (f"the solver did not reach tol {asset.tol:g} (relative residual {stats.solver.residual:.2g}); "
                        f"partition of unity within {stats.partition_of_unity_error:.2g}, linear precision within "
                        f"{stats.linear_precision_error:.2g} of the diagonal")
    if asset.cage == MADE_CAGE:
        write_cage_file(made, binding.cage_vertices, binding.cage_faces)
    binding.batch_inputs = digest
    binding.save(npz)
    if poses is not None and asset.skin:
        from ..binding.skin import write_skin

        if progress:
            progress_line(progress, k, total, asset.name, f"writing a skin of {len(poses.frames)} frames")
        report = write_skin(usd[0], binding, poses, influences=asset.influences,
                            non_negative=asset.non_negative, max_error=asset.max_error, fps=asset.fps,
                            with_cage=asset.with_cage)
        result.skin_error = {"max": report.error.max, "rms": report.error.rms, "influences": report.influences}
    elif poses is not None:
        if progress:
            progress_line(progress, k, total, asset.name, f"writing {len(poses.frames)} frames of USD")
        write_animation(usd[0], binding, poses, fps=asset.fps, with_cage=asset.with_cage,
                        with_weights=asset.with_weights)
