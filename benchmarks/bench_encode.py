"""Encoding time: the normal equations' products over the vertices (W^T W, W^T P) on the device against BLAS on
the host, and the whole encode, for the ogre (26k vertices, 118 handles) and frames made by its binding.

    python benchmarks/bench_encode.py --device cuda --frames 100,1000
    python benchmarks/bench_encode.py --device cpu --frames 8 --resolution 16      # smoke test
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import warp_stokes as ws
from warp_stokes.binding.encode import encode_poses, normal_equations

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, pair_files, select_device  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pair", default="ogre")
    p.add_argument("--frames", default="100,1000", help="comma-separated frame counts")
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)
    resolved, name = select_device(args.device)
    mesh, cage = pair_files(args.pair)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(mesh, cage, resolution=args.resolution, device=resolved.alias)
    rng = np.random.default_rng(0)
    scale = 0.02 * np.linalg.norm(np.ptp(binding.cage_vertices, axis=0))
    rows = []
    for count in (int(f) for f in args.frames.split(",")):
        poses = binding.cage_vertices + scale * rng.normal(size=(count, *binding.cage_vertices.shape))
        frames = np.asarray(binding.deform(poses), dtype=np.float64)
        normal_equations(binding.weights, frames[:2], device=resolved, kernels=True)  # compiled and loaded
        timings = {}
        for label, kernels in (("device kernels", True), ("host BLAS", False)):
            start = time.perf_counter()
            gram, projected = normal_equations(binding.weights, frames, device=resolved, kernels=kernels)
            timings[label] = (time.perf_counter() - start, gram, projected)
        (t_dev, g_dev, p_dev), (t_host, g_host, p_host) = timings["device kernels"], timings["host BLAS"]
        start = time.perf_counter()
        encoded, rms = encode_poses(binding, ws.Poses(frames, np.arange(count, dtype=float), "made"))
        t_encode = time.perf_counter() - start
        diagonal = np.linalg.norm(np.ptp(binding.cage_vertices, axis=0))
        rows.append([name, args.pair, str(binding.n_vertices), str(binding.n_handles), str(count), f"{t_dev:.3f}",
                     f"{t_host:.3f}", f"{np.abs(g_dev - g_host).max() / np.abs(g_host).max():.1e}",
                     f"{np.abs(p_dev - p_host).max() / np.abs(p_host).max():.1e}", f"{t_encode:.3f}",
                     f"{np.abs(encoded.positions - poses).max() / diagonal:.1e}", f"{rms.max():.1e}"])
    print(markdown_table(("device", "pair", "vertices", "handles", "frames", "products on device s",
                          "products BLAS s", "gram diff", "W^T P diff", "encode s", "pose error / diag",
                          "max RMS / diag"), rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
