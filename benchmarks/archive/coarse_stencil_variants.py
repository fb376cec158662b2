"""Three other forms of the coarse levels' one-pass Chebyshev step (``kernels.multigrid.stencil_chebyshev_step``),
timed against it on the ogre's multigrid (eleventh session, issue 16; ``RESULTS.md``). None was kept:

- ``two``: two handle columns per thread (h and h + H/2), each block loaded once for both;
- ``handle-major``: the launch ordered (handle, node), so that a warp holds 32 nodes of one handle;
- ``walk L``: runs of consecutive nodes along z in pieces of L, the 27 neighbours' values kept as three planes of 9
  in registers, so that each node loads 9 new values instead of 27 (the fine stencil's walk; the same sums in the
  same order: bit for bit the kernel's numbers).

    python benchmarks/archive/coarse_stencil_variants.py --device cuda:0 --resolutions 256 512

Every variant's result is compared with the kernel's (bit for bit, or the largest difference).
"""

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import warp_stokes as ws  # noqa: E402
from common import PAIRS, time_kernel  # noqa: E402
from warp_stokes.kernels import multigrid as K  # noqa: E402

mat94f = wp.types.matrix(shape=(9, 4), dtype=wp.float32)


@wp.kernel
def step_two(blocks: wp.array2d(dtype=wp.mat44f), rows: wp.array2d(dtype=wp.int32), b: wp.array2d(dtype=wp.vec4f),
             x: wp.array2d(dtype=wp.vec4f), inv_diag: wp.array(dtype=wp.mat44f), ca: float, cb: float, half: int,
             d: wp.array2d(dtype=wp.vec4f), x_next: wp.array2d(dtype=wp.vec4f)):
    n, g = wp.tid()
    h1 = g + half
    two = h1 < x.shape[1]
    acc0 = wp.vec4f(0.0)
    acc1 = wp.vec4f(0.0)
    for o in range(27):
        col = rows[n, o]
        if col >= 0:
            blk = blocks[n, o]
            acc0 += blk * x[col, g]
            if two:
                acc1 += blk * x[col, h1]
    dinv = K.diagonal_block(inv_diag, n)
    v = ca * d[n, g] + cb * (dinv * (b[n, g] - acc0))
    d[n, g] = v
    x_next[n, g] = x[n, g] + v
    if two:
        v1 = ca * d[n, h1] + cb * (dinv * (b[n, h1] - acc1))
        d[n, h1] = v1
        x_next[n, h1] = x[n, h1] + v1


@wp.kernel
def step_handle_major(blocks: wp.array2d(dtype=wp.mat44f), rows: wp.array2d(dtype=wp.int32),
                      b: wp.array2d(dtype=wp.vec4f), x: wp.array2d(dtype=wp.vec4f),
                      inv_diag: wp.array(dtype=wp.mat44f), ca: float, cb: float, d: wp.array2d(dtype=wp.vec4f),
                      x_next: wp.array2d(dtype=wp.vec4f)):
    h, n = wp.tid()
    v = ca * d[n, h] + cb * (K.diagonal_block(inv_diag, n) * (b[n, h] - K.block_row(blocks, rows, x, n, h)))
    d[n, h] = v
    x_next[n, h] = x[n, h] + v


@wp.func
def neighbour_plane(rows: wp.array2d(dtype=wp.int32), x: wp.array2d(dtype=wp.vec4f), n: int, dk: int, h: int):
    plane = mat94f()
    for s in range(9):
        col = rows[n, 3 * s + dk + 1]
        if col >= 0:
            plane[s] = x[col, h]
    return plane


@wp.func
def walked_row(blocks: wp.array2d(dtype=wp.mat44f), n: int, below: mat94f, mid: mat94f, above: mat94f):
    acc = wp.vec4f(0.0)
    for s in range(9):  # slot 3 s + dk + 1: the kernel's order
        acc += blocks[n, 3 * s] * below[s]
        acc += blocks[n, 3 * s + 1] * mid[s]
        acc += blocks[n, 3 * s + 2] * above[s]
    return acc


