"""Warp kernels of warp-stokes, installed as ``warp_stokes.kernels``.

Kernels only: launch code (array allocation, dimensions, devices) lives in the ``warp_stokes`` modules.
Node labels shared by all kernels are defined in :mod:`warp_stokes.kernels.labels`.
"""
