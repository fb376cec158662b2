"""Experiments on the stencil kernel's form, measured on an H100 (benchmarks/HISTORY.md, "What limits the stencil").

None of these kernels is used by the package; they record what was tried and measured against its kernel
(``warp_stokes.kernels.stencil``, float32 sums unless named f64): until the fourth session the line walk now
kept as ``lines`` in stencil_variants.py, since then the 2 x 2 patch walk that the ``patches`` mode found.
Every variant's output is compared with the package kernel's (float64 sums) in the "max diff" column. Modes,
from the repository root:

    python benchmarks/archive/stencil_experiments.py forms  --pair ogre --resolutions 128 256
        walk    the line walk along any axis (generic: bounds-checked loads, vec3i steps), lines cut at L
        lockstep  bricks of bi x bj columns walking their common z range, one line per column, padded
        tiles   shared-memory planes (Warp tiles, tile_scatter_masked): a block = 32 handles x bi x bj columns
    python benchmarks/archive/stencil_experiments.py bricks --pair ogre --resolutions 128 256
        the line walk with its lines cut at absolute multiples of L and ordered by bricks of bi x bj
        columns (a block's consecutive lines form a patch), launched with block_dim threads; and the "pairs"
        variant of stencil_variants.py in the same order
    python benchmarks/archive/stencil_experiments.py regs   --pair ogre --resolutions 128 256
        the line walk (and pairs) compiled with register caps (cuda_max_registers) and other block sizes
    ncu --clock-control none -k regex:"apply_operator|apply_tiles|walk" --launch-skip 8 --launch-count 8 \
        --section SpeedOfLight --section MemoryWorkloadAnalysis --section Occupancy --section LaunchStats \
        --section WarpStateStats python benchmarks/archive/stencil_experiments.py profile --pair ogre --resolutions 256
        each form launched once after a warm-up launch, for Nsight Compute

The tile kernel runs on the CPU only with ``wp.config.enable_cpu_blocks`` (set CPU_BLOCKS=1), which is how its
output was checked before the GPU run.
"""
import argparse
import os
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import warp as wp

import warp_stokes as ws
from warp_stokes.kernels import stencil

if os.environ.get("CPU_BLOCKS"):
    wp.config.enable_cpu_blocks = True

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]  # stencil_variants.py here, common.py in benchmarks/
from common import copy_bandwidth, pair, time_kernel  # noqa: E402
import stencil_variants as sv  # noqa: E402


@wp.func
def value_at(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
             k: int, h: int):
    if i < 0 or j < 0 or k < 0 or i >= index.shape[0] or j >= index.shape[1] or k >= index.shape[2]:
        return wp.vec4f()
    row = index[i, j, k]
    if row >= 0 and row < n_rows:
        return field[row, h]
    return wp.vec4f()


# ------------------------------------------------------------------------------------------------------------
# walk kernel: lines given as (i, j, k, length) along axis W; writes only interior nodes (row < n_out)

def walk_kernel(W, grid_stride=True, prefetch=False):
    U = (W + 1) % 3
    V = (W + 2) % 3
    eu = wp.vec3i(*[1 if a == U else 0 for a in range(3)])
    ev = wp.vec3i(*[1 if a == V else 0 for a in range(3)])
    ew = wp.vec3i(*[1 if a == W else 0 for a in range(3)])
    cu, cv, cw = 1 + U, 1 + V, 1 + W

    @wp.func
    def at(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, p: wp.vec3i, h: int):
        return value_at(field, index, n_rows, p[0], p[1], p[2], h)

    @wp.func
    def load(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, p: wp.vec3i,
             h: int):
        pl = sv.Plane()
        pl.centre = at(field, index, n_rows, p, h)
        pl.xp = at(field, index, n_rows, p + eu, h)
        pl.xm = at(field, index, n_rows, p - eu, h)
        pl.yp = at(field, index, n_rows, p + ev, h)
        pl.ym = at(field, index, n_rows, p - ev, h)
        pl.corners = wp.vec4f(at(field, index, n_rows, p + eu + ev, h)[0], at(field, index, n_rows, p + eu - ev, h)[0],
                              at(field, index, n_rows, p - eu + ev, h)[0], at(field, index, n_rows, p - eu - ev, h)[0])
        return pl

    @wp.func
    def combine(below: sv.Plane, mid: sv.Plane, above: sv.Plane):
        c = mid.centre
        xp = mid.xp
        xm = mid.xm
        yp = mid.yp
        ym = mid.ym
        zp = above.centre
        zm = below.centre
        corners = mid.corners
        edges = (corners[0] + corners[1]) + (corners[2] + corners[3])
        edges += (above.xp[0] + above.xm[0]) + (above.yp[0] + above.ym[0])
        edges += (below.xp[0] + below.xm[0]) + (below.yp[0] + below.ym[0])
        faces = xp[0] + xm[0] + yp[0] + ym[0] + zp[0] + zm[0]
        divergence = (xp[cu] - xm[cu]) + (yp[cv] - ym[cv]) + (zp[cw] - zm[cw])
        out = wp.vec4f()
        out[0] = 48.0 * c[0] - 10.0 * faces + edges + 3.0 * divergence
        out[cu] = xm[cu] + 4.0 * c[cu] + xp[cu] - 3.0 * (xp[0] - xm[0])
        out[cv] = ym[cv] + 4.0 * c[cv] + yp[cv] - 3.0 * (yp[0] - ym[0])
        out[cw] = zm[cw] + 4.0 * c[cw] + zp[cw] - 3.0 * (zp[0] - zm[0])
        return out

    @wp.kernel(module="unique", grid_stride=grid_stride)
    def walk(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), items: wp.array(dtype=wp.vec4i),
             n_rows: int, n_out: int, out: wp.array2d(dtype=wp.vec4f)):
        g, s, lane = wp.tid()
        h = g * 32 + lane
        if h >= field.shape[1]:
            return
        it = items[s]
        if it[3] == 0:
            return
        p = wp.vec3i(it[0], it[1], it[2])
        below = load(field, index, n_rows, p - ew, h)
        mid = load(field, index, n_rows, p, h)
        for t in range(it[3]):
            q = p + t * ew
            above = load(field, index, n_rows, q + ew, h)
            row = index[q[0], q[1], q[2]]
            if row >= 0 and row < n_out:
                out[row, h] = combine(below, mid, above)
            below = mid
            mid = above

    return walk