@wp.kernel
def step_walk(blocks: wp.array2d(dtype=wp.mat44f), rows: wp.array2d(dtype=wp.int32), runs: wp.array(dtype=wp.vec2i),
              b: wp.array2d(dtype=wp.vec4f), x: wp.array2d(dtype=wp.vec4f), inv_diag: wp.array(dtype=wp.mat44f),
              ca: float, cb: float, d: wp.array2d(dtype=wp.vec4f), x_next: wp.array2d(dtype=wp.vec4f)):
    p, h = wp.tid()
    run = runs[p]
    below = neighbour_plane(rows, x, run[0], -1, h)
    mid = neighbour_plane(rows, x, run[0], 0, h)
    for t in range(run[1]):
        n = run[0] + t
        above = neighbour_plane(rows, x, n, 1, h)
        v = ca * d[n, h] + cb * (K.diagonal_block(inv_diag, n) * (b[n, h] - walked_row(blocks, n, below, mid, above)))
        d[n, h] = v
        x_next[n, h] = x[n, h] + v
        below = mid
        mid = above


def runs_of(ijk: np.ndarray, max_length: int) -> np.ndarray:
    """(first row, count) of runs of consecutive rows one lattice step apart along z, in pieces of max_length."""
    step = np.all(ijk[1:] == ijk[:-1] + np.array([0, 0, 1]), axis=1)
    starts = np.flatnonzero(np.r_[True, ~step])
    lengths = np.diff(np.r_[starts, len(ijk)])
    pieces = -(-lengths // max_length)
    piece = np.arange(pieces.sum()) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    first = np.repeat(starts, pieces) + max_length * piece
    count = np.minimum(np.repeat(starts + lengths, pieces) - first, max_length)
    return np.stack([first, count], 1).astype(np.int32)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--pair", default="ogre", choices=list(PAIRS))
    p.add_argument("--resolutions", nargs="+", type=int, default=[256, 512])
    p.add_argument("--lengths", nargs="+", type=int, default=[4, 8, 16, 32])
    args = p.parse_args()
    warnings.simplefilter("ignore")
    cage = ws.check_cage(PAIRS[args.pair][1])
    rng = np.random.default_rng(0)
    for resolution in args.resolutions:
        mg = ws.Multigrid(ws.voxelize(cage, resolution, device=args.device), device=args.device)
        handles = cage.n_handles
        with wp.ScopedDevice(args.device):
            for depth in range(1, min(4, len(mg.levels) - 1)):
                lev = mg.levels[depth]
                n = lev.n
                x_np, b_np, d_np = (rng.standard_normal((n, handles, 4)).astype(np.float32) for _ in range(3))
                x, b = wp.array(x_np, dtype=wp.vec4f), wp.array(b_np, dtype=wp.vec4f)
                common = [lev.blocks, lev.rows]
                tail = [lev.inv_diag, 0.3, 0.5]
                variants = {"kernel": lambda d, out: wp.launch(K.stencil_chebyshev_step, dim=(n, handles),
                                                               inputs=[*common, b, x, *tail, d], outputs=[out]),
                            "two": lambda d, out: wp.launch(step_two, dim=(n, (handles + 1) // 2),
                                                            inputs=[*common, b, x, *tail, (handles + 1) // 2, d],
                                                            outputs=[out]),
                            "handle-major": lambda d, out: wp.launch(step_handle_major, dim=(handles, n),
                                                                     inputs=[*common, b, x, *tail, d], outputs=[out])}
                for length in args.lengths:
                    runs = wp.array(runs_of(lev.ijk_device.numpy(), length), dtype=wp.vec2i)
                    variants[f"walk {length}"] = (lambda runs: lambda d, out: wp.launch(
                        step_walk, dim=(runs.shape[0], handles), inputs=[*common, runs, b, x, *tail, d],
                        outputs=[out]))(runs)
                reference, cells = None, []
                for name, launch in variants.items():
                    d, out = wp.array(d_np, dtype=wp.vec4f), wp.empty_like(x)
                    launch(d, out)
                    result = out.numpy().copy()  # a copy: on the CPU .numpy() is a view of the array
                    if reference is None:
                        reference = result
                    same = np.array_equal(result, reference)
                    seconds = time_kernel(args.device, lambda: launch(d, out), repeats=10)
                    cells.append(f"{name} {1e3 * seconds:.3f} ms"
                                 + ("" if same else f" (differs by {np.abs(result - reference).max():.1e})"))
                print(f"n = {resolution}, level {depth}, {n:,} nodes: " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
