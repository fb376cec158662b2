"""Running a batch: the manifest read, every asset's inputs found and its outputs checked against all of them, the
folder locked, each asset bound (:mod:`.asset`) here or on Ray workers (:mod:`.distributed`), and the summary."""

from __future__ import annotations

import json
import os
import sys

from .. import __version__
from ..errors import WarpStokesError
from ..io.inputs import InputSet, inputs_of
from ..io.outputs import atomic_output, check_output_target, output_folder, remove_stale_temporaries
from .asset import (Result, asset_inputs, bind_one, earlier_records, outputs_of, progress_line, skipped, up_to_date,
                    warn_for)
from .distributed import require_ray, run_on_ray
from .lock import folder_lock
from .manifest import Asset, read_manifest

__all__ = ["Result", "run_batch", "bind_one", "skipped", "earlier_records", "outputs_of", "format_summary", "pace",
           "warn_for", "refuse_outputs_over_inputs", "asset_inputs"]


def run_batch(manifest, outdir, force: bool = False, device=None, progress=True, workers: int | None = None,
              ray_address: str | None = None) -> list[Result]:
    """Bind every asset of a manifest, writing ``<name>.npz`` and, with poses, ``<name>.usd`` to ``outdir``.

    Parameters
    ----------
    manifest : path of a TOML or JSON manifest (see the module docstring)
    outdir : output folder (created if missing)
    force : bool, redo assets whose outputs are up to date with their inputs
    device : None | str
    progress : True for progress lines on stderr, a text stream for them, or None/False for silence
    workers : int, optional, bind in this many Ray worker processes on a local Ray cluster started here (on a GPU
        host, default one per GPU); see :mod:`warp_stokes.batch.distributed`
    ray_address : str, optional, join this Ray cluster (e.g. ``"auto"``) instead of starting one

    Returns
    -------
    list of Result, one per asset; ``summary.json`` in ``outdir`` holds the same

    Raises
    ------
    WarpStokesError
        When another live batch holds the folder's lock, or Ray is asked for and not installed.
    """
    if progress is True:
        progress = sys.stderr
    assets = read_manifest(manifest)
    outdir = os.fspath(outdir)
    distributed = workers is not None or ray_address is not None
    if distributed:
        require_ray()  # before any work or file
    else:
        from ..binding.spread import spread_devices
        from ..device import Backend

        if spread_devices(device) is None:
            device = Backend.of(device).device  # a device this machine lacks: refused before the folder is made
    inputs, unreadable = {}, {}
    for asset in assets:  # an asset whose inputs cannot be read fails alone, below
        try:
            inputs[asset.name] = asset_inputs(asset)
        except WarpStokesError as exc:
            unreadable[asset.name] = str(exc)
    refuse_outputs_over_inputs(assets, outdir, manifest, inputs)
    with output_folder(outdir), folder_lock(outdir):
        remove_stale_temporaries(outdir)  # this package's, of processes gone: a killed batch's
        if distributed:
            results = run_on_ray(assets, outdir, manifest, force, device, progress, workers, ray_address,
                                 inputs, unreadable)
        else:
            results = _run_assets(assets, outdir, force, device, progress, inputs, unreadable)
        _write_json(os.path.join(outdir, "summary.json"), {"warp_stokes_version": __version__,
                                                           "assets": [r.__dict__ for r in results]})
    return results


def refuse_outputs_over_inputs(assets: list[Asset], outdir: str, manifest, inputs: dict) -> None:
    """Before any work: no file the batch writes (each asset's outputs, ``summary.json``) is one it reads (the
    manifest, and every file of every asset's inputs: ``inputs``, asset name -> InputSet), nor exists as anything
    but a regular file. An asset named like its input, written into the input's folder, would replace it.

    Raises
    ------
    WarpStokesError, one line naming the output, what it would replace and whose it is
    """
    read = inputs_of(os.fspath(manifest), error=WarpStokesError)
    read = InputSet({path: "the manifest" for path in read.files})
    for asset in assets:
        if asset.name in inputs:
            read = read.union(inputs[asset.name])
    outputs = [(os.path.join(outdir, "summary.json"), "the batch's summary")]
    outputs += [(path, f"asset {asset.name!r}'s output") for asset in assets for path in outputs_of(asset, outdir)]
    for path, what in outputs:
        whose = read.meets(path)
        if whose is not None:
            raise WarpStokesError(f"{path}: {what} would replace {whose}; write the batch to another folder or "
                                  "rename the asset")
        try:
            check_output_target(path)
        except WarpStokesError as exc:
            raise WarpStokesError(f"{exc} ({what})") from None


def _run_assets(assets, outdir, force, device, progress, inputs: dict, unreadable: dict) -> list[Result]:
    results = []
    digests, current = up_to_date(assets, outdir, force, inputs)
    todo = [asset for asset, done in zip(assets, current) if done is None]
    if progress and todo:  # once the folder is ours (Ray workers compile in their own processes)
        from ..kernel_cache import BIND_MODULES, KERNEL_MODULES, announce_compilation  # (Warp: not for a Ray driver)

        announce_compilation(device, harmonic=any(a.method == "harmonic" for a in todo), stream=progress,
                             # a CPU deforms with BLAS: the deform kernels are a GPU's only
                             modules=KERNEL_MODULES if any(a.poses for a in todo) and getattr(device, "is_cuda", False)
                             else BIND_MODULES)
    for k, asset in enumerate(assets):
        result = current[k]
        if result is None:
            result = bind_one(asset, outdir, device, progress, k, len(assets), inputs=inputs.get(asset.name),
                              unreadable=unreadable.get(asset.name), digest=digests[k])
            warn_for(result)
        if progress:
            progress_line(progress, k + 1, len(assets), asset.name,
                      "up to date, skipped" if result.status == "skipped" else result.status)
        results.append(result)
    return results


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


def pace(results: list[Result], started: float) -> str | None:
    """How soon and how fast the batch bound: the time from ``started`` (seconds since the epoch: the command's
    start) to the first asset done, and the assets a minute from then to the last (the steady pace, without the
    start of Python, Warp or Ray's workers); None when nothing was bound.

    Examples
    --------
    >>> pace([Result("a", "ok", finished=12.0), Result("b", "ok", finished=13.0), Result("c", "ok", finished=14.0)],
    ...      started=10.0)
    'first asset done 2.0 s after the start; then 60 assets a minute (3 bound)'
    """
    ends = sorted(r.finished for r in results if r.finished is not None and r.status != "skipped")
    if not ends:
        return None
    text = f"first asset done {ends[0] - started:.1f} s after the start"
    if len(ends) > 1 and ends[-1] > ends[0]:
        text += f"; then {60.0 * (len(ends) - 1) / (ends[-1] - ends[0]):.0f} assets a minute"
    return text + f" ({len(ends)} bound)"
