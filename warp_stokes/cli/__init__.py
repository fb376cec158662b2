"""Command line: ``warp-stokes cage | bind | deform | animate | encode | batch | sweep | show | edit``."""

from __future__ import annotations

import argparse
import math
import os
import sys
import warnings

from ..arguments import number
from ..errors import WarpStokesError
from . import commands
from .commands import format_stats

__all__ = ["main", "format_stats"]


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print(one_line(f"warning: {message}"), file=sys.stderr)


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (exit code 2), as every other error of the command."""

    def error(self, message):
        self.exit(2, one_line(f"{self.prog}: error: {message}") + "\n")


def _number(kind, low=None, high=None, low_open=False):
    """An argparse type: ``kind`` (int or float) within [low, high] (low excluded with ``low_open``), finite, and for
    floats within float32's range (every number the package stores or computes with in its kernels is float32)."""

    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        try:
            return number(value, "", low, high, low_open, integer=kind is int)
        except WarpStokesError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = kind.__name__  # what argparse names in "invalid int value"
    return parse


def _resolution(text: str):
    """An argparse type: "auto", or an integer >= 1 (bind names the range it takes)."""
    if text == "auto":
        return text
    try:
        int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither auto nor an integer") from None
    return _number(int, 1)(text)


_resolution.__name__ = "resolution"


def _resolutions(text: str) -> list:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of integers") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give resolutions >= 1, e.g. 16,24,32")
    return values


def _key_frames(text: str) -> list:
    """An argparse type: comma-separated frame numbers, finite and strictly increasing (their count is checked
    against the poses once they are loaded)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of numbers, e.g. 0,12,30") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: give finite frame numbers, e.g. 0,12,30")
    if any(b <= a for a, b in zip(values, values[1:])):
        raise argparse.ArgumentTypeError(f"{text!r}: the frame numbers must be strictly increasing")
    return values


def _slice(text: str) -> tuple:
    """An argparse type: ``AXIS=FRACTION`` (e.g. ``z=0.5``), the fraction of the cage's box along x, y or z."""
    axis, _, fraction = text.partition("=")
    try:
        value = float(fraction)
    except ValueError:
        value = None
    if axis.strip().lower() not in ("x", "y", "z") or value is None or not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text!r} is not AXIS=FRACTION with x, y or z and a fraction in [0, 1], "
                                         "e.g. z=0.5")
    return axis.strip().lower(), value


def one_line(text: str) -> str:
    """``text`` as one printable line: control characters (a newline in a file name) and bytes of a name that are
    not text (surrogates) written as escapes, so that every error is one line and printing it cannot fail.

    Examples
    --------
    >>> print(one_line("take\\n2.obj: no such file"))
    take\\n2.obj: no such file
    """
    text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


def main(argv=None) -> int:
    """Entry point of the ``warp-stokes`` command: its exit code (0 done, 1 a solve that did not converge or an asset
    that failed, 2 bad input or a failed write, 130 interrupted by Ctrl-C, 128 + N by signal N: SIGTERM, SIGHUP)."""
    from ..io.outputs import Interrupted, interrupt_on_signals

    for stream in (sys.stdout, sys.stderr):  # a file name of any bytes prints (escaped) instead of failing
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    try:
        with interrupt_on_signals():
            return _main(argv)
    except KeyboardInterrupt:
        # outputs are written under temporary names and renamed when complete: nothing half-written stays
        print("warp-stokes: interrupted; no output was left half-written", file=sys.stderr)
        return 130
    except Interrupted as exc:
        import signal

        print(f"warp-stokes: interrupted ({signal.Signals(exc.signum).name}); no output was left half-written",
              file=sys.stderr)
        return 128 + exc.signum


