"""Draw the README's pictures of the bundled arm again, with the README's own commands, into ``pictures/``.

    python examples/arm/make_pictures.py

The commands run in a scratch folder, as the README's tour runs them from the repository root (the arm bound at the
default resolution, a cage of 58 handles made for it, then ``show``); the three PNG files it draws replace
``pictures/weights.png``, ``deformed.png`` and ``made_cage.png``. ``tests/test_docs.py`` compares the pictures its
run of the README draws with these files, so a change that alters them says so until this script is run. The other
pictures there come from the guides' commands: ``error.png`` from docs/reference.md's "Pictures", ``convergence.png``
and ``cost.png`` from docs/resolution.md's sweep.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: the README's commands that draw them, in order (the first ones make what ``show`` reads)
COMMANDS = [
    ["bind", "examples/arm/arm.obj", "examples/arm/arm_cage.obj", "-o", "arm.npz", "--quiet"],
    ["cage", "examples/arm/arm.obj", "-o", "arm_made_cage.obj", "--handles", "58"],
    ["bind", "examples/arm/arm.obj", "arm_made_cage.obj", "-o", "arm_made.npz", "--quiet"],
    ["show", "arm.npz", "--handle", "19", "--slice", "z=0.3", "-o", "weights.png"],
    ["show", "arm.npz", "--pose", "bent.npy", "--view", "side", "-o", "deformed.png"],
    ["show", "arm_made.npz", "--with-cage", "-o", "made_cage.png"],
]
PICTURES = ("weights.png", "deformed.png", "made_cage.png")


def draw(folder: Path) -> list[Path]:
    """Run the commands in ``folder`` (a copy of examples/ in it); the pictures drawn."""
    import numpy as np

    from warp_stokes.cli import main

    shutil.copytree(HERE.parent, folder / "examples", dirs_exist_ok=True)
    np.save(folder / "bent.npy", np.load(HERE / "bend_poses.npy")[-1])
    here = Path.cwd()
    try:
        os.chdir(folder)
        for argv in COMMANDS:  # on the CPU, where the same input draws the same bytes
            if main(argv + ["--device", "cpu"]) != 0:
                raise SystemExit(f"warp-stokes {' '.join(argv)} failed")
    finally:
        os.chdir(here)
    return [folder / name for name in PICTURES]


def main() -> None:
    with tempfile.TemporaryDirectory() as scratch:
        for picture in draw(Path(scratch)):
            shutil.copyfile(picture, HERE / "pictures" / picture.name)
            print(f"wrote {HERE / 'pictures' / picture.name}")


if __name__ == "__main__":
    sys.exit(main())
