"""Bad input drawn by class, not listed by case (issue 47): names of any bytes, numbers at and beyond float32's and
float64's limits, damaged files of every format read, special files, outputs that meet inputs and faults in the
writer, in every command's input slots. Each example runs the command line in process (``main(argv)``) in a copy of
a small workspace and checks the invariants that hold for any input:

- no traceback and no hang; exit code 0, 1 or 2 as documented; exit 2 is one line on stderr;
- nothing outside the command's outputs is created, changed or deleted, and on failure nothing at all (no output
  half-written, no temporary file left);
- what a class says more: a name the file system takes works; a file that cannot be read never exits 0; an output
  that meets an input is refused.

The examples are derandomized (the same each run, about a minute on 2 cores). ``WARP_STOKES_HYPOTHESIS_EXAMPLES=N``
draws N random examples per test instead; ``WARP_STOKES_SURVEY=FILE`` records every failing example in FILE (one JSON
line each) instead of stopping at the first, to count what a version of the package gets wrong.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import math
import os
import resource
import shutil
import signal
import stat

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, note, settings
from hypothesis import strategies as st

from conftest import EXAMPLE, write_obj

EXAMPLES = int(os.environ.get("WARP_STOKES_HYPOTHESIS_EXAMPLES", "0") or 0)
SURVEY = os.environ.get("WARP_STOKES_SURVEY")
HANG_SECONDS = int(os.environ.get("WARP_STOKES_HANG_SECONDS", "60"))


def budget(examples: int):
    """Settings of a property: ``examples`` derandomized examples (CI), or the environment's number drawn at
    random."""
    return settings(max_examples=EXAMPLES or examples, derandomize=not EXAMPLES, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                           HealthCheck.data_too_large, HealthCheck.filter_too_much])


# ----------------------------------------------------------------------------------------------------------------
# the workspace: small valid inputs of every kind, bound once; each example works in a copy of it
# ----------------------------------------------------------------------------------------------------------------


def _cli(argv, cwd):
    """``main(argv)`` in ``cwd``: (exit code, stdout, stderr, the exception that escaped or None)."""
    from warp_stokes.cli import main

    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    os.chdir(cwd)
    escaped, rc = None, None
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), _deadline(HANG_SECONDS), \
                _memory_cap():
            try:
                rc = main(list(argv))
            except SystemExit as exc:
                rc = exc.code
    except BaseException as exc:  # a traceback, a hang, memory without end
        escaped = exc
    finally:
        os.chdir(here)
    return rc, out.getvalue(), err.getvalue(), escaped


class Hang(BaseException):
    pass


@contextlib.contextmanager
def _deadline(seconds: int):
    def expire(signum, frame):
        raise Hang(f"no answer within {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def _memory_cap(extra: int = 4 << 30):
    """The address space capped at what the process has now plus ``extra``: a read without end is a MemoryError
    here, not the machine's out-of-memory killer."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    try:
        with open("/proc/self/statm") as fh:
            size = int(fh.read().split()[0]) * resource.getpagesize()
    except OSError:
        yield
        return
    cap = size + extra if hard == resource.RLIM_INFINITY else min(size + extra, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A folder of valid inputs: the arm (OBJ, PLY, STL, glTF, GLB, USDA, USDC), its cage, poses (.npy, .npz, a USD
    file that sublayers a file of the user's, a USD file with value clips), frames (a folder of OBJ, .npy), bindings
    of the OBJ and of the USD asset at resolution 8, and manifests (TOML, JSON)."""
    import trimesh
    from pxr import Usd

    base = tmp_path_factory.mktemp("workspace")
    for name in ("arm.obj", "arm_cage.obj", "arm.usda", "bend_poses.npy"):
        shutil.copy(EXAMPLE / name, base / name)
    poses = np.load(base / "bend_poses.npy")
    np.save(base / "bent.npy", poses[-1])
    np.savez(base / "poses.npz", poses=poses[:4], frames=np.arange(4.0))
    mesh = trimesh.load(base / "arm.obj", process=False)
    for ext in ("ply", "stl", "glb", "gltf"):
        mesh.export(base / f"arm.{ext}")
    Usd.Stage.Open(str(base / "arm.usda")).Export(str(base / "arm.usdc"))
    (base / "mine.usda").write_text('#usda 1.0\ndef "Mine" {}\n')
    (base / "p.usda").write_text("#usda 1.0\n(\n    subLayers = [@./mine.usda@, @./arm.usda@]\n)\n")
    (base / "clip.usda").write_text('#usda 1.0\ndef "Clip" {}\n')
    (base / "c.usda").write_text('#usda 1.0\n(\n    subLayers = [@./arm.usda@]\n)\nover "Arm" (\n    clips = {\n'
                                 '        dictionary default = {\n            asset[] assetPaths = [@./clip.usda@]\n'
                                 '            string primPath = "/Clip"\n            double2[] active = [(0, 0)]\n'
                                 '            double2[] times = [(0, 0)]\n        }\n    }\n) {}\n')
    for argv in (["bind", "arm.obj", "arm_cage.obj", "-o", "b.npz"],
                 ["bind", "arm.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "u.npz"]):
        rc, _, err, escaped = _cli(argv + ["--resolution", "8", "--device", "cpu", "--quiet"], base)
        assert rc == 0 and escaped is None, err
    import warp_stokes as ws

    binding = ws.load_binding(base / "b.npz", device="cpu")
    frames = binding.deform(poses[::8])
    (base / "fr").mkdir()
    for k, vertices in enumerate(frames):
        write_obj(base / "fr" / f"frame_{k}.obj", vertices, binding.mesh_faces)
    np.save(base / "frames.npy", frames)
    (base / "m.toml").write_text('[[asset]]\nname = "a"\nmesh = "arm.obj"\ncage = "arm_cage.obj"\n'
                                 'poses = "bend_poses.npy"\nresolution = 8\n')
    (base / "m.json").write_text(json.dumps({"assets": [{"name": "a", "mesh": "arm.obj", "cage": "arm_cage.obj",
                                                         "resolution": 8}]}))
    return base


@pytest.fixture
def scratch(tmp_path, workspace):
    """A fresh copy of the workspace for each example: ``scratch()`` returns its path (``scratch(folder)`` a copy of
    that folder instead: a workspace a command has already written to)."""
    count = [0]

    def make(source=None):
        count[0] += 1
        folder = tmp_path / f"w{count[0]}"
        shutil.copytree(workspace if source is None else source, folder, symlinks=True)
        return folder

    return make


@pytest.fixture(scope="module")
def written(workspace, tmp_path_factory):
    """``written(key, argv)``: a copy of the workspace in which ``argv`` has run, made once per key for the module;
    the examples that start from that command's outputs copy it (``scratch``) instead of running the same command
    again. (Not for what depends on where it ran: a batch's up-to-date records name the files it read.)"""
    made = {}

    def get(key, argv):
        if key not in made:
            folder = tmp_path_factory.mktemp("written") / "w"
            shutil.copytree(workspace, folder, symlinks=True)
            rc, _, err, escaped = _cli(argv, folder)
            assert rc == 0 and escaped is None, err
            made[key] = folder
        return made[key]

    return get


# ----------------------------------------------------------------------------------------------------------------
# the invariants
# ----------------------------------------------------------------------------------------------------------------


def snapshot(root) -> dict:
    """Every entry under ``root`` (links not followed): its kind, size, contents and mode. (The contents themselves,
    compared byte for byte: no digest to compute, twice per example.)"""
    found = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = os.path.join(folder, name)
            info = os.lstat(path)
            key = os.path.relpath(path, root)
            if stat.S_ISREG(info.st_mode):  # (the inode too: a file written again under the same contents)
                with open(path, "rb") as fh:
                    contents = fh.read()
                found[key] = ("file", info.st_size, contents, stat.S_IMODE(info.st_mode), info.st_ino)
            elif stat.S_ISLNK(info.st_mode):
                found[key] = ("link", os.readlink(path))
            else:
                found[key] = ("other", stat.S_IFMT(info.st_mode))
    return found


def _errors(stderr: str) -> list[str]:
    """The lines of stderr that are not warnings, notes or a batch's progress ("[###...] 1/3 name: stage")."""
    return [line for line in stderr.splitlines() if not line.startswith(("warning:", "note:", "["))]


class Defect(AssertionError):
    pass


def defect(label: str, message: str, argv=()) -> None:
    """A broken invariant: raised, or in survey mode recorded (and the example goes on)."""
    if SURVEY:
        with open(SURVEY, "a", encoding="utf-8") as fh:
            fh.write(json.dumps({"class": label, "message": message[:500], "argv": [repr(a) for a in argv]}) + "\n")
        return
    raise Defect(f"[{label}] {message}\n  argv: {list(argv)!r}")


def outputs_text(folder, outputs) -> str:
    """"summary.json" when a batch's summary in ``outputs`` records an error that names a temporary file."""
    for output in outputs:
        summary = os.path.join(folder, output, "summary.json")
        if os.path.isfile(summary):
            with open(summary, encoding="utf-8") as fh:
                text = fh.read()
            if ".wst~" in text or "/.tmp-" in text:
                return "summary.json"
    return ""


def check(label: str, argv, folder, outputs=(), expect=None, rc_ok=(0, 1, 2)):
    """Run ``argv`` in ``folder`` and check the invariants; ``outputs`` are the paths (relative to ``folder``; a
    folder's whole tree) the command may write; ``expect`` 0 or 2 where the class says which. Returns the exit code
    and stderr."""
    before = snapshot(folder)
    rc, out, err, escaped = _cli(argv, folder)
    after = snapshot(folder)
    note(f"rc={rc} stderr={err!r}")
    if escaped is not None:
        import traceback

        defect(label, f"escaped: {type(escaped).__name__}: {escaped}\n"
                      + "".join(traceback.format_exception(escaped)[-3:]), argv)
        return rc, err
    if rc not in rc_ok:
        defect(label, f"exit code {rc}", argv)
    errors = _errors(err)
    if rc == 2 and (len(errors) != 1 or not errors[0].startswith("warp-stokes")):
        defect(label, f"exit 2 with {len(errors)} error lines: {err!r}", argv)
    if expect is not None and rc != expect:
        defect(label, f"exit {rc}, expected {expect}: {err.strip()!r}", argv)
    if ".wst~" in err or "/.tmp-" in err or "summary.json" in outputs_text(folder, outputs):
        defect(label, f"a message names a temporary file instead of the output: {err.strip()!r}", argv)
    allowed = [os.path.normpath(o) for o in outputs] if rc in (0, 1) else []
    folders = {os.path.dirname(o) for o in allowed} - {""}  # an output folder made for them (batch -o out)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    outside = [k for k in changed if k not in folders and not any(k == o or k.startswith(o + os.sep)
                                                                  for o in allowed)]
    if outside:
        defect(label, f"exit {rc}; changed outside its outputs: {outside[:5]} ({err.strip()[:200]!r})", argv)
    return rc, err


# ----------------------------------------------------------------------------------------------------------------
# class 1: names of any bytes the file system takes
# ----------------------------------------------------------------------------------------------------------------

SPECIAL_NAMES = [b"-take2", b"--x", b"a b", b"a\nb", b"tab\there", b"\x1b[31mred", b"caf\xc3\xa9", b"\xff\xfe",
                 b"arm [v2] #3 @home", b"x:y", b"%s%n", b"a\\b", b"." * 3 + b"x", b"~user", b"x" * 240]
stems = st.one_of(st.sampled_from(SPECIAL_NAMES),
                  st.binary(min_size=1, max_size=64).map(lambda b: b.replace(b"/", b"_").replace(b"\0", b"_")))

# (slot, command): the name goes to an input (a copy of a valid file) or the output, with its format's extension
NAME_SLOTS = [
    ("pose input", ["deform", "b.npz", "{name}.npy", "-o", "out.obj"], "bent.npy"),
    ("poses input", ["animate", "b.npz", "{name}.npy", "-o", "out.usda"], "bend_poses.npy"),
    ("binding input", ["deform", "{name}.npz", "bent.npy", "-o", "out.obj"], "b.npz"),
    ("mesh output", ["deform", "b.npz", "bent.npy", "-o", "{name}.obj"], None),
    ("usd output", ["animate", "b.npz", "bend_poses.npy", "-o", "{name}.usda"], None),
    ("glTF output", ["animate", "b.npz", "bend_poses.npy", "-o", "{name}.glb"], None),
    ("layer output", ["animate", "u.npz", "bend_poses.npy", "-o", "{name}.usdc"], None),
    ("poses output", ["encode", "b.npz", "frames.npy", "-o", "{name}.npy"], None),
    ("binding output", ["bind", "arm.obj", "arm_cage.obj", "-o", "{name}.npz", "--resolution", "8"], None),
]


@budget(60)
@given(stem=stems, slot=st.sampled_from(NAME_SLOTS))
def test_a_name_the_file_system_takes_works(scratch, stem, slot):
    label, template, source = slot
    folder = scratch()
    ext = os.path.splitext(next(a for a in template if "{name}" in a))[1]
    name = os.fsdecode(stem)
    path = os.path.join(os.fsencode(folder), stem + os.fsencode(ext))
    try:  # a name the file system refuses (too long) is no name a user can give
        if source is not None:
            shutil.copy(folder / source, path)
        else:
            with open(path, "wb"):
                pass
            os.unlink(path)
    except OSError:
        assume(False)
    argv = [a.replace("{name}", name) for a in template] + ["--device", "cpu"]
    output = argv[argv.index("-o") + 1]
    # a name of dots alone ("..glb") has no extension for Python (os.path.splitext): a one-line error will do
    dots = not stem.strip(b".")
    check(f"names: {label}", argv, folder, outputs=[output], expect=None if dots else 0)


@budget(30)
@given(name=stems, field=st.sampled_from(["name", "mesh", "cage_prim", "mesh_prims"]))
def test_a_manifest_string_of_any_text_works_or_is_refused_in_one_line(scratch, name, field):
    folder = scratch()
    text = os.fsdecode(name)
    entry = {"name": "a", "mesh": "arm.obj", "cage": "arm_cage.obj", "resolution": 8}
    expect = None
    if field == "name":
        entry["name"] = text
        expect = 0 if (text.isprintable() and not set(text) & set("/\\:") and not text.startswith(".")
                       and len(name) <= 240) else 2
        outputs = [f"out/{text}.npz", "out/summary.json"]
    elif field == "mesh":  # a copy of the mesh under that name
        try:
            shutil.copy(folder / "arm.obj", os.path.join(os.fsencode(folder), name + b".obj"))
        except OSError:
            assume(False)
        entry["mesh"] = text + ".obj"
        outputs = ["out/a.npz", "out/summary.json"]
        expect = 0
    else:  # a prim path that is not one: the asset fails, alone
        entry.update(mesh="arm.usda", cage=None)
        entry["cage_prim" if field == "cage_prim" else "mesh_prims"] = text if field == "cage_prim" else [text]
        if field == "mesh_prims":
            entry["cage_prim"] = "/Arm/Rig/Cage"
        entry = {k: v for k, v in entry.items() if v is not None}
        outputs = ["out/a.npz", "out/summary.json"]
    (folder / "s.json").write_text(json.dumps({"assets": [entry]}))  # JSON escapes what UTF-8 cannot hold
    check(f"manifest strings: {field}", ["batch", "s.json", "-o", "out", "--device", "cpu"], folder,
          outputs=outputs, expect=expect)


BESIDE = [b".tmp-notes.txt", b".tmp-a.npz-x", b".wst~1~other-host~0a1b2c3d~a.npz", b".warp-stokes.lock.bak",
          b"a.npz.tmp", b"~a.usd", b".a.usd.swp", b"summary.json~",
          f".tmp-{os.uname().nodename}-{os.getpid()}-h.usd-0a1b2c.usd".encode()]  # a live process's, another pattern


@budget(20)
@given(name=st.one_of(st.sampled_from(BESIDE), stems), live=st.booleans(),
       command=st.sampled_from(["batch", "deform", "bind", "animate"]))
def test_files_beside_the_outputs_are_left_alone(scratch, name, live, command):
    # a file of the user's, or another command's live temporary file, in the folder the command writes to
    folder = scratch()
    (folder / "out").mkdir()
    if live:  # the pattern of a temporary file of this (live) process: another command's, being written
        import socket

        host = "".join(c if c.isalnum() or c in ".-" else "-" for c in socket.gethostname())[:32]
        name = f".wst~{os.getpid()}~{host}~0a1b2c3d~h.usd".encode()
    try:
        with open(os.path.join(os.fsencode(folder / "out"), name), "wb") as fh:
            fh.write(b"not the package's")
    except OSError:
        assume(False)
    argv, outputs = {
        "batch": (["batch", "m.toml", "-o", "out"], ["out/a.npz", "out/a.usd", "out/summary.json"]),
        "deform": (["deform", "b.npz", "bent.npy", "-o", "out/d.obj"], ["out/d.obj"]),
        "bind": (["bind", "arm.obj", "auto", "-o", "out/B.npz", "--resolution", "8", "--handles", "40"],
                 ["out/B.npz", "out/B.cage.obj"]),
        "animate": (["animate", "b.npz", "bend_poses.npy", "-o", "out/a.usdc"], ["out/a.usdc"]),
    }[command]
    check(f"beside: {command}", argv + ["--device", "cpu"], folder, outputs=outputs, expect=0)


# ----------------------------------------------------------------------------------------------------------------
# class 2: numbers at and beyond float32's and float64's limits, NaN and infinities
# ----------------------------------------------------------------------------------------------------------------

LIMITS = ["0", "-0", "1e-45", "1e-40", "1.1754943508222875e-38", "3.4028234663852886e38", "3.5e38", "1e308", "1e309",
          "nan", "-nan", "inf", "-inf", "-1", "1", "2147483648", "9223372036854775808", "1e-300", "24", "0.5", "abc",
          "", "0x10", "1_000"]
numbers_text = st.one_of(st.sampled_from(LIMITS), st.floats(allow_nan=True, allow_infinity=True).map(repr),
                         st.integers(min_value=-2**70, max_value=2**70).map(str))
NUMBER_OPTIONS = [
    (["animate", "b.npz", "bend_poses.npy", "-o", "o.glb", "--fps"], "o.glb"),
    (["animate", "b.npz", "bend_poses.npy", "-o", "o.usda", "--fps"], "o.usda"),
    (["animate", "b.npz", "bend_poses.npy", "-o", "o.usda", "--meters-per-unit"], "o.usda"),
    (["animate", "b.npz", "poses.npz", "-o", "o.usda", "--inbetween"], "o.usda"),
    (["animate", "b.npz", "bend_poses.npy", "-o", "o.usda", "--skeleton", "--influences"], "o.usda"),
    (["animate", "b.npz", "bend_poses.npy", "-o", "o.glb", "--max-error"], "o.glb"),
    (["animate", "b.npz", "poses.npz", "-o", "o.glb", "--key-frames"], "o.glb"),
    (["bind", "arm.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.npz", "--resolution", "8", "--rest-time"], "o.npz"),
    (["bind", "arm.obj", "arm_cage.obj", "-o", "o.npz", "--resolution", "8", "--tol"], "o.npz"),
    (["bind", "arm.obj", "arm_cage.obj", "-o", "o.npz", "--resolution", "8", "--memory-gb"], "o.npz"),
    (["bind", "arm.obj", "arm_cage.obj", "-o", "o.npz", "--resolution", "8", "--max-iterations"], "o.npz"),
    (["bind", "arm.obj", "arm_cage.obj", "-o", "o.npz", "--resolution"], "o.npz"),
    (["encode", "b.npz", "frames.npy", "-o", "o.npy", "--smooth"], "o.npy"),
    (["show", "b.npz", "--slice", "z=0.5", "-o", "o.png", "--handle"], "o.png"),
]


def _valid_output(path) -> str | None:
    """What is wrong with a written output, read back as its consumers read it (None when nothing)."""
    ext = os.path.splitext(str(path))[1]
    if ext in (".usda", ".usdc", ".usd"):
        from pxr import Usd, UsdGeom

        stage = Usd.Stage.Open(str(path))
        rate = stage.GetTimeCodesPerSecond()
        if not (np.isfinite(rate) and rate > 0):
            return f"time codes per second {rate}"
        for prim in stage.Traverse():
            if prim.IsA(UsdGeom.PointBased):
                attr = UsdGeom.PointBased(prim).GetPointsAttr()
                for t in attr.GetTimeSamples() or [None]:
                    value = attr.Get(t) if t is not None else attr.Get()
                    if value is not None and not np.isfinite(np.asarray(value)).all():
                        return f"{prim.GetPath()} has points that are not finite at {t}"
    if ext in (".glb", ".gltf"):
        import pygltflib

        try:
            gltf = pygltflib.GLTF2().load(str(path))
        except Exception as exc:
            return f"pygltflib cannot read it: {exc}"
        for accessor in gltf.accessors:
            for bound in (accessor.min or []) + (accessor.max or []):
                if not np.isfinite(bound):
                    return "an accessor's bounds are not finite"
    if ext == ".npy":
        if not np.isfinite(np.load(path)).all():
            return "values that are not finite"
    return None


def _key_frames_taken(text: str) -> bool:
    """Whether a list of key frames is one the documentation takes: numbers, finite, strictly increasing, within
    float32's range, and their times at 24 fps distinct in float32 (glTF)."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        return False
    times = np.float32(np.array(values) / 24.0)
    return (all(np.isfinite(values)) and all(abs(v) <= 3.4e38 for v in values)
            and all(b > a for a, b in zip(values, values[1:])) and len(set(times.tolist())) == len(values)
            and values[-1] - values[0] < 100_000)  # in-betweening writes every integer frame: 100,000 at most


def _int_the_cli_takes(text: str) -> float:
    """The integer the CLI reads from ``text`` for --inbetween and --resolution, parsed as it parses them (Python's
    ``int``, which also takes "1_000", " +5", "\u0661\u0662"), or -inf for text it does not read as an integer."""
    try:
        return int(text)
    except ValueError:
        return -math.inf


@budget(100)
@given(option=st.sampled_from(NUMBER_OPTIONS), value=numbers_text, lists=st.booleans())
def test_numbers_at_the_limits_are_taken_or_refused_in_one_line(scratch, option, value, lists):
    template, output = option
    expect = None
    if template[-1] == "--key-frames":  # a list: one value among increasing frame numbers
        value = ",".join(["0", "1", "2", value] if lists else [value, "1e3", "1e4", "5e4"])
        expect = 0 if _key_frames_taken(value) else None
    if template[-1] in ("--inbetween", "--resolution"):  # a large count is work (minutes on a CPU), not bad input
        assume(_int_the_cli_takes(value) <= {"--inbetween": 200}.get(template[-1], 64))
    folder = scratch()
    argv = template + [value, "--device", "cpu"]
    rc, err = check(f"numbers: {template[-1]}", argv, folder, outputs=[output], expect=expect)
    if rc == 0:
        problem = _valid_output(folder / output)
        if problem:
            defect(f"numbers: {template[-1]}", f"exit 0 with an output its consumers refuse: {problem}", argv)


# (a list of CPUs spreads a bind over Ray workers: tests/test_spread.py)
DEVICE_NAMES = ["cuda", "cuda:7", "gpu", "", "cpu,cuda", "cuda:all", "cpu:1", "CUDA", "cuda:-1", "\x00"]


@budget(12)
@given(device=st.sampled_from(DEVICE_NAMES), command=st.sampled_from(["batch", "bind", "deform"]))
def test_a_device_this_machine_lacks_is_refused_before_anything_is_made(scratch, device, command):
    from conftest import cuda_available

    assume(not (cuda_available() and device.lower().startswith("cuda")))
    folder = scratch()
    argv = {"batch": ["batch", "m.toml", "-o", "out"],
            "bind": ["bind", "arm.obj", "arm_cage.obj", "-o", "o.npz", "--resolution", "8"],
            "deform": ["deform", "b.npz", "bent.npy", "-o", "o.obj"]}[command] + ["--device", device]
    check(f"devices: {command}", argv, folder, outputs=[argv[argv.index("-o") + 1]])


VALUES = [np.nan, np.inf, -np.inf, 1e300, -1e300, 3.5e38, 3.4e38, 1e-320, 1e19, -0.0]


@budget(50)
@given(value=st.sampled_from(VALUES), where=st.tuples(st.integers(0, 23), st.integers(0, 57), st.integers(0, 2)),
       command=st.sampled_from(["animate-usd", "animate-glb", "deform", "encode", "frame-times"]))
def test_numbers_in_files_are_taken_or_refused_in_one_line(scratch, value, where, command):
    folder = scratch()
    poses = np.load(folder / "bend_poses.npy")
    if command == "frame-times":  # the frame numbers of an archive of poses
        frames = np.arange(4.0)
        frames[where[0] % 4] = value
        np.savez(folder / "x.npz", poses=poses[:4], frames=frames)
        argv, output = ["animate", "b.npz", "x.npz", "-o", "o.glb"], "o.glb"
    elif command == "encode":
        frames = np.load(folder / "frames.npy")
        frames[where[0] % len(frames), where[1], where[2]] = value
        np.save(folder / "x.npy", frames)
        argv, output = ["encode", "b.npz", "x.npy", "-o", "o.npy"], "o.npy"
    else:
        poses[where] = value
        if command == "deform":
            np.save(folder / "x.npy", poses[where[0]])
            argv, output = ["deform", "b.npz", "x.npy", "-o", "o.obj"], "o.obj"
        else:
            np.save(folder / "x.npy", poses)
            output = "o.usda" if command == "animate-usd" else "o.glb"
            argv = ["animate", "b.npz", "x.npy", "-o", output]
    argv += ["--device", "cpu"]
    rc, err = check(f"numbers in files: {command}", argv, folder, outputs=[output])
    if rc == 0:
        problem = _valid_output(folder / output)
        if problem:
            defect(f"numbers in files: {command}", f"exit 0 with an output its consumers refuse: {problem}", argv)


# ----------------------------------------------------------------------------------------------------------------
# class 3: damaged files of every format read
# ----------------------------------------------------------------------------------------------------------------

# (file, command with {} for it, whether a file cut short can still be whole: text formats can)
FORMATS = [
    ("arm.obj", ["bind", "{}", "arm_cage.obj", "-o", "o.npz", "--resolution", "8"], True),
    ("arm_cage.obj", ["bind", "arm.obj", "{}", "-o", "o.npz", "--resolution", "8"], True),
    ("arm.ply", ["bind", "{}", "arm_cage.obj", "-o", "o.npz", "--resolution", "8"], False),
    ("arm.stl", ["bind", "{}", "arm_cage.obj", "-o", "o.npz", "--resolution", "8"], False),
    ("arm.glb", ["bind", "{}", "arm_cage.obj", "-o", "o.npz", "--resolution", "8"], False),
    ("arm.gltf", ["bind", "{}", "arm_cage.obj", "-o", "o.npz", "--resolution", "8"], False),
    ("arm.usda", ["bind", "{}", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.npz", "--resolution", "8"], True),
    ("arm.usdc", ["bind", "{}", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.npz", "--resolution", "8"], False),
    ("mine.usda", ["animate", "u.npz", "p.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.usda"], True),
    ("bend_poses.npy", ["animate", "b.npz", "{}", "-o", "o.usda"], False),
    ("poses.npz", ["animate", "b.npz", "{}", "-o", "o.usda"], False),
    ("bent.npy", ["deform", "b.npz", "{}", "-o", "o.obj"], False),
    ("b.npz", ["deform", "{}", "bent.npy", "-o", "o.obj"], False),
    ("frames.npy", ["encode", "b.npz", "{}", "-o", "o.npy"], False),
    ("fr/frame_1.obj", ["encode", "b.npz", "fr", "-o", "o.npy"], True),
    ("m.toml", ["batch", "{}", "-o", "out"], True),
    ("m.json", ["batch", "{}", "-o", "out"], False),
]


@st.composite
def damage(draw, size: int):
    """A way to damage a file of ``size`` bytes: cut it short, flip bytes, or put bytes in; and whether the result
    is cut short (and nothing else)."""
    kind = draw(st.sampled_from(["cut", "flip", "insert", "empty"]))
    if kind == "empty":
        return ("cut", 0), True
    if kind == "cut":
        return ("cut", draw(st.integers(0, max(size - 1, 0)))), True
    count = draw(st.integers(1, 8))
    places = draw(st.lists(st.integers(0, max(size - 1, 0)), min_size=count, max_size=count))
    payload = draw(st.binary(min_size=1, max_size=8))
    return (kind, places, payload), False


def apply_damage(data: bytes, how) -> bytes:
    if how[0] == "cut":
        return data[: how[1]]
    data = bytearray(data)
    for place in how[1]:
        if how[0] == "flip":
            data[place] ^= how[2][0] or 0xFF
        else:
            data[place:place] = how[2]
    return bytes(data)


@budget(120)
@given(fmt=st.sampled_from(FORMATS), data=st.data())
def test_a_damaged_file_is_refused_in_one_line_or_read_whole(scratch, fmt, data):
    name, template, text = fmt
    folder = scratch()
    original = (folder / name).read_bytes()
    how, cut_short = data.draw(damage(len(original)))
    damaged = apply_damage(original, how)
    assume(damaged != original)
    (folder / name).write_bytes(damaged)
    if name == "arm.gltf":  # a whole glTF beside it: a damaged one must not be read in its place
        shutil.copy(folder / "arm.glb", folder / "model.glb")
        (folder / "model.gltf").write_bytes(original)
    argv = [a.replace("{}", name) for a in template] + ["--device", "cpu"]
    output = argv[argv.index("-o") + 1]
    whole_cut = cut_short and text and damaged.strip() and original.startswith(damaged)
    expect = 2 if cut_short and not text and not whole_cut else None
    check(f"damaged {os.path.splitext(name)[1]}", argv, folder, outputs=[output], expect=expect)


# ----------------------------------------------------------------------------------------------------------------
# class 4: special files where a file is read
# ----------------------------------------------------------------------------------------------------------------

SLOTS = [
    ("mesh", ["bind", "{}", "arm_cage.obj", "-o", "o.npz", "--resolution", "8"], "arm.obj"),
    ("cage", ["bind", "arm.obj", "{}", "-o", "o.npz", "--resolution", "8"], "arm_cage.obj"),
    ("USD mesh", ["bind", "{}", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.npz", "--resolution", "8"], "arm.usda"),
    ("sublayer", ["animate", "u.npz", "p.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.usda"], "mine.usda"),
    ("binding", ["deform", "{}", "bent.npy", "-o", "o.obj"], "b.npz"),
    ("pose", ["deform", "b.npz", "{}", "-o", "o.obj"], "bent.npy"),
    ("poses", ["animate", "b.npz", "{}", "-o", "o.usda"], "bend_poses.npy"),
    ("frame", ["encode", "b.npz", "fr", "-o", "o.npy"], "fr/frame_1.obj"),
    ("frames", ["encode", "b.npz", "{}", "-o", "o.npy"], "frames.npy"),
    ("manifest", ["batch", "{}", "-o", "out"], "m.toml"),
    ("glTF buffer", ["bind", "arm.gltf", "arm_cage.obj", "-o", "o.npz", "--resolution", "8"], "gltf_buffer.bin"),
    ("batch mesh", ["batch", "m.toml", "-o", "out"], "arm.obj"),
]
KINDS = ["pipe", "link to /dev/zero", "link to /dev/null", "link to nothing", "folder", "socket"]


def make_special(path, kind: str) -> None:
    import socket

    os.unlink(path) if os.path.lexists(path) and not os.path.isdir(path) else None
    if kind == "pipe":
        os.mkfifo(path)
    elif kind.startswith("link to /dev"):
        os.symlink(kind.split()[-1], path)
    elif kind == "link to nothing":
        os.symlink(os.path.join(os.path.dirname(path), "nowhere"), path)
    elif kind == "folder":
        os.mkdir(path)
    else:
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(path))
        server.close()


@budget(40)
@given(slot=st.sampled_from(SLOTS), kind=st.sampled_from(KINDS))
def test_a_special_file_is_refused_at_once(scratch, slot, kind):
    label, template, name = slot
    folder = scratch()
    if name == "gltf_buffer.bin":
        buffers = json.loads((folder / "arm.gltf").read_text()).get("buffers", [])
        uri = next((b.get("uri") for b in buffers if not str(b.get("uri", "data:")).startswith("data:")), None)
        if uri is None:  # the exporter embedded the buffer: give it a file of its own
            document = json.loads((folder / "arm.gltf").read_text())
            import base64

            raw = base64.b64decode(document["buffers"][0]["uri"].split(",", 1)[1])
            (folder / "buffer.bin").write_bytes(raw)
            document["buffers"][0]["uri"] = "buffer.bin"
            (folder / "arm.gltf").write_text(json.dumps(document))
            uri = "buffer.bin"
        name = uri
    if len(str(folder / name)) > 100 and kind == "socket":
        assume(False)
    make_special(folder / name, kind)
    argv = [a.replace("{}", name) for a in template] + ["--device", "cpu"]
    output = argv[argv.index("-o") + 1]
    expect = 1 if template[0] == "batch" and label == "batch mesh" else 2
    check(f"special file: {label}", argv, folder, outputs=[output], expect=expect)


# ----------------------------------------------------------------------------------------------------------------
# class 5: outputs that meet inputs
# ----------------------------------------------------------------------------------------------------------------

MEETINGS = [
    ("the binding's mesh", ["deform", "b.npz", "bent.npy", "-o", "{}"], "arm.obj"),
    ("the binding's cage", ["deform", "b.npz", "bent.npy", "-o", "{}"], "arm_cage.obj"),
    ("the binding's asset", ["animate", "u.npz", "bend_poses.npy", "-o", "{}"], "arm.usda"),
    ("a sublayer of the poses", ["animate", "u.npz", "p.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "{}"],
     "mine.usda"),
    ("a sublayer of the poses, as a skin", ["animate", "u.npz", "p.usda", "--cage-prim", "/Arm/Rig/Cage",
                                            "--skeleton", "-o", "{}"], "mine.usda"),
    ("a clip of the poses", ["animate", "u.npz", "c.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "{}"],
     "clip.usda"),
    ("a clip of the asset", ["cage", "c.usda", "-o", "{}", "--handles", "40"], "clip.usda"),
    ("the frames' USD", ["encode", "u.npz", "p.usda", "-o", "{}"], "mine.usda"),
    ("a frame of the folder", ["encode", "b.npz", "fr", "-o", "{}"], "fr/frame_0.obj"),
    ("the manifest", ["batch", "m.json", "-o", "{}"], "."),
    ("the poses", ["animate", "b.npz", "bend_poses.npy", "-o", "{}"], "bend_poses.npy"),
    ("a frame of the folder, for a made cage", ["encode", "auto", "fr", "-o", "{}"], "fr/poses.npy"),
]
WAYS = ["as named", "through a link", "through a hard link", "through ../", "in upper case"]


@budget(50)
@given(meeting=st.sampled_from(MEETINGS), way=st.sampled_from(WAYS))
def test_an_output_never_replaces_an_input(scratch, meeting, way):
    label, template, target = meeting
    folder = scratch()
    ext = os.path.splitext(target)[1]
    name = target
    if not os.path.exists(folder / target) and target != ".":  # an output that would be read as an input
        assume(way in ("as named", "through ../"))
    elif way == "through a link" and target != ".":
        name = "alias" + ext
        os.symlink(folder / target, folder / name)
    elif way == "through a hard link" and target != ".":
        name = "twin" + ext
        os.link(folder / target, folder / name)
    elif way == "through ../":
        name = os.path.join("fr", "..", target)
    elif way == "in upper case":  # another file on a case-sensitive system: it must simply work there
        assume(target not in (".",) and not os.path.exists(folder / target.upper()))
    if label == "the manifest":
        (folder / "summary.json").write_text((folder / "m.json").read_text())
        argv = ["batch", "summary.json", "-o", "."]
    else:
        argv = [a.replace("{}", name.upper() if way == "in upper case" else name) for a in template]
    argv += ["--device", "cpu"]
    if way == "in upper case" and label != "the manifest":
        output = argv[argv.index("-o") + 1]
        check(f"meets: {label}", argv, folder, outputs=[output])
        return
    check(f"meets: {label}", argv, folder, outputs=[], expect=2)


# ----------------------------------------------------------------------------------------------------------------
# a binding edited by hand: any field of its records given any value
# ----------------------------------------------------------------------------------------------------------------

FIELDS = [("settings", k) for k in ("method", "resolution", "tol", "solver", "sampling", "mesh", "cage",
                                     "cage_prim", "rest_time", "boundary_settings", "max_iterations")] + \
         [("stats", k) for k in ("format", "device", "handles", "vertices", "method", "seconds", "warnings", "grid",
                                 "solver", "resolution", "made_cage", "converged", "grid_shape")] + \
         [("stats.grid", k) for k in ("shape", "spacing", "interior_nodes")] + \
         [("stats.solver", k) for k in ("preconditioner", "converged", "iterations", "rounds", "levels", "devices")] + \
         [("stats.resolution", k) for k in ("requested", "chosen", "cap")] + \
         [("asset", k) for k in ("path", "up_axis", "meters_per_unit", "time_codes_per_second", "rest_time",
                                 "default_prim")] + \
         [("parts", k) for k in ("path", "vertices", "normals", "to_world")] + \
         [("", k) for k in ("settings", "stats", "parts", "asset", "format", "sources", "cage_fingerprint")]
FIELD_VALUES = st.sampled_from(["abc", "", -1, 0, 1e300, float("nan"), float("inf"), True, None, [], {}, [1, 2],
                                {"x": 1}, 2**70, "Z", "vertex", [[1, 0], [0, 1]], "/Arm/Geo/Skin"])


@budget(60)
@given(field=st.sampled_from(FIELDS), value=FIELD_VALUES, usd=st.booleans(),
       command=st.sampled_from(["deform", "animate", "skin", "show"]))
def test_a_binding_edited_by_hand_is_refused_in_one_line_or_read_whole(scratch, field, value, usd, command):
    folder = scratch()
    source = folder / ("u.npz" if usd else "b.npz")
    with np.load(source) as data:
        arrays = dict(data)
    meta = json.loads(str(arrays["meta"]))
    section, key = field
    if section == "":
        meta[key] = value
    elif section == "parts":
        assume(isinstance(meta.get("parts"), list) and meta["parts"])
        meta["parts"][0][key] = value
    else:
        record = meta
        for name in section.split("."):  # "stats.solver": a record inside the stats
            record = record.get(name) if isinstance(record, dict) else None
        assume(isinstance(record, dict))
        record[key] = value
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(folder / "e.npz", **arrays)
    argv, output = {"deform": (["deform", "e.npz", "bent.npy", "-o", "o.obj"], "o.obj"),
                    "animate": (["animate", "e.npz", "bend_poses.npy", "-o", "o.usda"], "o.usda"),
                    "skin": (["animate", "e.npz", "bend_poses.npy", "--skeleton", "-o", "o.usda"], "o.usda"),
                    "show": (["show", "e.npz", "--handle", "3", "-o", "o.png"], "o.png")}[command]
    argv += ["--device", "cpu"]
    rc, err = check(f"edited binding: {section}.{key}", argv, folder, outputs=[output], rc_ok=(0, 2))
    if rc == 0:
        problem = _valid_output(folder / output)
        if problem:
            defect(f"edited binding: {section}.{key}", f"exit 0 with an output its consumers refuse: {problem}",
                   argv)


# ----------------------------------------------------------------------------------------------------------------
# what a batch is up to date with: every file an asset read
# ----------------------------------------------------------------------------------------------------------------

CHANGES = ["the asset's root layer", "a sublayer", "a referenced layer", "the poses", "its entry",
           "another asset's entry", "nothing, touched"]


@budget(8)
@given(change=st.sampled_from(CHANGES))
def test_a_batch_redoes_an_asset_when_anything_it_read_changed(scratch, change):
    folder = scratch()
    shutil.copy(folder / "arm.usda", folder / "geo.usda")
    (folder / "ref.usda").write_text('#usda 1.0\ndef "Extra" {\n    double weight = 1\n}\n')
    (folder / "hero.usda").write_text('#usda 1.0\n(\n    subLayers = [@./geo.usda@]\n)\n'
                                      'def "Props" (\n    references = @./ref.usda@</Extra>\n) {}\n')
    entry = ('[[asset]]\nname = "hero"\nmesh = "hero.usda"\ncage_prim = "/Arm/Rig/Cage"\nresolution = 8\n'
             'poses = "bend_poses.npy"\n\n[[asset]]\nname = "other"\nmesh = "arm.obj"\ncage = "arm_cage.obj"\n'
             'resolution = 8\n')
    (folder / "h.toml").write_text(entry)
    rc, _, err, escaped = _cli(["batch", "h.toml", "-o", "out", "--device", "cpu"], folder)
    assert rc == 0 and escaped is None, err
    edits = {
        "the asset's root layer": lambda: (folder / "hero.usda").write_text(
            (folder / "hero.usda").read_text() + 'def "Note" {}\n'),
        "a sublayer": lambda: (folder / "geo.usda").write_text((folder / "geo.usda").read_text() + '\ndef "Note" {}\n'),
        "a referenced layer": lambda: (folder / "ref.usda").write_text(
            (folder / "ref.usda").read_text().replace("weight = 1", "weight = 2")),
        "the poses": lambda: np.save(folder / "bend_poses.npy", np.load(folder / "bend_poses.npy") * 1.001),
        "its entry": lambda: (folder / "h.toml").write_text(entry.replace("resolution = 8\nposes",
                                                                          "resolution = 9\nposes")),
        "another asset's entry": lambda: (folder / "h.toml").write_text(entry + "fps = 30\n"),
        "nothing, touched": lambda: os.utime(folder / "geo.usda"),
    }
    edits[change]()
    rc, _, err, escaped = _cli(["batch", "h.toml", "-o", "out", "--device", "cpu"], folder)
    if escaped is not None or rc != 0:
        defect(f"up to date: {change}", f"the second run failed: {escaped or err}")
        return
    status = {a["name"]: a["status"] for a in json.loads((folder / "out" / "summary.json").read_text())["assets"]}
    redo = change not in ("another asset's entry", "nothing, touched")
    if (status["hero"] == "ok") != redo:
        defect(f"up to date: {change}", f"hero was {status['hero']} after {change}")


# ----------------------------------------------------------------------------------------------------------------
# class 6: faults in the writer
# ----------------------------------------------------------------------------------------------------------------

# commands that write several files, run once before (their outputs exist) and again with a fault
GROUPS = [
    ("bind auto", ["bind", "arm.obj", "auto", "-o", "B.npz", "--resolution", "8", "--handles", "{handles}"],
     ["B.npz", "B.cage.obj"]),
    ("batch", ["batch", "m.toml", "-o", "out", "--force"], ["out/a.npz", "out/a.usd", "out/summary.json"]),
]
FAULTS = ["rename", "link", "file size", "write"]


@contextlib.contextmanager
def fault(kind: str, after: int):
    """The writer made to fail as a full disk or a failing file system does: the ``after``-th rename (or hard link,
    or open for writing) fails, once, or files cannot grow beyond ``after`` kB."""
    if kind == "file size":
        previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (after * 1024, hard))
        try:
            yield
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
            signal.signal(signal.SIGXFSZ, previous)
        return
    import builtins

    calls = [0]
    target = {"rename": (os, "replace"), "link": (os, "link"), "write": (builtins, "open")}[kind]
    real = getattr(*target)

    def failing(*args, **kwargs):
        if kind == "write" and not any(m in str(args[1] if len(args) > 1 else kwargs.get("mode", "r"))
                                       for m in "wax"):
            return real(*args, **kwargs)
        calls[0] += 1
        if calls[0] == after:
            raise OSError(errno.ENOSPC if kind == "write" else errno.EIO, os.strerror(errno.ENOSPC))
        return real(*args, **kwargs)

    setattr(*target, failing)
    try:
        yield
    finally:
        setattr(*target, real)


@budget(30)
@given(group=st.sampled_from(GROUPS), kind=st.sampled_from(FAULTS), after=st.integers(1, 3))
def test_a_fault_in_the_writer_leaves_every_output_as_it_was(scratch, written, group, kind, after):
    label, template, outputs = group
    first = [a.replace("{handles}", "40") for a in template] + ["--device", "cpu", "--quiet"] \
        if template[0] == "bind" else [a.replace("{handles}", "40") for a in template] + ["--device", "cpu"]
    folder = scratch(written(label, first))  # the first run is the same for every example: run once, copied
    again = [a.replace("{handles}", "48") for a in first]
    before = snapshot(folder)
    with fault(kind, after if kind != "file size" else 16 * after):
        rc, out, err, escaped = _cli(again, folder)
    after_snapshot = snapshot(folder)
    note(f"rc={rc} err={err!r}")
    if escaped is not None:
        defect(f"faults: {label}", f"escaped: {type(escaped).__name__}: {escaped}", again)
        return
    errors = _errors(err)
    if rc == 2 and len(errors) != 1:
        defect(f"faults: {label}", f"exit 2 with {len(errors)} error lines: {err!r}", again)
    changed = sorted(k for k in set(before) | set(after_snapshot) if before.get(k) != after_snapshot.get(k))
    whole = [o for o in outputs if not o.endswith("summary.json")]  # written together, or none of them
    if [o for o in whole if o in changed] not in ([], whole):
        defect(f"faults: {label}", f"exit {rc}; of the outputs written together only {changed[:5]} changed: "
                                   f"{errors[-1:]}", again)
    if rc == 2 and label != "batch" and changed:  # (a batch's summary may fail after its assets were written)
        defect(f"faults: {label}", f"failed, yet changed {changed[:5]}: {errors[-1:]}", again)
    if rc == 0 and label == "bind auto":  # a binding and the cage it was bound to, from the same run
        import warp_stokes as ws

        binding = ws.load_binding(folder / "B.npz", device="cpu")
        cage = ws.load_surface(folder / "B.cage.obj")
        if not np.allclose(cage.vertices, binding.cage_vertices, atol=1e-6 * np.ptp(cage.vertices)):
            defect(f"faults: {label}", "the binding and its cage file are of different runs", again)
    stray = [k for k in changed if not any(k == o or k.startswith(o + os.sep) for o in outputs)]
    if stray:
        defect(f"faults: {label}", f"exit {rc}; changed outside its outputs: {stray[:5]}", again)


# ----------------------------------------------------------------------------------------------------------------
# the library: options checked where they enter
# ----------------------------------------------------------------------------------------------------------------

OPTION_VALUES = st.sampled_from([2.5, True, False, "8", "Y", -1, 0, 8, float("nan"), float("inf"), 1e40, 1e-40, [8],
                                  2**40, np.float64(24.0), np.int64(4)])


def _takes(option: str, value, handles: int) -> bool:
    """Whether ``value`` is one the option takes (as documented)."""
    real = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if option == "influences":
        return real and float(value).is_integer() and isinstance(value, (int, np.integer)) and 1 <= value <= handles
    if option in ("max_error", "fps", "meters_per_unit"):
        return real and np.isfinite(value) and 1.1754943508222875e-38 <= value <= 3.4028234663852886e38
    if option in ("non_negative", "with_cage"):
        return isinstance(value, (bool, np.bool_))
    return value in ("Y", "Z")


@budget(60)
@given(option=st.sampled_from(["influences", "max_error", "fps", "non_negative", "with_cage", "up_axis",
                               "meters_per_unit"]), value=OPTION_VALUES, skin=st.booleans())
def test_the_library_takes_an_option_or_refuses_it_in_one_error(scratch, workspace, option, value, skin):
    import warp_stokes as ws

    assume(skin or option not in ("influences", "max_error", "non_negative"))
    binding = ws.load_binding(workspace / "b.npz", device="cpu")
    poses = np.load(workspace / "bend_poses.npy")[:3]
    folder = scratch()
    before = snapshot(folder)
    write = ws.write_skin if skin else ws.write_animation
    takes = _takes(option, value, binding.n_handles)
    try:
        write(str(folder / "o.usda"), binding, poses, **{option: value})
    except ws.WarpStokesError as exc:
        if takes:
            defect(f"library: {option}", f"{option}={value!r} refused: {exc}")
        if snapshot(folder) != before:
            defect(f"library: {option}", "refused, yet files changed")
    except Exception as exc:
        defect(f"library: {option}", f"{type(exc).__name__}: {exc} for {option}={value!r}")
    else:
        if not takes:
            defect(f"library: {option}", f"{option}={value!r} accepted")