def _values_taken_whole(parser: argparse.ArgumentParser, argv: list) -> list:
    """``argv`` with the values that start with a dash taken as values, as a user means them: an option's value
    joined to it (``--key-frames -10,0,10``, ``-o -take2.usd``), and a file named like an option (``-take2.npy``,
    no option of the command) given as ``./-take2.npy``. argparse would read each as an option of its own."""
    sub = parser._subparsers._group_actions[0].choices.get(argv[0]) if argv and parser._subparsers else None
    if sub is None:
        return argv
    options = sub._option_string_actions

    def is_option(token: str) -> bool:  # an option's name, or the start of one (argparse takes abbreviations)
        name = token.split("=", 1)[0]
        return name in options or (name.startswith("--") and any(o.startswith(name) for o in options))

    joined, k = [argv[0]], 1
    while k < len(argv):
        token = argv[k]
        action = options.get(token)
        if (action is not None and action.nargs is None and k + 1 < len(argv) and argv[k + 1].startswith("-")
                and not is_option(argv[k + 1]) and argv[k + 1] != "--"):
            joined.append(f"{max(action.option_strings, key=len)}={argv[k + 1]}")
            k += 2
            continue
        if token == "--":
            joined += argv[k:]
            break
        if token.startswith("-") and token != "-" and not is_option(token) and os.path.lexists(token):
            token = os.path.join(".", token)
        joined.append(token)
        k += 1
    return joined


def _parser() -> argparse.ArgumentParser:
    """The command line: one subcommand per stage of the data's way (bind, deform, animate) and batches of them."""
    from warp_stokes import __version__

    parser = _Parser(prog="warp-stokes", description="Stokes cage coordinates with NVIDIA Warp.")
    parser.add_argument("--version", action="version", version=f"warp-stokes {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for add in (_add_cage, _add_bind, _add_deform, _add_animate, _add_encode, _add_batch, _add_sweep, _add_show,
                _add_edit):
        add(sub)
    return parser


def _add_cage(sub) -> None:
    p = sub.add_parser("cage", help="make a cage for a mesh that has none: closed, enclosing every vertex, with about "
                                    "the handles asked for")
    p.add_argument("mesh", help="mesh file (OBJ, PLY, OFF, STL, glTF/GLB, ...) or a USD asset (all its meshes, in "
                                "world space); open, self-intersecting and many-piece meshes are fine")
    p.add_argument("-o", "--output", required=True,
                   help="cage file to write (obj, ply or off), or for a USD asset a layer over it (usd, usda or usdc) "
                        "that defines the cage as a prim")
    p.add_argument("--cage-prim", default=None, metavar="PATH",
                   help="with a USD layer: the cage prim's path (default /<default prim>/MadeCage); then bind the "
                        "layer with --cage-prim PATH")
    p.add_argument("--handles", type=_number(int, 8), default=None,
                   help="the cage's vertex count (default: chosen from the mesh's shape, and printed)")
    p.add_argument("--offset", type=_number(float, 0.0, 0.5, low_open=True), default=None,
                   help="how far the cage starts from the mesh, as a fraction of its bounding diagonal (default "
                        "0.02, raised where the handles asked are not reached): larger leaves more room to "
                        "simplify, smaller fits tighter")
    p.add_argument("--mesh-prim", action="append", default=None, metavar="PATH",
                   help="a mesh prim of the USD asset to enclose (repeat for several; default: all its meshes)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N (default: CUDA when present)")
    p.set_defaults(run=commands.cage_command)


