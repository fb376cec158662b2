"""CPU and CUDA give the same weights, where the two devices are on different machines.

    python benchmarks/compare_devices.py --write refs/            # on a machine with Warp's CPU back end
    python benchmarks/compare_devices.py --check refs/ --device cuda:0   # on the GPU machine

``tests/test_cuda.py`` does the same in one process where one machine has both devices; the lent GPU machines
carry a CUDA-only Warp, so the CPU weights travel as files. Pairs: the bundled arm and the ogre at n = 24.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

PAIRS = {name: common.PAIRS[name] for name in ("arm", "ogre")}
RESOLUTION = 24


def bind_all(device: str) -> dict:
    import warp_stokes as ws

    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, (mesh, cage) in PAIRS.items():
            b = ws.bind(mesh, cage, resolution=RESOLUTION, device=device)
            out[name] = (b.weights, b.stats)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", help="bind on the CPU and write the weights to this folder")
    p.add_argument("--check", help="bind on --device and compare with the weights in this folder")
    p.add_argument("--device", default="cuda:0")
    args = p.parse_args(argv)
    if args.write:
        Path(args.write).mkdir(parents=True, exist_ok=True)
        for name, (w, s) in bind_all("cpu").items():
            np.savez(Path(args.write) / f"{name}.npz", weights=w, iterations=s.solver.iterations,
                     interior=s.grid.interior_nodes)
            print(f"{name}: {w.shape}, {s.solver.iterations} iterations on the CPU")
        return 0
    worst = 0.0
    for name, (w, s) in bind_all(args.device).items():
        ref = np.load(Path(args.check) / f"{name}.npz")
        diff = float(np.abs(ref["weights"] - w).max())
        worst = max(worst, diff)
        print(f"{name} n={RESOLUTION}: max |w_cpu - w_{args.device}| = {diff:.2e}; interior nodes "
              f"{int(ref['interior'])} / {s.grid.interior_nodes}; iterations cpu {int(ref['iterations'])}, "
              f"{args.device} {s.solver.iterations}")
    print("agree (<= 1e-5)" if worst <= 1e-5 else "DISAGREE")
    return 0 if worst <= 1e-5 else 1


if __name__ == "__main__":
    sys.exit(main())
