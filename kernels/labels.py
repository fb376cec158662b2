"""Node labels of the voxel grid."""

import warp as wp

OUTSIDE = wp.constant(0)  # outside the cage and beyond the band: never read
INTERIOR = wp.constant(1)  # inside the cage (generalised winding number > 1/2): unknowns q, G
RING = wp.constant(2)  # known q and G read by the stencil of an interior node: outside, or inside but cut off by
#                         a thin wedge of outside space (warp_stokes.geometry.grid.voxelize)
BAND = wp.constant(3)  # outside, within the sampling band: known q (the boundary data), read by sampling only