def walk_items(grid, W, L):
    """(i, j, k, length) runs of interior nodes along axis W, cut at L (not aligned)."""
    ijk = grid.active_ijk[: grid.n_interior].astype(np.int64)
    others = [a for a in range(3) if a != W]
    order = np.lexsort((ijk[:, W], ijk[:, others[1]], ijk[:, others[0]]))
    s = ijk[order]
    new = np.ones(len(s), bool)
    new[1:] = (s[1:, others[0]] != s[:-1, others[0]]) | (s[1:, others[1]] != s[:-1, others[1]]) | (s[1:, W] != s[:-1, W] + 1)
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], len(s))
    pieces = -(-(ends - starts) // L)
    first = np.repeat(starts, pieces)
    first += L * (np.arange(pieces.sum()) - np.repeat(np.cumsum(pieces) - pieces, pieces))
    lengths = np.minimum(first + L, np.repeat(ends, pieces)) - first
    return np.concatenate([s[first], lengths[:, None]], axis=1).astype(np.int32)


def brick_items(grid, bi, bj, L):
    """Lockstep bricks along z: each brick of bi x bj columns and an absolute k block of L walks the common
    k range of its interior nodes; one item per column (padded with empty items)."""
    ijk = grid.active_ijk[: grid.n_interior].astype(np.int64)
    key = np.stack([ijk[:, 0] // bi, ijk[:, 1] // bj, ijk[:, 2] // L], 1)
    u, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    kmin = np.full(len(u), 1 << 30)
    kmax = np.full(len(u), -1)
    np.minimum.at(kmin, inv, ijk[:, 2])
    np.maximum.at(kmax, inv, ijk[:, 2])
    ci, cj = np.meshgrid(np.arange(bi), np.arange(bj), indexing="ij")
    ci, cj = ci.ravel(), cj.ravel()
    i = (u[:, 0:1] * bi + ci[None]).ravel()
    j = (u[:, 1:2] * bj + cj[None]).ravel()
    k = np.repeat(kmin, bi * bj)
    length = np.repeat(kmax - kmin + 1, bi * bj)
    ok = (i < grid.shape[0]) & (j < grid.shape[1])
    length[~ok] = 0
    i[~ok] = 0
    j[~ok] = 0
    items = np.stack([i, j, k, length], 1).astype(np.int32)
    bricks = np.stack([u[:, 0] * bi, u[:, 1] * bj, kmin, kmax + 1], 1).astype(np.int32)
    return items, bricks


# ------------------------------------------------------------------------------------------------------------
# tile kernel: a block = 32 handles x (BI x BJ) columns walking its brick's k range, planes shared in smem

def tile_kernel(BI, BJ):
    T = BI * BJ
    HJ = BJ + 2
    HALO = (BI + 2) * HJ
    ROUNDS = -(-HALO // T)
    SIZE = HALO * 32
    SHIFT = HJ * 32

    @wp.func
    def fill(tile: wp.tile(dtype=wp.vec4f, shape=(SIZE,)), field: wp.array2d(dtype=wp.vec4f),
             index: wp.array3d(dtype=wp.int32), n_rows: int, i0: int, j0: int, k: int, col: int, lane: int,
             h: int, live: int):
        for r in range(ROUNDS):
            s = col + r * T
            has = s < HALO
            v = wp.vec4f()
            if has and live != 0:
                v = value_at(field, index, n_rows, i0 - 1 + s // HJ, j0 - 1 + s % HJ, k, h)
            wp.tile_scatter_masked(tile, s * 32 + lane, v, has)

    @wp.kernel(module="unique")
    def apply_tiles(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32),
                    bricks: wp.array(dtype=wp.vec4i), n_rows: int, n_out: int, out: wp.array2d(dtype=wp.vec4f)):
        b, g, tid = wp.tid()
        lane = tid % 32
        col = tid // 32
        h = g * 32 + lane
        live = int(0)
        if h < field.shape[1]:
            live = 1
        br = bricks[b]
        i0 = br[0]
        j0 = br[1]
        k0 = br[2]
        k1 = br[3]
        ci = col // BJ
        cj = col % BJ
        i = i0 + ci
        j = j0 + cj
        sc = ((ci + 1) * HJ + cj + 1) * 32 + lane
        ta = wp.tile_zeros(shape=(SIZE,), dtype=wp.vec4f, storage="shared")
        tb = wp.tile_zeros(shape=(SIZE,), dtype=wp.vec4f, storage="shared")
        c_below = wp.vec4f()
        c_mid = wp.vec4f()
        s_below = float(0.0)
        s_mid = float(0.0)
        in_mid = wp.vec4f()
        n_planes = k1 - k0 + 2
        for step in range((n_planes + 1) // 2):
            for half in range(2):
                k = k0 - 1 + 2 * step + half
                c = wp.vec4f()
                xp = wp.vec4f()
                xm = wp.vec4f()
                yp = wp.vec4f()
                ym = wp.vec4f()
                corners = float(0.0)
                if half == 0:
                    fill(ta, field, index, n_rows, i0, j0, k, col, lane, h, live)
                    c = ta[sc]
                    xp = ta[sc + SHIFT]
                    xm = ta[sc - SHIFT]
                    yp = ta[sc + 32]
                    ym = ta[sc - 32]
                    corners = (ta[sc + SHIFT + 32][0] + ta[sc + SHIFT - 32][0]) + (
                        ta[sc - SHIFT + 32][0] + ta[sc - SHIFT - 32][0])
                else:
                    fill(tb, field, index, n_rows, i0, j0, k, col, lane, h, live)
                    c = tb[sc]
                    xp = tb[sc + SHIFT]
                    xm = tb[sc - SHIFT]
                    yp = tb[sc + 32]
                    ym = tb[sc - 32]
                    corners = (tb[sc + SHIFT + 32][0] + tb[sc + SHIFT - 32][0]) + (
                        tb[sc - SHIFT + 32][0] + tb[sc - SHIFT - 32][0])
                s4 = (xp[0] + xm[0]) + (yp[0] + ym[0])
                inplane = wp.vec4f(
                    48.0 * c[0] - 10.0 * s4 + corners + 3.0 * ((xp[1] - xm[1]) + (yp[2] - ym[2])),
                    xm[1] + 4.0 * c[1] + xp[1] - 3.0 * (xp[0] - xm[0]),
                    ym[2] + 4.0 * c[2] + yp[2] - 3.0 * (yp[0] - ym[0]),
                    4.0 * c[3],
                )
                node = k - 1
                if node >= k0 and node < k1 and live != 0:
                    row = index[i, j, node]
                    if row >= 0 and row < n_out:
                        value = in_mid[0] - 10.0 * (c[0] + c_below[0]) + s4 + s_below + 3.0 * (c[3] - c_below[3])
                        gz = c_below[3] + in_mid[3] + c[3] - 3.0 * (c[0] - c_below[0])
                        out[row, h] = wp.vec4f(value, in_mid[1], in_mid[2], gz)
                c_below = c_mid
                s_below = s_mid
                c_mid = c
                s_mid = s4
                in_mid = inplane

    return apply_tiles


def tile_bricks(grid, bi, bj, L):
    _, bricks = brick_items(grid, bi, bj, L)
    # clip columns beyond the grid are handled by index bounds in value_at; outputs need i < nx: guard by
    # bricks never exceeding the grid (interior nodes are >= 2 from the edges, columns past nx have none)
    return bricks


class Case:
    """One (cage, resolution): the grid, the starting field's interior block x, and the package kernel's
    float64-sum result on it (the reference every variant is compared with)."""

    def __init__(self, cage, n, device):
        self.n, self.device = n, device
        self.grid = ws.voxelize(cage, n, device=device)
        self.n_handles = cage.n_handles
        self.n_int = self.grid.n_interior
        self.x = ws.boundary_field(self.grid, cage, device=device)[0 : self.n_int]
        self.arrays = self.grid.device_arrays(device)
        self.lines = wp.array(sv.interior_lines(self.grid), dtype=wp.vec2i, device=device)
        self.groups = -(-self.n_handles // 32)
        ref = wp.empty(self.x.shape, dtype=wp.vec4f, device=device)
        ws.apply_operator(self.grid, self.x, ref, n_rows=self.n_int, device=device)
        self.reference = ref.numpy()

    def line_walk(self, block_dim=256, kernel=None):
        """A launch of the line walk (the package kernel until the fourth session) over lines of 128."""
        kernel = kernel or sv.apply_lines
        return lambda y: wp.launch(kernel, dim=(self.groups, self.lines.shape[0], 32),
                                   inputs=[self.x, self.arrays["index"], self.arrays["active_ijk"], self.lines,
                                           self.n_int], outputs=[y], device=self.device, block_dim=block_dim)

    def measure(self, variants, copy, only=None):
        """Time each launch(y) and print a table row: bandwidth at 32 bytes per (interior node, handle)."""
        for name, launch in variants.items():
            if only and not re.search(only, name):
                continue
            y = wp.full(self.x.shape, wp.vec4f(np.nan), dtype=wp.vec4f, device=self.device)
            try:
                seconds = time_kernel(self.device, lambda: launch(y))
            except Exception as e:  # noqa: BLE001 (a variant that does not launch is a result too)
                print(f"| {self.n} | {self.n_handles} | {self.n_int} | {name} | failed: {str(e)[:200]} |", flush=True)
                continue
            yn = y.numpy()
            diff = float(np.abs(yn - self.reference).max()) if np.isfinite(yn).all() else float("nan")
            gbs = 32 * self.n_int * self.n_handles / seconds / 1e9
            print(f"| {self.n} | {self.n_handles} | {self.n_int} | {name} | {seconds * 1e3:.3f} | {gbs:.0f} | "
                  f"{gbs / copy:.0%} | {diff:.1e} |", flush=True)


def start(only=False):
    """Parse the mode's arguments, measure the copy, load the pair and print the table head."""
    p = argparse.ArgumentParser()
    p.add_argument("--pair", default="ogre")
    p.add_argument("--resolutions", nargs="+", type=int, default=[128, 256])
    p.add_argument("--device", default="cuda:0")
    if only:
        p.add_argument("--only", default=None, help="regular expression: run the variants whose name matches")
    args = p.parse_args(sys.argv[2:])
    warnings.simplefilter("ignore")
    device = ws.resolve_device(args.device)
    copy = copy_bandwidth(device) / 1e9 if device.is_cuda else float("nan")
    _, cage = pair(args.pair)
    cage = ws.check_cage(cage)
    print(f"device {ws.device_name(device)}, copy {copy:.0f} GB/s, pair {args.pair}", flush=True)
    print("| n | handles | interior | variant | ms | GB/s | of copy | max diff |")
    print("|---|---|---|---|---|---|---|---|", flush=True)
    return args, device, copy, cage


def main_forms():
    args, device, copy, cage = start(only=True)
    walks = {}
    for n in args.resolutions:
        case = Case(cage, n, device)
        grid, x, arrays, n_int, groups = case.grid, case.x, case.arrays, case.n_int, case.groups
        V = {}
        V["package f32"] = lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device, precise=False)
        V["package f64"] = lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device)
        for bd in (256, 128, 512):
            V[f"lines f32 bd{bd}"] = case.line_walk(bd)
        longest = int(np.argmax(grid.shape))
        for W, L, gs in [(2, 128, True), (2, 128, False), (longest, 128, True), (longest, 64, True), (longest, 256, True)]:
            key = (W, gs)
            if key not in walks:
                walks[key] = walk_kernel(W, grid_stride=gs)
            items = wp.array(walk_items(grid, W, L), dtype=wp.vec4i, device=device)
            V[f"walk axis{W} L{L}{'' if gs else ' lean'} ({items.shape[0]} lines)"] = (
                lambda y, items=items, kern=walks[key]: wp.launch(
                    kern, dim=(groups, items.shape[0], 32),
                    inputs=[x, arrays["index"], items, n_int, n_int], outputs=[y], device=device))
        if (2, True) not in walks:
            walks[(2, True)] = walk_kernel(2)
        for bi, bj, L in [(2, 4, 64), (4, 2, 64), (4, 4, 64), (1, 8, 64), (8, 1, 64)]:
            items, _ = brick_items(grid, bi, bj, L)
            items = wp.array(items, dtype=wp.vec4i, device=device)
            bd = 32 * bi * bj
            V[f"lockstep {bi}x{bj} L{L}"] = (lambda y, items=items, bd=bd: wp.launch(
                walks[(2, True)], dim=(groups, items.shape[0], 32),
                inputs=[x, arrays["index"], items, n_int, n_int], outputs=[y], device=device, block_dim=bd))
        for bi, bj, L in [(2, 4, 64), (4, 4, 64), (4, 4, 32), (8, 4, 64), (4, 8, 64)]:
            try:
                kern = tile_kernel(bi, bj)
                bricks = wp.array(tile_bricks(grid, bi, bj, L), dtype=wp.vec4i, device=device)
                V[f"tiles {bi}x{bj} L{L}"] = (lambda y, kern=kern, bricks=bricks, bd=32 * bi * bj: wp.launch_tiled(
                    kern, dim=(bricks.shape[0], groups), inputs=[x, arrays["index"], bricks, n_int, n_int],
                    outputs=[y], device=device, block_dim=bd))
            except Exception as e:  # noqa: BLE001
                print("tile kernel failed to build:", bi, bj, e, flush=True)
        case.measure(V, copy, args.only)


def brick_lines(grid, bi, bj, L):
    """(first row, length) runs of interior nodes along z, cut at absolute multiples of L, ordered by brick
    (i // bi, j // bj, k // L) and then (i % bi, j % bj): a block's consecutive lines form a bi x bj patch."""
    ijk = grid.active_ijk[: grid.n_interior].astype(np.int64)
    new = np.ones(len(ijk), bool)
    new[1:] = (ijk[1:, 0] != ijk[:-1, 0]) | (ijk[1:, 1] != ijk[:-1, 1]) | (ijk[1:, 2] != ijk[:-1, 2] + 1) | (
        ijk[1:, 2] % L == 0)
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], len(ijk))
    s = ijk[starts]
    order = np.lexsort((s[:, 1] % bj, s[:, 0] % bi, s[:, 2] // L, s[:, 1] // bj, s[:, 0] // bi))
    return np.stack([starts[order], (ends - starts)[order]], 1).astype(np.int32)


def pair_brick_items(grid, bi, bp, L):
    """sv.pair_items cut at absolute multiples of L and ordered by (i // bi, pair // bp, k // L)."""
    items = sv.pair_items(grid, 100000).astype(np.int64)
    out = []
    for i, j, k, n in items:
        k_end = k + n
        while k < k_end:
            stop = min(k_end, (k // L + 1) * L)
            out.append((i, j, k, stop - k))
            k = stop
    out = np.array(out, np.int64)
    order = np.lexsort(((out[:, 1] // 2) % bp, out[:, 0] % bi, out[:, 2] // L, (out[:, 1] // 2) // bp, out[:, 0] // bi))
    return out[order].astype(np.int32)


def main_bricks():
    args, device, copy, cage = start()
    for n in args.resolutions:
        case = Case(cage, n, device)
        grid, x, arrays, n_int, groups = case.grid, case.x, case.arrays, case.n_int, case.groups
        V = {"package f32": lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device, precise=False),
             "lines f32": case.line_walk()}
        configs = [(1, 8, 128, 256), (1, 8, 64, 256), (2, 4, 64, 256), (2, 4, 128, 256), (4, 2, 64, 256),
                   (2, 2, 64, 128), (2, 2, 128, 128), (1, 4, 128, 128), (4, 4, 64, 512), (2, 8, 64, 512),
                   (2, 4, 32, 256), (2, 4, 64, 128), (4, 4, 64, 256)]
        for bi, bj, L, bd in configs:
            lines = wp.array(brick_lines(grid, bi, bj, L), dtype=wp.vec2i, device=device)
            for kern, tag in ((sv.apply_lines, "f32"), (sv.apply_lines_f64, "f64")):
                if tag == "f64" and (bi, bj, L, bd) not in [(2, 4, 64, 256), (2, 2, 64, 128), (2, 4, 128, 256)]:
                    continue
                V[f"brick {bi}x{bj} L{L} bd{bd} {tag}"] = (lambda y, lines=lines, bd=bd, kern=kern: wp.launch(
                    kern, dim=(groups, lines.shape[0], 32),
                    inputs=[x, arrays["index"], arrays["active_ijk"], lines, n_int], outputs=[y], device=device,
                    block_dim=bd))
        for bi, bp, L, bd in [(1, 8, 64, 256), (2, 4, 64, 256), (2, 2, 64, 128), (4, 2, 64, 256), (2, 4, 128, 256)]:
            items = wp.array(pair_brick_items(grid, bi, bp, L), dtype=wp.vec4i, device=device)
            V[f"pairs brick {bi}x{bp}p L{L} bd{bd}"] = (lambda y, items=items, bd=bd: wp.launch(
                sv.apply_pairs, dim=(groups, items.shape[0], 32), inputs=[x, arrays["index"], items, n_int],
                outputs=[y], device=device, block_dim=bd))
        case.measure(V, copy)


def rekernel(kernel, **options):
    """The same kernel function compiled with other options (registers, launch bounds)."""
    return wp.kernel(kernel.func, module="unique", **options)


def main_regs():
    args, device, copy, cage = start()
    kernels = {"lines f32": (sv.apply_lines, 256)}
    for regs in (48, 56, 64, 72):
        kernels[f"f32 maxreg{regs}"] = (rekernel(sv.apply_lines, cuda_max_registers=regs), 256)
    kernels["f32 maxreg64 bd128"] = (rekernel(sv.apply_lines, cuda_max_registers=64), 128)
    kernels["f32 maxreg64 bd512"] = (rekernel(sv.apply_lines, cuda_max_registers=64), 512)
    kernels["lines f64"] = (sv.apply_lines_f64, 256)
    kernels["f64 maxreg64"] = (rekernel(sv.apply_lines_f64, cuda_max_registers=64), 256)
    kernels["f64 maxreg72"] = (rekernel(sv.apply_lines_f64, cuda_max_registers=72), 256)
    pairs_k = {"pairs": sv.apply_pairs, "pairs maxreg64": rekernel(sv.apply_pairs, cuda_max_registers=64),
               "pairs maxreg72": rekernel(sv.apply_pairs, cuda_max_registers=72)}
    for n in args.resolutions:
        case = Case(cage, n, device)
        grid, x, arrays, n_int, groups = case.grid, case.x, case.arrays, case.n_int, case.groups
        V = {}
        for L in (64, 128):
            lines = wp.array(sv.interior_lines(grid, L), dtype=wp.vec2i, device=device)
            for name, (kern, bd) in kernels.items():
                V[f"{name} L{L}"] = (lambda y, kern=kern, bd=bd, lines=lines: wp.launch(
                    kern, dim=(groups, lines.shape[0], 32),
                    inputs=[x, arrays["index"], arrays["active_ijk"], lines, n_int], outputs=[y], device=device,
                    block_dim=bd))
            items = wp.array(sv.pair_items(grid, L), dtype=wp.vec4i, device=device)
            for name, kern in pairs_k.items():
                V[f"{name} L{L}"] = (lambda y, items=items, kern=kern: wp.launch(
                    kern, dim=(groups, items.shape[0], 32), inputs=[x, arrays["index"], items, n_int],
                    outputs=[y], device=device))
        case.measure(V, copy)


def main_profile():
    p = argparse.ArgumentParser()
    p.add_argument("--pair", default="ogre")
    p.add_argument("--resolutions", nargs=1, type=int, default=[256])
    p.add_argument("--device", default="cuda:0")
    args = p.parse_args(sys.argv[2:])
    warnings.simplefilter("ignore")
    device = ws.resolve_device(args.device)
    mesh, cage = pair(args.pair)
    cage = ws.check_cage(cage)
    grid = ws.voxelize(cage, args.resolutions[0], device=device)
    field = ws.boundary_field(grid, cage, device=device)
    n_int = grid.n_interior
    x = field[0:n_int]
    arrays = grid.device_arrays(device)
    y = wp.empty(x.shape, dtype=wp.vec4f, device=device)
    groups = -(-cage.n_handles // 32)

    def lines_of(bi, bj, L, bd):
        lines = wp.array(brick_lines(grid, bi, bj, L), dtype=wp.vec2i, device=device)
        return lambda: wp.launch(sv.apply_lines, dim=(groups, lines.shape[0], 32),
                                 inputs=[x, arrays["index"], arrays["active_ijk"], lines, n_int], outputs=[y],
                                 device=device, block_dim=bd)

    walk = walk_kernel(2)
    items = wp.array(brick_items(grid, 2, 4, 64)[0], dtype=wp.vec4i, device=device)
    tiles = tile_kernel(4, 4)
    bricks = wp.array(tile_bricks(grid, 4, 4, 64), dtype=wp.vec4i, device=device)
    plain = wp.array(sv.interior_lines(grid), dtype=wp.vec2i, device=device)
    launches = [
        lambda: ws.apply_operator(grid, x, y, n_rows=n_int, device=device, precise=False),
        lambda: wp.launch(sv.apply_lines, dim=(groups, plain.shape[0], 32),
                          inputs=[x, arrays["index"], arrays["active_ijk"], plain, n_int], outputs=[y], device=device),
        lambda: wp.launch(walk, dim=(groups, items.shape[0], 32), inputs=[x, arrays["index"], items, n_int, n_int],
                          outputs=[y], device=device, block_dim=256),
        lambda: wp.launch_tiled(tiles, dim=(bricks.shape[0], groups), inputs=[x, arrays["index"], bricks, n_int, n_int],
                                outputs=[y], device=device, block_dim=512),
        lines_of(2, 4, 64, 256), lines_of(2, 2, 64, 128), lines_of(4, 4, 64, 512), lines_of(1, 8, 128, 256),
    ]
    for launch in launches + launches:  # the first round compiles and warms up
        launch()
    wp.synchronize_device(device)


# ------------------------------------------------------------------------------------------------------------
# layout: the package's line walk over component planes instead of packed vec4 rows

@wp.func
def planes_rc(field: wp.array3d(dtype=wp.float32), row: int, c: int, h: int):
    return field[row, c, h]


@wp.func
def planes_cr(field: wp.array3d(dtype=wp.float32), row: int, c: int, h: int):
    return field[c, row, h]


@wp.struct
class Flat:
    """A plane around a column as the stencil uses it: (q, G) at the column, (q, Gx) at +-x, (q, Gy) at +-y,
    and the sum of q over the four diagonal neighbours."""

    centre: wp.vec4f
    x: wp.vec4f  # q(+x), Gx(+x), q(-x), Gx(-x)
    y: wp.vec4f  # q(+y), Gy(+y), q(-y), Gy(-y)
    corners: wp.float32


def planar_kernel(get, scalar=wp.float32):
    """The package's walk (lines along z, planes in registers) reading only the components each neighbour
    contributes: 16 floats per new plane against 9 packed vec4 rows (36 floats' worth of sectors)."""

    @wp.func
    def pair_at(field: wp.array3d(dtype=wp.float32), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int,
                j: int, k: int, c: int, h: int):
        row = index[i, j, k]
        if row >= 0 and row < n_rows:
            return wp.vec2f(get(field, row, 0, h), get(field, row, c, h))
        return wp.vec2f()

    @wp.func
    def q_at(field: wp.array3d(dtype=wp.float32), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
             k: int, h: int):
        row = index[i, j, k]
        if row >= 0 and row < n_rows:
            return get(field, row, 0, h)
        return wp.float32(0.0)

    @wp.func
    def load(field: wp.array3d(dtype=wp.float32), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
             k: int, h: int):
        p = Flat()
        row = index[i, j, k]
        if row >= 0 and row < n_rows:
            p.centre = wp.vec4f(get(field, row, 0, h), get(field, row, 1, h), get(field, row, 2, h),
                                get(field, row, 3, h))
        xp = pair_at(field, index, n_rows, i + 1, j, k, 1, h)
        xm = pair_at(field, index, n_rows, i - 1, j, k, 1, h)
        yp = pair_at(field, index, n_rows, i, j + 1, k, 2, h)
        ym = pair_at(field, index, n_rows, i, j - 1, k, 2, h)
        p.x = wp.vec4f(xp[0], xp[1], xm[0], xm[1])
        p.y = wp.vec4f(yp[0], yp[1], ym[0], ym[1])
        up = q_at(field, index, n_rows, i + 1, j + 1, k, h) + q_at(field, index, n_rows, i + 1, j - 1, k, h)
        down = q_at(field, index, n_rows, i - 1, j + 1, k, h) + q_at(field, index, n_rows, i - 1, j - 1, k, h)
        p.corners = up + down
        return p

    @wp.func
    def put(out: wp.array3d(dtype=wp.float32), row: int, c: int, h: int, v: scalar):
        if wp.static(get is planes_rc):
            out[row, c, h] = wp.float32(v)
        else:
            out[c, row, h] = wp.float32(v)

    @wp.kernel(module="unique")
    def apply_planar(field: wp.array3d(dtype=wp.float32), index: wp.array3d(dtype=wp.int32),
                     interior_ijk: wp.array(dtype=wp.vec3i), lines: wp.array(dtype=wp.vec2i), n_rows: int,
                     n_handles: int, out: wp.array3d(dtype=wp.float32)):
        g, s, lane = wp.tid()
        h = g * 32 + lane
        if h >= n_handles:
            return
        line = lines[s]
        start = line[0]
        ijk = interior_ijk[start]
        i = ijk[0]
        j = ijk[1]
        k = ijk[2]
        below = load(field, index, n_rows, i, j, k - 1, h)
        mid = load(field, index, n_rows, i, j, k, h)
        three = scalar(3.0)
        four = scalar(4.0)
        for t in range(line[1]):
            above = load(field, index, n_rows, i, j, k + t + 1, h)
            edges = scalar(mid.corners) + (scalar(above.x[0]) + scalar(above.x[2])) + (
                scalar(above.y[0]) + scalar(above.y[2]))
            edges += (scalar(below.x[0]) + scalar(below.x[2])) + (scalar(below.y[0]) + scalar(below.y[2]))
            faces = (scalar(mid.x[0]) + scalar(mid.x[2])) + (scalar(mid.y[0]) + scalar(mid.y[2])) + (
                scalar(above.centre[0]) + scalar(below.centre[0]))
            div = (scalar(mid.x[1]) - scalar(mid.x[3])) + (scalar(mid.y[1]) - scalar(mid.y[3])) + (
                scalar(above.centre[3]) - scalar(below.centre[3]))
            row = start + t
            put(out, row, 0, h, scalar(48.0) * scalar(mid.centre[0]) - scalar(10.0) * faces + edges + three * div)
            put(out, row, 1, h, scalar(mid.x[3]) + four * scalar(mid.centre[1]) + scalar(mid.x[1])
                - three * (scalar(mid.x[0]) - scalar(mid.x[2])))
            put(out, row, 2, h, scalar(mid.y[3]) + four * scalar(mid.centre[2]) + scalar(mid.y[1])
                - three * (scalar(mid.y[0]) - scalar(mid.y[2])))
            put(out, row, 3, h, scalar(below.centre[3]) + four * scalar(mid.centre[3]) + scalar(above.centre[3])
                - three * (scalar(above.centre[0]) - scalar(below.centre[0])))
            below = mid
            mid = above

    return apply_planar


def main_layout():
    """The walk over (rows, 4, H) and (4, rows, H) planes, handles padded to multiples of P."""
    args, device, copy, cage = start(only=True)
    kernels = {"rc": planar_kernel(planes_rc), "cr": planar_kernel(planes_cr),
               "rc f64": planar_kernel(planes_rc, wp.float64)}
    for n in args.resolutions:
        case = Case(cage, n, device)
        grid, x, arrays, n_int, groups = case.grid, case.x, case.arrays, case.n_int, case.groups
        H = case.n_handles
        xn = x.numpy()  # (rows, H, 4)
        V = {"package f32": lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device, precise=False),
             "package f64": lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device),
             "lines f32": case.line_walk()}
        case.measure(V, copy, args.only)
        lines = case.lines
        for name, kern in kernels.items():
            rc = name.startswith("rc")
            for pad in ((1, 8, 32) if name == "rc" else (1, 32)):
                Hp = -(-H // pad) * pad
                a = np.zeros((n_int, 4, Hp), np.float32)
                a[:, :, :H] = xn.transpose(0, 2, 1)
                if not rc:
                    a = np.ascontiguousarray(a.transpose(1, 0, 2))
                field = wp.array(a, dtype=wp.float32, device=device)
                for bd in ((256, 128) if name == "rc" else (256,)):
                    label = f"planes {name} pad{pad} bd{bd}"
                    if args.only and not re.search(args.only, label):
                        continue
                    out = wp.full(a.shape, np.nan, dtype=wp.float32, device=device)

                    def launch(kern=kern, field=field, out=out, bd=bd):
                        wp.launch(kern, dim=(groups, lines.shape[0], 32),
                                  inputs=[field, arrays["index"], arrays["active_ijk"], lines, n_int, H],
                                  outputs=[out], device=device, block_dim=bd)

                    seconds = time_kernel(device, launch)
                    o = out.numpy()
                    o = (o if rc else o.transpose(1, 0, 2))[:, :, :H].transpose(0, 2, 1)
                    diff = float(np.abs(o - case.reference).max()) if np.isfinite(o).all() else float("nan")
                    gbs = 32 * n_int * H / seconds / 1e9
                    print(f"| {n} | {H} | {n_int} | {label} | {seconds * 1e3:.3f} | {gbs:.0f} | {gbs / copy:.0%} | "
                          f"{diff:.1e} |", flush=True)


# ------------------------------------------------------------------------------------------------------------
# patches: one thread walks a BI x BJ patch of columns along z, each plane loaded once ((BI + 2)(BJ + 2) rows for
# BI * BJ nodes) and reduced to per-column terms: the package kernel (kernels/stencil.py) for any patch shape.
# Its first form kept all four equations' plane terms in the sum type; HISTORY.md's shape table is from that form.


def main_patches():
    args, device, copy, cage = start(only=True)
    shapes = [(1, 1), (1, 2), (2, 1), (2, 2), (1, 4), (2, 3), (3, 2)]
    kernels = {}
    for bi, bj in shapes:
        try:
            kernels[(bi, bj)] = stencil.operator_kernel(wp.float32, (bi, bj))
        except Exception as e:  # noqa: BLE001
            print("patch kernel failed to build:", bi, bj, e, flush=True)
    for n in args.resolutions:
        case = Case(cage, n, device)
        grid, x, arrays, n_int, groups = case.grid, case.x, case.arrays, case.n_int, case.groups
        V = {"package f32": lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device, precise=False),
             "package f64": lambda y: ws.apply_operator(grid, x, y, n_rows=n_int, device=device),
             "lines f32": case.line_walk(), "lines f64": case.line_walk(kernel=sv.apply_lines_f64)}
        for (bi, bj), kern in kernels.items():
            for L in (64, 128):
                items = wp.array(grid.interior_patches((bi, bj), L), dtype=wp.vec4i, device=device)
                nodes = int(items.numpy()[:, 3].sum()) * bi * bj
                for bd in (128, 256):
                    V[f"patch {bi}x{bj} L{L} bd{bd} ({nodes / n_int:.2f} walked/interior)"] = (
                        lambda y, kern=kern, items=items, bd=bd: wp.launch(
                            kern, dim=(groups, items.shape[0], 32), inputs=[x, arrays["index"], items, n_int],
                            outputs=[y], device=device, block_dim=bd))
        case.measure(V, copy, args.only)


def main_patch_regs():
    """The package's patch kernel (float32 and float64 sums) with register caps, block sizes and run lengths."""
    args, device, copy, cage = start(only=True)
    kernels = {"f32": stencil.apply_operator_fast, "f64": stencil.apply_operator}
    for tag, kern in list(kernels.items()):
        for regs in (64, 80, 96):
            kernels[f"{tag} maxreg{regs}"] = rekernel(kern, cuda_max_registers=regs)
    for n in args.resolutions:
        case = Case(cage, n, device)
        grid, x, arrays, n_int, groups = case.grid, case.x, case.arrays, case.n_int, case.groups
        V = {}
        for L in (32, 64, 128):
            items = wp.array(grid.interior_patches((stencil.PATCH_I, stencil.PATCH_J), L), dtype=wp.vec4i,
                             device=device)
            for name, kern in kernels.items():
                for bd in (128, 256):
                    V[f"patches {name} L{L} bd{bd}"] = (lambda y, kern=kern, items=items, bd=bd: wp.launch(
                        kern, dim=(groups, items.shape[0], 32), inputs=[x, arrays["index"], items, n_int],
                        outputs=[y], device=device, block_dim=bd))
        case.measure(V, copy, args.only)


if __name__ == "__main__":
    modes = {"forms": main_forms, "bricks": main_bricks, "regs": main_regs, "profile": main_profile,
             "layout": main_layout, "patches": main_patches,
             "patch_regs": main_patch_regs}
    if len(sys.argv) < 2 or sys.argv[1] not in modes:
        sys.exit(f"usage: {sys.argv[0]} {{{','.join(modes)}}} [--pair P] [--resolutions N ...] [--device D]")
    modes[sys.argv[1]]()