def _add_bind(sub) -> None:
    p = sub.add_parser("bind", help="compute the weights of a mesh's vertices with respect to a cage")
    p.add_argument("mesh", help="mesh file (OBJ, PLY, OFF, STL, glTF/GLB, ...) or a USD asset (all its meshes)")
    p.add_argument("cage", nargs="?", default=None,
                   help="closed cage mesh file, or a USD file with --cage-prim (optional when --cage-prim names a prim "
                        "of the mesh's USD asset), or 'auto': a cage made for the mesh (as 'warp-stokes cage' makes it "
                        "with its defaults), written beside the binding as OUTPUT.cage.obj")
    p.add_argument("--cage-prim", default=None, metavar="PATH", help="the cage's mesh prim in the USD stage")
    p.add_argument("--handles", type=_number(int, 8), default=None,
                   help="with cage auto: the made cage's vertex count (default: chosen from the mesh's shape)")
    p.add_argument("--offset", type=_number(float, 0.0, 0.5, low_open=True), default=None,
                   help="with cage auto: how far the made cage starts from the mesh, as a fraction of its bounding "
                        "diagonal (default 0.02, raised where the handles asked are not reached)")
    p.add_argument("--mesh-prim", action="append", default=None, metavar="PATH",
                   help="a mesh prim of the USD asset to bind (repeat for several; default: all but the cage)")
    p.add_argument("--rest-time", type=_number(float), default=None,
                   help="USD time code of the rest pose (default: the cage prim's first time sample)")
    p.add_argument("-o", "--output", required=True, help="binding file to write (.npz)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress line (it is drawn on stderr only when stderr is a terminal)")
    p.add_argument("--resolution", type=_resolution, default="auto",
                   help="grid cells along the cage's longest axis, or auto (the default): 64, more where the cage's "
                        "folded edges need it, at most 96 on a CPU and 256 on a GPU")
    p.add_argument("--device", default=None,
                   help="cpu, cuda or cuda:N (default: CUDA when present, else CPU); several (cuda:0,cuda:1, or cuda:all "
                        "for every GPU) solve shares of the handles at once, as Ray tasks (the ray extra)")
    p.add_argument("--tol", type=_number(float, 0.0, 0.1, low_open=True), default=1e-6, help="solver tolerance (1e-6)")
    p.add_argument("--max-iterations", type=_number(int, 1), default=None, help="solver iteration limit")
    p.add_argument("--solver", choices=["multigrid", "jacobi"], default="multigrid",
                   help="CG preconditioner (multigrid)")
    p.add_argument("--memory-gb", type=_number(float, 0.0, low_open=True), default=None,
                   help="memory budget in GiB (default: 90%% of free GPU memory, half the free RAM on CPU)")
    p.add_argument("--threads", type=_number(int, 1), default=None,
                   help="on a CPU, threads that solve chunks of handles at once (default: every core)")
    p.add_argument("--boundary", choices=["local", "mvc"], default="local",
                   help="boundary data: local to each node's closest cage point (default) or mean value coordinates")
    p.add_argument("--sampling", choices=["hermite", "trilinear"], default="hermite",
                   help="weights at the vertices: C1 tricubic Hermite of values and gradients (default) or trilinear")
    p.add_argument("--method", choices=["stokes", "harmonic", "mvc"], default="stokes",
                   help="Stokes coordinates (default); harmonic coordinates (Laplace on the same grid and data); or "
                        "mean value coordinates at the vertices (no grid)")
    p.set_defaults(run=commands.bind_command)


