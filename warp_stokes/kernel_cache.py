"""The package's Warp kernels in Warp's cache: whether a machine has compiled them, and compiling them all at once
(a first run on a machine says so before it waits). ``device`` is a Warp device or its alias."""

from __future__ import annotations

import os
import sys

import warp as wp

__all__ = ["KERNEL_MODULES", "BIND_MODULES", "kernels_compiled", "compile_kernels", "announce_compilation"]


#: the package's kernel modules (warp_stokes.kernels.*): what a first run on a machine compiles (laplace is left out:
#: only harmonic coordinates compile it)
KERNEL_MODULES = ("cg", "cg_cpu", "checks", "deform", "intersect", "labels", "local_boundary", "multigrid",
                  "multigrid_cpu", "mvc", "sample", "stencil", "stencil_cpu", "voxel")
#: the modules a bind compiles (deforming compiles "deform" on first use: a bind's process never does)
BIND_MODULES = tuple(m for m in KERNEL_MODULES if m != "deform")


def _warp_modules(modules, device) -> list[tuple]:
    """The Warp modules behind the package's kernel modules ``modules`` that run on ``device``'s kind, with the
    block size their kernels launch with (None: Warp's default): each Python module's own, and the modules of its
    kernels compiled alone (``module="unique"``, e.g. the stencil's walks, launched in blocks of ``BLOCK_DIM``). A
    module that names the kinds it runs on (``DEVICE_KINDS``, e.g. the CPU's node loops) is left out elsewhere, and
    so are kernels a module lists as ``CUDA_ONLY`` on a CPU (the GPU's patch walks) and as ``CPU_ONLY`` on a GPU."""
    import importlib

    kind = "cuda" if device.is_cuda else "cpu"
    found = []
    for name in modules:
        if name == "labels":  # constants only: nothing to compile
            continue
        python_module = importlib.import_module(f"{__package__}.kernels.{name}")
        if kind not in getattr(python_module, "DEVICE_KINDS", (kind,)):
            continue
        skipped = getattr(python_module, "CUDA_ONLY" if kind == "cpu" else "CPU_ONLY", ())
        own = wp.get_module(python_module.__name__)
        found.append((own, None))
        block_dim = getattr(python_module, "BLOCK_DIM", None)
        found += [(k.module, block_dim) for k in vars(python_module).values()
                  if isinstance(k, wp.Kernel) and k.module is not own and not any(k is c for c in skipped)]
    return found


def kernels_compiled(device=None, modules=KERNEL_MODULES) -> bool:
    """Whether Warp's kernel cache on this machine holds the package's kernels for the device's kind (CPU object
    files, or CUDA binaries). A first run compiles them; commands say so before they start.

    Examples
    --------
    >>> isinstance(kernels_compiled("cpu"), bool)
    True
    """
    d = wp.get_device(device)
    cache = wp.config.kernel_cache_dir
    if not cache or not os.path.isdir(cache):
        return False
    suffixes = (".cubin", ".ptx") if d.is_cuda else (".o",)
    entries = os.listdir(cache)
    for module, _ in _warp_modules(modules, d):
        prefix = f"wp_{module.name}_"
        folders = [os.path.join(cache, e) for e in entries if e.startswith(prefix)]
        if not any(f.endswith(suffixes) for folder in folders if os.path.isdir(folder) for f in os.listdir(folder)):
            return False
    return True


def compile_kernels(device=None, modules=KERNEL_MODULES, workers: int | None = None) -> None:
    """Compile the package's kernels ``modules`` for ``device`` (or load them from Warp's cache) now, on ``workers``
    threads at once (default: one per CPU core), instead of one module after another at their first launches.

    Examples
    --------
    >>> compile_kernels("cpu", modules=("cg",))
    """
    d = wp.get_device(device)
    by_block = {}
    for module, block_dim in _warp_modules(modules, d):
        by_block.setdefault(block_dim, []).append(module)
    workers = workers or os.cpu_count() or 1
    for block_dim, group in by_block.items():
        wp.force_load(d, modules=group, block_dim=block_dim, max_workers=workers)


def announce_compilation(device=None, harmonic: bool = False, stream=None, modules=BIND_MODULES) -> None:
    """Before a first run's kernel compilation: one line on ``stream`` (default stderr), so that a wait is not taken
    for a hang, then the compilation itself, all modules at once (:func:`compile_kernels`). Nothing when the cache
    holds all of ``modules`` (a bind's, by default; ``harmonic``: the Laplace kernels count too)."""
    resolved = wp.get_device(device)
    modules = tuple(modules) + (("laplace",) if harmonic else ())
    if not kernels_compiled(resolved, modules):
        took = "5-10 s" if resolved.is_cuda else "about 10 s on a 2-core CPU"
        print(f"warp-stokes: compiling the kernels for {resolved.alias} (first run on this machine, {took}; "
              "later runs load them from Warp's cache)", file=stream or sys.stderr, flush=True)
        compile_kernels(resolved, modules)
