"""Variants of the batched 19-point stencil, timed against a device-to-device copy on the same GPU.

    python benchmarks/archive/bench_stencil.py --device cuda:0 --pair ogre --resolutions 128 256

Bytes counted: 32 per (interior node, handle): the packed (q, G) read once and the result written once.
Variants (all read and write the package's (node row, handle) vec4 layout, handles innermost):
  package      warp_stokes.apply_operator (float64 sums, used for residuals): one thread per (handle, patch of
               2 x 2 columns, at most PATCH_LENGTH planes along z), each plane loaded once (16 rows for 4
               nodes) and reduced to per-column terms; launched (handle groups of 32, patches, 32) in blocks
               of 128
  package f32  the same kernel with float32 sums (used in CG and smoothing steps)
  patches L    the float32 kernel with runs cut at L planes
  lines L      the package kernel until the fourth session: one thread per (handle, z line of at most L
               interior nodes), three whole planes (9 loads each) in registers (archive/stencil_variants.py)
  lean L       the line walk keeping only the components each neighbour contributes
               (archive/stencil_variants.py)
  pairs L      one thread walks two neighbouring columns: 12 loads per plane for 2 nodes
               (archive/stencil_variants.py)
  gather f64   one thread per (node, handle), 18 neighbour rows looked up in the 3D index grid, float64 sums
               (the package kernel before the line form)
  gather f32   the same with float32 sums
  table        float32 sums, neighbour rows from a precomputed (node, 18) table
  h4           float32 sums, index-grid lookups, 4 handles per thread (the lookups amortised over 4 handles)
  h4table      float32 sums, neighbour table, 4 handles per thread
Every variant's output is compared with the package kernel's.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import warp as wp

import warp_stokes as ws
from warp_stokes.kernels import stencil

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]  # the earlier forms (lines, lean, pairs) beside it, common.py above
from common import copy_bandwidth, pair, select_device, table_head, table_row, time_kernel  # noqa: E402
import stencil_variants as sv  # noqa: E402

@wp.func
def fetch(field: wp.array2d(dtype=wp.vec4f), row: int, n_rows: int, h: int):
    if row >= 0 and row < n_rows:
        return field[row, h]
    return wp.vec4f(0.0)


@wp.func
def idx(index: wp.array3d(dtype=wp.int32), c: wp.vec3i, di: int, dj: int, dk: int):
    return index[c[0] + di, c[1] + dj, c[2] + dk]


@wp.func
def combine(centre: wp.vec4f, xp: wp.vec4f, xm: wp.vec4f, yp: wp.vec4f, ym: wp.vec4f, zp: wp.vec4f,
            zm: wp.vec4f, edges: float):
    faces = xp[0] + xm[0] + yp[0] + ym[0] + zp[0] + zm[0]
    div = (xp[1] - xm[1]) + (yp[2] - ym[2]) + (zp[3] - zm[3])
    value = 48.0 * centre[0] - 10.0 * faces + edges + 3.0 * div
    gx = xm[1] + 4.0 * centre[1] + xp[1] - 3.0 * (xp[0] - xm[0])
    gy = ym[2] + 4.0 * centre[2] + yp[2] - 3.0 * (yp[0] - ym[0])
    gz = zm[3] + 4.0 * centre[3] + zp[3] - 3.0 * (zp[0] - zm[0])
    return wp.vec4f(value, gx, gy, gz)


def gather_kernel(scalar):
    vec4 = wp.types.vector(length=4, dtype=scalar)

    @wp.kernel(module="unique")
    def gather(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32),
               ijk: wp.array(dtype=wp.vec3i), n_rows: int, out: wp.array2d(dtype=wp.vec4f)):
        n, h = wp.tid()
        c = ijk[n]
        edges = scalar(0.0)
        for a in range(-1, 2, 2):
            for b in range(-1, 2, 2):
                edges += scalar(fetch(field, idx(index, c, a, b, 0), n_rows, h)[0])
                edges += scalar(fetch(field, idx(index, c, a, 0, b), n_rows, h)[0])
                edges += scalar(fetch(field, idx(index, c, 0, a, b), n_rows, h)[0])
        centre = vec4(field[n, h])
        xp = vec4(fetch(field, idx(index, c, 1, 0, 0), n_rows, h))
        xm = vec4(fetch(field, idx(index, c, -1, 0, 0), n_rows, h))
        yp = vec4(fetch(field, idx(index, c, 0, 1, 0), n_rows, h))
        ym = vec4(fetch(field, idx(index, c, 0, -1, 0), n_rows, h))
        zp = vec4(fetch(field, idx(index, c, 0, 0, 1), n_rows, h))
        zm = vec4(fetch(field, idx(index, c, 0, 0, -1), n_rows, h))
        faces = xp[0] + xm[0] + yp[0] + ym[0] + zp[0] + zm[0]
        div = (xp[1] - xm[1]) + (yp[2] - ym[2]) + (zp[3] - zm[3])
        value = scalar(48.0) * centre[0] - scalar(10.0) * faces + edges + scalar(3.0) * div
        gx = xm[1] + scalar(4.0) * centre[1] + xp[1] - scalar(3.0) * (xp[0] - xm[0])
        gy = ym[2] + scalar(4.0) * centre[2] + yp[2] - scalar(3.0) * (yp[0] - ym[0])
        gz = zm[3] + scalar(4.0) * centre[3] + zp[3] - scalar(3.0) * (zp[0] - zm[0])
        out[n, h] = wp.vec4f(wp.float32(value), wp.float32(gx), wp.float32(gy), wp.float32(gz))

    return gather


gather_f64 = gather_kernel(wp.float64)
gather_f32 = gather_kernel(wp.float32)


@wp.kernel
def stencil_table(field: wp.array2d(dtype=wp.vec4f), table: wp.array2d(dtype=wp.int32), n_rows: int,
                  out: wp.array2d(dtype=wp.vec4f)):
    n, h = wp.tid()
    edges = float(0.0)
    for e in range(6, 18):
        edges += fetch(field, table[n, e], n_rows, h)[0]
    out[n, h] = combine(field[n, h], fetch(field, table[n, 0], n_rows, h), fetch(field, table[n, 1], n_rows, h),
                        fetch(field, table[n, 2], n_rows, h), fetch(field, table[n, 3], n_rows, h),
                        fetch(field, table[n, 4], n_rows, h), fetch(field, table[n, 5], n_rows, h), edges)


@wp.kernel
def stencil_h4(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32),
               ijk: wp.array(dtype=wp.vec3i), n_rows: int, out: wp.array2d(dtype=wp.vec4f)):
    n, g = wp.tid()
    c = ijk[n]
    rows = wp.vector(dtype=wp.int32, length=18)
    for e in range(2):
        s = 2 * e - 1
        rows[e] = idx(index, c, -s, 0, 0)
        rows[2 + e] = idx(index, c, 0, -s, 0)
        rows[4 + e] = idx(index, c, 0, 0, -s)
    k = int(6)
    for a in range(-1, 2, 2):
        for b in range(-1, 2, 2):
            rows[k] = idx(index, c, a, b, 0)
            rows[k + 1] = idx(index, c, a, 0, b)
            rows[k + 2] = idx(index, c, 0, a, b)
            k += 3
    for hh in range(4):
        h = 4 * g + hh
        if h < field.shape[1]:
            edges = float(0.0)
            for e in range(6, 18):
                edges += fetch(field, int(rows[e]), n_rows, h)[0]
            out[n, h] = combine(field[n, h], fetch(field, int(rows[0]), n_rows, h),
                                fetch(field, int(rows[1]), n_rows, h), fetch(field, int(rows[2]), n_rows, h),
                                fetch(field, int(rows[3]), n_rows, h), fetch(field, int(rows[4]), n_rows, h),
                                fetch(field, int(rows[5]), n_rows, h), edges)


@wp.kernel
def stencil_h4_table(field: wp.array2d(dtype=wp.vec4f), table: wp.array2d(dtype=wp.int32), n_rows: int,
                     out: wp.array2d(dtype=wp.vec4f)):
    n, g = wp.tid()
    for hh in range(4):
        h = 4 * g + hh
        if h < field.shape[1]:
            edges = float(0.0)
            for e in range(6, 18):
                edges += fetch(field, table[n, e], n_rows, h)[0]
            out[n, h] = combine(field[n, h], fetch(field, table[n, 0], n_rows, h),
                                fetch(field, table[n, 1], n_rows, h), fetch(field, table[n, 2], n_rows, h),
                                fetch(field, table[n, 3], n_rows, h), fetch(field, table[n, 4], n_rows, h),
                                fetch(field, table[n, 5], n_rows, h), edges)


def neighbour_table(grid):
    """(interior nodes, 18) rows of the face neighbours (+x, -x, +y, -y, +z, -z) then the 12 edge neighbours,
    in the order the kernels above sum them."""
    ijk = grid.active_ijk[: grid.n_interior]
    order = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    for a in (-1, 1):
        for b in (-1, 1):
            order += [(a, b, 0), (a, 0, b), (0, a, b)]
    cols = [grid.index[tuple((ijk + np.array(o)).T)] for o in order]
    return np.stack(cols, axis=1).astype(np.int32)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--pair", default="ogre")
    p.add_argument("--resolutions", nargs="+", type=int, default=[128, 256])
    p.add_argument("--handles", type=int, default=None, help="solve this many handles (default: all, up to 128)")
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    device, device_name = select_device(args.device)
    copy = copy_bandwidth(device) / 1e9 if device.is_cuda else float("nan")
    mesh, cage = pair(args.pair)
    cage = ws.check_cage(cage)
    print(f"device {device_name}, copy {copy:.0f} GB/s")
    print(table_head(("n", "handles", "interior", "variant", "ms", "GB/s", "of copy", "max diff")))
    for n in args.resolutions:
        grid = ws.voxelize(cage, n, device=device)
        n_handles = min(cage.n_handles, args.handles or 128)
        field = ws.boundary_field(grid, cage, device=device, handles=slice(0, n_handles))
        n_int = grid.n_interior
        x = field[0:n_int]
        arrays = grid.device_arrays(device)
        table = wp.array(neighbour_table(grid), dtype=wp.int32, device=device)
        reference = wp.empty(x.shape, dtype=wp.vec4f, device=device)
        ws.apply_operator(grid, x, reference, n_rows=n_int, device=device)
        ref = reference.numpy()
        groups = (n_handles + 3) // 4
        variants = {
            "package": lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device),
            "package f32": lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device, precise=False),
        }
        groups32 = (n_handles + stencil.GROUP - 1) // stencil.GROUP
        for length in (32, 128):
            patches = wp.array(grid.interior_patches((stencil.PATCH_I, stencil.PATCH_J), length), dtype=wp.vec4i,
                               device=device)
            variants[f"patches {length}"] = lambda y, patches=patches: wp.launch(
                stencil.apply_operator_fast, dim=(groups32, patches.shape[0], stencil.GROUP),
                inputs=[x, arrays["index"], patches, n_int], outputs=[y], device=device,
                block_dim=stencil.BLOCK_DIM)
        for length in (32, 64, 128, 256):
            lines = wp.array(sv.interior_lines(grid, length), dtype=wp.vec2i, device=device)
            variants[f"lines {length}"] = lambda y, lines=lines: wp.launch(
                sv.apply_lines, dim=(groups32, lines.shape[0], 32),
                inputs=[x, arrays["index"], arrays["active_ijk"], lines, n_int], outputs=[y], device=device)
            variants[f"lean {length}"] = lambda y, lines=lines: wp.launch(
                sv.apply_lean, dim=(groups32, lines.shape[0], 32),
                inputs=[x, arrays["index"], arrays["active_ijk"], lines, n_int], outputs=[y], device=device)
            items = wp.array(sv.pair_items(grid, length), dtype=wp.vec4i, device=device)
            variants[f"pairs {length}"] = lambda y, items=items: wp.launch(
                sv.apply_pairs, dim=(groups32, items.shape[0], 32), inputs=[x, arrays["index"], items, n_int],
                outputs=[y], device=device)
        variants.update({
            "gather f64": lambda y: wp.launch(gather_f64, dim=x.shape, inputs=[x, arrays["index"],
                                                                            arrays["active_ijk"], n_int],
                                              outputs=[y], device=device),
            "gather f32": lambda y: wp.launch(gather_f32, dim=x.shape, inputs=[x, arrays["index"],
                                                                            arrays["active_ijk"], n_int],
                                              outputs=[y], device=device),
            "table": lambda y: wp.launch(stencil_table, dim=x.shape, inputs=[x, table, n_int], outputs=[y],
                                         device=device),
            "h4": lambda y: wp.launch(stencil_h4, dim=(n_int, groups), inputs=[x, arrays["index"],
                                                                               arrays["active_ijk"], n_int],
                                      outputs=[y], device=device),
            "h4table": lambda y: wp.launch(stencil_h4_table, dim=(n_int, groups), inputs=[x, table, n_int],
                                           outputs=[y], device=device),
        })
        for name, launch in variants.items():
            y = wp.full(x.shape, wp.vec4f(np.nan), dtype=wp.vec4f, device=device)
            seconds = time_kernel(device, lambda: launch(y))
            diff = float(np.nanmax(np.abs(y.numpy() - ref))) if np.isfinite(y.numpy()).all() else float("nan")
            gbs = 32 * n_int * n_handles / seconds / 1e9
            print(table_row((n, n_handles, n_int, name, f"{seconds * 1e3:.3f}", f"{gbs:.0f}", f"{gbs / copy:.0%}",
                             f"{diff:.1e}")), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