def _add_deform(sub) -> None:
    p = sub.add_parser("deform", help="deform the bound mesh with a deformed cage and write it")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("cage", help="deformed cage with the bound cage's topology (faces in any order), or its "
                                "vertex positions as a .npy array of shape (L, 3)")
    p.add_argument("-o", "--output", required=True, help="mesh file to write (obj, ply, off, stl, glb)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=commands.deform_command)


def _add_animate(sub) -> None:
    p = sub.add_parser("animate", help="write the bound mesh, deformed by a sequence of cage poses, as animated USD "
                                       "(baked points, or a UsdSkel rig / glTF skin that consumers play live)")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("poses", help="cage poses: a folder of OBJ frames, a .npy/.npz array (F, L, 3) or a USD file "
                                 "(one pose per time sample of --cage-prim)")
    p.add_argument("-o", "--output", required=True, help="USD file to write (.usd/.usdc binary, .usda text; for a "
                                                         "binding of a USD asset, a layer over it), or a glTF skin "
                                                         "(.glb, .gltf)")
    p.add_argument("--cage-prim", default=None, metavar="PATH",
                   help="the cage's prim in the poses' USD file (default: the first mesh with the cage's point count)")
    p.add_argument("--asset", default=None, help="the bound USD asset, where it is not at the path the binding records")
    p.add_argument("--fps", type=_number(float, 0.0, low_open=True), default=None,
                   help="time codes per second (default: the poses' USD stage's, else 24)")
    p.add_argument("--key-frames", type=_key_frames, default=None, metavar="F,F,...",
                   help="the poses are keys at these frame numbers (one per pose, increasing, e.g. 0,12,30); the "
                        "frames between them are interpolated")
    p.add_argument("--inbetween", type=_number(int, 0), default=None, metavar="K",
                   help="write K interpolated frames between each two key poses (default with --key-frames: every "
                        "integer frame)")
    p.add_argument("--interpolation", choices=["linear", "spline"], default=None,
                   help="between keys: linear (default) or a natural cubic spline (with --key-frames or --inbetween)")
    p.add_argument("--with-cage", action="store_true", help="also write the animated cage (/Root/Cage)")
    p.add_argument("--with-weights", action="store_true", help="write the weights as a primvar")
    p.add_argument("--skeleton", action="store_true",
                   help="write a UsdSkel rig instead of baked points: one joint per cage handle, its translations per "
                        "frame, the meshes skinned to it (a .glb/.gltf output is always a skin)")
    p.add_argument("--influences", type=_number(int, 1), default=None, metavar="K",
                   help="joints per vertex of the skin (default: all for USD, exact; 8 for glTF); fewer are chosen by "
                        "weight and renormalised, and the error this makes is measured and printed")
    p.add_argument("--non-negative", action="store_true",
                   help="drop negative weights from the skin (for consumers that ignore them, e.g. Blender; glTF "
                        "always does)")
    p.add_argument("--max-error", type=_number(float, 0.0, low_open=True), default=None, metavar="E",
                   help="refuse a skin further than E x the mesh's diagonal from the cage deformation over the poses")
    p.add_argument("--up-axis", choices=["Y", "Z"], default=None, help="stage up axis (Y; over an asset, the asset's)")
    p.add_argument("--meters-per-unit", type=_number(float, 0.0, low_open=True), default=None,
                   help="stage metersPerUnit (1.0; over an asset, the asset's)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=commands.animate_command)


def _add_encode(sub) -> None:
    p = sub.add_parser("encode", help="the cage poses that best reproduce a sequence of meshes (least squares)")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind', or 'auto': a sequence without a cage "
                                   "(OBJ frames, a USD file or a rigged glTF/GLB): a cage made for its first frame (a "
                                   "rigged file's rest pose), bound, and both written beside the poses "
                                   "(OUTPUT.cage.obj, OUTPUT.binding.npz)")
    p.add_argument("frames", help="meshes with the bound mesh's topology: a folder of OBJ frames, a .npy/.npz array "
                                  "(F, V, 3), a USD file (time samples, or its UsdSkel skinning), or a skinned "
                                  "glTF/GLB (its animation, skinned: --animation)")
    p.add_argument("-o", "--output", required=True, help="poses to write: .npy (F, L, 3) or USD (an animated cage)")
    p.add_argument("--smooth", type=_number(float, 0.0), default=0.0,
                   help="weight of each handle's squared change between consecutive frames (0)")
    p.add_argument("--mesh-prim", action="append", default=None, metavar="PATH",
                   help="for USD frames: the mesh prim(s) to read (default: the binding's parts, else the first "
                        "mesh with the bound mesh's point count)")
    p.add_argument("--animation", default=None, metavar="NAME",
                   help="for a rigged glTF/GLB: the animation to read (its name; required when it has several); for "
                        "a UsdSkel asset: a SkelAnimation prim (path or name) to play instead of the skeletons' own")
    p.add_argument("--fps", type=_number(float, 0.0, low_open=True), default=None,
                   help="for a rigged file: sample its animation at this rate from its first key to its last "
                        "(default: at its key times)")
    p.add_argument("--resolution", type=_resolution, default=None,
                   help="with binding auto: the bind's grid cells along the cage's longest axis (default auto, as "
                        "for bind)")
    p.add_argument("--device", default=None,
                   help="where the products over the vertices are summed: cpu (BLAS), cuda or cuda:N (default: CUDA "
                        "when present)")
    p.set_defaults(run=commands.encode_command)


def _add_sweep(sub) -> None:
    p = sub.add_parser("sweep", help="bind at several resolutions (Stokes, harmonic, MVC) and tabulate cost and "
                                     "convergence")
    p.add_argument("mesh", help="mesh file")
    p.add_argument("cage", help="closed cage mesh file")
    p.add_argument("--resolutions", type=_resolutions, required=True, help="comma-separated, e.g. 16,24,32")
    p.add_argument("--methods", default="stokes", help="comma-separated: stokes, harmonic, mvc (default stokes)")
    p.add_argument("--pose", default=None, help="a deformed cage (file or .npy (L, 3)): adds the conformal "
                                                "distortion's 95th percentile")
    p.add_argument("-o", "--output", required=True, help="folder for sweep.csv and sweep.json")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.add_argument("--tol", type=_number(float, 0.0, 0.1, low_open=True), default=1e-6, help="solver tolerance")
    p.add_argument("--threads", type=_number(int, 1), default=1,
                   help="on a CPU, threads per bind (default 1: each row's peak memory the same from run to run)")
    p.set_defaults(run=commands.sweep_command)


def _add_show(sub) -> None:
    p = sub.add_parser("show", help="draw a handle's weight on a slice, or the (deformed) mesh's distortion or its cage (PNG)")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("--handle", type=_number(int, 0), default=None, metavar="L",
                   help="draw handle L's weight on a slice through the cage; handles count from 0 in the cage's "
                        "vertex order (0 to handles - 1)")
    p.add_argument("--slice", type=_slice, default=None, metavar="AXIS=F",
                   help="with --handle: the plane at fraction F of the cage's box along x, y or z (default z=0.5)")
    p.add_argument("--pose", default=None, help="draw the mesh deformed by this cage (file or .npy (L, 3)), coloured "
                                                "by conformal distortion")
    p.add_argument("--error", default=None, metavar="MESH",
                   help="colour the (deformed) mesh by its distance to this reference mesh instead")
    p.add_argument("--with-cage", action="store_true",
                   help="draw the cage's edges over the mesh (posed with it); alone, the rest mesh in its cage")
    p.add_argument("--view", choices=["front", "side", "top"], default=None,
                   help="the mesh's orthographic view (default front: along -z, +y up; a Z-up asset's: along +y)")
    p.add_argument("-o", "--output", required=True, help="picture to write (.png)")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=commands.show_command)


