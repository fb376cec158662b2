"""Memory: what a bind may use on a device, the high-water mark of a GPU's pool, and sizes as people read them.
``device`` is a Warp device or its alias."""

from __future__ import annotations

import os

import warp as wp

__all__ = ["available_memory", "reset_peak_memory", "memory_size"]


def available_memory(device=None) -> int:
    """Bytes a bind may use on ``device``: 90% of the free memory of a CUDA device, half the available RAM on
    the CPU."""
    d = wp.get_device(device)
    if d.is_cuda:
        return int(0.9 * d.free_memory)
    try:
        return int(0.5 * os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 8 << 30


#: CU_MEMPOOL_ATTR_USED_MEM_HIGH of the CUDA driver API (cuda.h)
_USED_MEM_HIGH = 8


def reset_peak_memory(device) -> bool:
    """Reset the high-water mark of a CUDA device's memory pool (the one Warp allocates from) to its current use,
    so that ``wp.get_mempool_used_mem_high`` measures what follows. Warp only reads the mark; the driver resets it
    (``cuMemPoolSetAttribute``, which accepts 0 only: the mark then restarts from the current use). Returns False
    where that is not possible (a CPU device, no driver library, the pool not in use): the caller must not trust a
    mark that an earlier, larger peak may have set."""
    import ctypes
    import ctypes.util

    d = wp.get_device(device)
    if not d.is_cuda or not wp.is_mempool_enabled(d):
        return False
    try:
        cuda = ctypes.CDLL(ctypes.util.find_library("cuda") or "libcuda.so.1")
        handle, pool, zero = ctypes.c_int(), ctypes.c_void_p(), ctypes.c_uint64(0)
        if cuda.cuDeviceGet(ctypes.byref(handle), ctypes.c_int(d.ordinal)) != 0:
            return False
        if cuda.cuDeviceGetMemPool(ctypes.byref(pool), handle) != 0:  # the pool the device allocates from now
            return False
        wp.synchronize_device(d)
        return cuda.cuMemPoolSetAttribute(pool, ctypes.c_int(_USED_MEM_HIGH), ctypes.byref(zero)) == 0
    except (OSError, AttributeError):
        return False


def memory_size(n_bytes: float) -> str:
    """Bytes as people read them: GiB from 1 GiB up, else MiB.

    Examples
    --------
    >>> memory_size(3 * 2**30), memory_size(10e6)
    ('3.00 GiB', '9.5 MiB')
    """
    return f"{n_bytes / 2**30:.2f} GiB" if n_bytes >= 2**30 else f"{n_bytes / 2**20:.1f} MiB"
