"""The package's Warp kernels in Warp's cache: whether a machine has compiled them, and compiling them all at once
(a first run on a machine says so before it waits). ``device`` is a Warp device or its alias."""

from __future__ import annotations

import os
import sys

import warp as wp

__all__ = ["KERNEL_MODULES", "BIND_MODULES", "missing_kernels", "kernels_compiled", "compile_kernels",
           "announce_compilation"]


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


def missing_kernels(device=None, modules=KERNEL_MODULES) -> list[str]:
    """The package's kernel modules among ``modules`` that Warp's kernel cache on this machine does not hold yet for
    the device's kind (CPU object files, or CUDA binaries), in the order given; modules for the other kind are left
    out.

    Examples
    --------
    >>> isinstance(missing_kernels("cpu", ("cg",)), list)
    True
    """
    d = wp.get_device(device)
    cache = wp.config.kernel_cache_dir
    entries = os.listdir(cache) if cache and os.path.isdir(cache) else []
    suffixes = (".cubin", ".ptx") if d.is_cuda else (".o",)

    def cached(module) -> bool:
        folders = [os.path.join(cache, e) for e in entries if e.startswith(f"wp_{module.name}_")]
        return any(f.endswith(suffixes) for folder in folders if os.path.isdir(folder) for f in os.listdir(folder))

    return [name for name in modules if not all(cached(m) for m, _ in _warp_modules((name,), d))]


def kernels_compiled(device=None, modules=KERNEL_MODULES) -> bool:
    """Whether Warp's kernel cache on this machine holds all of the package's kernels ``modules`` for the device's
    kind (:func:`missing_kernels`). A first run compiles them; commands say so before they start.

    Examples
    --------
    >>> isinstance(kernels_compiled("cpu"), bool)
    True
    """
    return not missing_kernels(device, modules)


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


#: what the kernel modules a bind does not always need are for, as the compile notice says
PURPOSES = {"laplace": "harmonic coordinates", "deform": "deforming on a GPU", "sample": "sampling the weights"}


def announce_compilation(device=None, harmonic: bool = False, stream=None, modules=BIND_MODULES) -> None:
    """Before a kernel compilation: one line on ``stream`` (default stderr), so that a wait is not taken for a hang,
    then the compilation itself, all modules at once (:func:`compile_kernels`). Nothing when the cache holds all of
    ``modules`` (a bind's, by default; ``harmonic``: the Laplace kernels count too). The line says "first run on this
    machine" only where none of a bind's kernels is there yet; otherwise it names the modules it compiles and why."""
    resolved = wp.get_device(device)
    modules = tuple(modules) + (("laplace",) if harmonic else ())
    missing = missing_kernels(resolved, modules)
    if not missing:
        return
    took = "5-10 s" if resolved.is_cuda else "about 10 s on a 2-core CPU"
    compiled_here = [m for m in BIND_MODULES if _warp_modules((m,), resolved)]  # a bind's, for this device's kind
    if set(compiled_here) <= set(missing_kernels(resolved, BIND_MODULES)):
        why = f"first run on this machine, {took}; later runs load them from Warp's cache"
    else:
        named = [f"{m} ({PURPOSES[m]})" if m in PURPOSES else m for m in missing]
        why = f"not yet in Warp's cache on this machine: {', '.join(named)}; up to {took}, once"
    print(f"warp-stokes: compiling the kernels for {resolved.alias} ({why})", file=stream or sys.stderr, flush=True)
    compile_kernels(resolved, missing)