def _add_batch(sub) -> None:
    p = sub.add_parser("batch", help="bind (and animate) every asset of a TOML or JSON manifest")
    p.add_argument("manifest", help="manifest file (.toml or .json); see the README")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--force", action="store_true", help="redo assets whose outputs are up to date")
    p.add_argument("--workers", type=_number(int, 1), default=None,
                   help="bind in N Ray worker processes on a local Ray cluster (on a GPU host, default one per GPU); "
                        'needs pip install "warp-stokes[ray]"')
    p.add_argument("--ray-address", default=None, metavar="ADDRESS",
                   help="join this Ray cluster (e.g. auto) instead of starting one")
    p.add_argument("--device", default=None, help="cpu, cuda or cuda:N")
    p.set_defaults(run=commands.batch_command)


def _add_edit(sub) -> None:
    p = sub.add_parser("edit", help="edit the bound mesh by its cage, live, in the browser (needs pip install "
                                    "'warp-stokes[edit]')")
    p.add_argument("binding", help="binding file written by 'warp-stokes bind'")
    p.add_argument("poses", nargs="?", default=None,
                   help="cage poses to start from, each a key at its frame (what 'animate' takes)")
    p.add_argument("-o", "--output", default=None,
                   help="where the page's Save writes: poses (.npy, .npz) for 'animate', or the mesh as USD or a "
                        "glTF skin (default edited.npz)")
    p.add_argument("--cage-prim", default=None, metavar="PATH", help="the cage's prim in the poses' USD file")
    p.add_argument("--scheme", choices=["arap", "laplacian", "none"], default="arap",
                   help="how the handles neither moved nor pinned follow a move (default arap: as rigid as possible)")
    p.add_argument("--interpolation", choices=["linear", "spline"], default="linear",
                   help="how the timeline in-betweens keys")
    p.add_argument("--host", default="127.0.0.1",
                   help="the address the page is served on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=_number(int, 1, 65535), default=8080, help="the port (the next free one if taken)")
    p.set_defaults(run=commands.edit_command)


def _main(argv) -> int:
    parser = _parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(_values_taken_whole(parser, argv))
    except SystemExit as exc:  # --help, --version, or a bad argument (one line on stderr already)
        return exc.code if isinstance(exc.code, int) else 2
    from warp_stokes.errors import ConvergenceError
    from warp_stokes.io.door import reading

    # warnings are shown once the command has run, so that bad input ends in its one-line error alone
    with warnings.catch_warnings(record=True) as caught, reading():
        warnings.simplefilter("always")
        try:
            rc = args.run(args)
        except ConvergenceError as exc:  # not bad input: the solve could not give exact weights (none written)
            print(one_line(f"warp-stokes: error: {exc}"), file=sys.stderr)
            return 1
        except (WarpStokesError, OSError) as exc:
            print(one_line(f"warp-stokes: error: {exc}"), file=sys.stderr)
            return 2

    shown = set()
    for w in caught:
        if str(w.message) not in shown:
            shown.add(str(w.message))
            _show_warning(w.message, w.category, w.filename, w.lineno)
    return rc
