"""The README and the guides in docs/ stay true: every shell and Python block runs as written, from a copy of the
repository root, in order (the README first: the guides go on from what its tour wrote), and the README's own
commands print no warning.

A block is skipped only where the line before its fence says ``<!-- docs-test: skip (reason) -->`` (a running Ray
cluster, a GPU, large data). In a shell block the set-up steps (a virtual environment, ``pip install``, ``pytest``)
are left out: the tests run inside the installed package already. A shell command that is ``warp-stokes`` alone with
plain words (several joined by ``&&``) runs in this process, ``main(argv)`` in the working folder, as the shell would
run it without the second a fresh process spends starting (the installed command itself is run by each command's
own test); every other command, and every Python block, runs as a subprocess.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import cli

ROOT = Path(__file__).resolve().parent.parent
GUIDES = ["usd.md", "batch.md", "methods.md", "resolution.md", "reference.md", "troubleshooting.md", "performance.md"]
SETUP = re.compile(r"^(python3 -m venv\b|\. \.venv/bin/activate$|pip install\b|pytest$)")
SKIP = re.compile(r"<!-- docs-test: skip \((.+)\) -->")
PLAIN = re.compile(r"[\w./=,:+-]+")  # a word the shell passes on as it is written


def blocks(path: Path) -> list[tuple[str, str, str | None]]:
    """(language, code, reason to skip or None) of every fenced block, in order."""
    lines = path.read_text().splitlines()
    found, k = [], 0
    while k < len(lines):
        fence = re.match(r"^```(\w*)\s*$", lines[k])
        if fence and fence.group(1):
            end = next(j for j in range(k + 1, len(lines)) if lines[j].startswith("```"))
            skip = SKIP.match(lines[k - 1]) if k else None
            found.append((fence.group(1), "\n".join(lines[k + 1:end]), skip.group(1) if skip else None))
            k = end
        k += 1
    return found


def shell_commands(code: str) -> list[str]:
    """The block's commands, continuation lines joined and set-up steps left out."""
    joined = re.sub(r"\s*\\\n\s*", " ", code)
    commands = []
    for line in joined.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        kept = [part for part in line.split(" && ") if not SETUP.match(part.strip())]
        if kept:
            commands.append(" && ".join(kept))
    return commands


def in_process(command: str) -> list[list[str]] | None:
    """The arguments of each ``warp-stokes`` command of a shell command where it is that command alone with plain
    words (several joined by ``&&``, a comment after them): what ``main(argv)`` runs as the shell would. None where
    the shell does more (quotes, a variable, a pipe or redirection, another program), and for a batch on Ray
    workers (``--workers``, ``--ray-address``: Ray's processes, started from this one, would outlive the command)."""
    words = command.split()
    words = words[:next((k for k, w in enumerate(words) if w.startswith("#")), len(words))]
    if not words or not all(w == "&&" or PLAIN.fullmatch(w) for w in words):
        return None
    commands = " ".join(words).split(" && ")
    argvs = [c.split() for c in commands]
    if any(argv[0] != "warp-stokes" or {"--workers", "--ray-address"} & set(argv) for argv in argvs):
        return None
    return [argv[1:] for argv in argvs]


