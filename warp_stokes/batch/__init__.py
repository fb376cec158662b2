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
(one whose inputs cannot even be read included) is reported and the batch goes on; an asset whose binding records
the digest of everything it read and of its entry, as they are now, is skipped unless forced. An asset's outputs
are written under temporary names and renamed together at its end, so a killed batch leaves an asset whole or
missing (re-run, it completes what is missing and removes the temporary files the killed run left, and no other
file). One batch at a time writes to a folder: a lock file ``OUTDIR/.warp-stokes.lock`` names the owner's host and
pid, and a second batch refuses the folder while that process lives (a lock left by a dead one of this host is
taken over; another host's is refused, naming it).
``OUTDIR/summary.json`` holds the software version and, per asset, its status, error, warnings, and where it was
bound (host, pid, device). With ``workers`` or ``ray_address`` the assets are bound in parallel by Ray worker
processes (:mod:`.distributed`; the optional extra ``warp-stokes[ray]``).
"""

from .lock import LOCK_NAME, folder_lock
from .manifest import ASSET_KEYS, Asset, ManifestError, read_manifest
from .run import Result, format_summary, pace, run_batch

__all__ = ["Asset", "Result", "ManifestError", "read_manifest", "run_batch", "format_summary", "pace", "folder_lock",
           "LOCK_NAME", "ASSET_KEYS"]