def run_document(path: Path, workdir: Path) -> list[str]:
    """Run the document's blocks in ``workdir``; returns the stderr of every command (for warnings)."""
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
               MPLBACKEND="Agg")
    errors = []
    for language, code, skip in blocks(path):
        if skip or language not in ("bash", "python"):
            continue
        runs = ([["bash", "-c", c] for c in shell_commands(code)] if language == "bash"
                else [[sys.executable, "-c", code]])
        for command in runs:
            argvs = in_process(command[-1]) if language == "bash" else None
            for argv in argvs if argvs is not None else [None]:  # (each of a && b only once the one before passed)
                proc = (cli(*argv, cwd=workdir) if argv is not None else
                        subprocess.run(command, cwd=workdir, env=env, capture_output=True, text=True, timeout=600))
                assert proc.returncode == 0, (f"{path.name}: {command[-1][:200]!r} exited {proc.returncode}\n"
                                              f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
                errors.append(proc.stderr)
    return errors


@pytest.fixture(scope="module")
def tour(tmp_path_factory):
    """A copy of what the commands read (examples/, pyproject.toml) with the README's blocks run in it."""
    workdir = tmp_path_factory.mktemp("docs")
    shutil.copytree(ROOT / "examples", workdir / "examples")
    stderr = run_document(ROOT / "README.md", workdir)
    return workdir, stderr


def test_the_readmes_commands_run_as_written_without_a_warning(tour):
    workdir, stderr = tour
    warned = [line for err in stderr for line in err.splitlines() if "warning" in line.lower()]
    assert not warned, warned
    for written in ("arm.npz", "bent_arm.obj", "arm_bend.usd", "arm_usd.npz", "arm_bend_layer.usda",
                    "out/summary.json", "weights.png", "deformed.png", "arm_bend_py.usda", "arm_py.npz"):
        assert (workdir / written).is_file(), written


def test_the_readmes_pictures_are_what_its_commands_draw_now(tour):
    """The pictures the README shows (examples/arm/pictures) are the ones its tour draws: a change that alters them
    fails here until ``python examples/arm/make_pictures.py`` draws them again. Compared decoded, allowing what
    another matplotlib's anti-aliasing or a GPU's last bits move (a few pixels), not a changed drawing."""
    from matplotlib.image import imread

    workdir, _ = tour
    for name in ("weights.png", "deformed.png", "made_cage.png"):
        drawn, committed = imread(workdir / name), imread(ROOT / "examples" / "arm" / "pictures" / name)
        assert drawn.shape == committed.shape, name
        changed = float(np.mean(np.abs(drawn - committed).max(axis=-1) > 8 / 255))
        assert changed < 0.005, (f"{name}: {100 * changed:.2f} % of its pixels differ from the README's picture; "
                                 "python examples/arm/make_pictures.py draws them again")


@pytest.mark.parametrize("guide", GUIDES)
def test_every_block_of_the_guides_runs_as_written(tour, guide):
    workdir, _ = tour
    run_document(ROOT / "docs" / guide, workdir)


def test_the_readme_is_short_and_the_docs_carry_no_history():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    for path in [ROOT / "README.md", *(ROOT / "docs" / g for g in GUIDES)]:
        text = path.read_text()
        assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text), f"{path.name}: a date"
        assert not re.search(r"\bissue \d+|\bsession\b", text, re.IGNORECASE), f"{path.name}: project history"
        # every relative link reaches a file of the repository
        for target in re.findall(r"\]\(([^)#]+)\)", text):
            if not target.startswith("http"):
                assert (path.parent / target).exists(), f"{path.name}: a link to {target}"
    # every guide is linked from the README, and every block is one the test knows how to run or show
    for guide in GUIDES:
        assert f"(docs/{guide})" in readme, guide
    for path in [ROOT / "README.md", *(ROOT / "docs" / g for g in GUIDES)]:
        assert {language for language, _, _ in blocks(path)} <= {"bash", "python", "text", "toml"}, path.name


def test_the_block_reader_skips_only_what_is_marked(tmp_path):
    doc = tmp_path / "d.md"
    doc.write_text("x\n```bash\npython3 -m venv .venv && . .venv/bin/activate && pip install . && echo hi \\\n"
                   "  there\n```\n<!-- docs-test: skip (needs a GPU) -->\n```bash\nexit 3\n```\n```text\nexit 4\n```\n")
    assert [(lang, skip) for lang, _, skip in blocks(doc)] == [("bash", None), ("bash", "needs a GPU"),
                                                                ("text", None)]
    assert shell_commands(blocks(doc)[0][1]) == ["echo hi there"]
    # what runs in this process: warp-stokes alone with plain words, each of several joined by &&
    assert in_process("warp-stokes bind a.obj b.obj -o c.npz && warp-stokes show c.npz -o d.png  # two") == [
        ["bind", "a.obj", "b.obj", "-o", "c.npz"], ["show", "c.npz", "-o", "d.png"]]
    for shell in ("warp-stokes batch m.toml -o out/ --workers 2", "warp-stokes bind $MESH auto -o b.npz",
                  "warp-stokes show b.npz -o 'my picture.png'", "warp-stokes bind a.obj b.obj -o c.npz > log",
                  "warp-stokes bind a.obj b.obj -o c.npz && echo done", "python -c pass", "# a comment"):
        assert in_process(shell) is None, shell
    assert run_document(doc, tmp_path) == [""]
    doc.write_text("```bash\nexit 3\n```\n")
    with pytest.raises(AssertionError, match="exited 3"):
        run_document(doc, tmp_path)
    doc.write_text("```bash\nwarp-stokes bind missing.obj cage.obj -o b.npz\n```\n")  # in process: its exit code too
    with pytest.raises(AssertionError, match="exited 2"):
        run_document(doc, tmp_path)
