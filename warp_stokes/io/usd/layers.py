"""A USD file's layer stack, every layer of it checked before any stage is composed: each is a regular file that USD
can parse. ``Usd.Stage.Open`` skips a sublayer it cannot read with a warning and composes the rest, which would
bind or animate a stage that is not the user's; here that is one error naming the layer."""

from __future__ import annotations

import functools
import glob
import os
import re
from dataclasses import dataclass

from ...errors import MeshError
from ..door import checked_input, reason, record_read

__all__ = ["LayerStack", "layer_stack", "usd_reason", "reads_usd"]


@dataclass
class LayerStack:
    """The layers of a USD file, opened and held (so that a stage opened while this is alive composes these very
    layers), and every file they name.

    Attributes
    ----------
    layers : list of Sdf.Layer
    files : list of str, real paths: the layers' files and the other assets they name (textures, ...), in the order
        found, the root first
    """

    layers: list
    files: list


def _is_layer(path: str) -> bool:
    from pxr import Sdf

    ext = os.path.splitext(path.split("[", 1)[0])[1].lstrip(".")
    return bool(ext) and Sdf.FileFormat.FindByExtension(ext) is not None


def _template_files(pattern: str) -> list[str]:
    """The files a value-clip template (``frames.###.usd``, ``frames.#.##.usd``) can name: every file matching it."""
    return sorted(glob.glob(re.sub(r"#+", "*", glob.escape(pattern).replace("[#]", "#"))))


def _clip_paths(layer) -> list[str]:
    """The asset paths a layer's value clips name: each clip set's ``assetPaths``, ``manifestAssetPath`` and
    ``templateAssetPath`` (still a pattern)."""
    found = []

    def visit(path):
        spec = layer.GetPrimAtPath(path) if path.IsPrimPath() else None
        clips = spec.GetInfo("clips") if spec is not None and spec.HasInfo("clips") else None
        for clip_set in (clips or {}).values():
            if not hasattr(clip_set, "get"):
                continue
            for asset in list(clip_set.get("assetPaths") or []) + [clip_set.get("manifestAssetPath")]:
                value = getattr(asset, "path", asset)
                if isinstance(value, str) and value:
                    found.append(value)
            template = clip_set.get("templateAssetPath")
            if isinstance(template, str) and template:
                found.append(template)

    layer.Traverse(layer.pseudoRoot.path, visit)
    return found


def _open(path: str, root: str, error):
    """One layer, opened guarded: an unreadable one is ``error`` naming it (and the file whose stack it is in)."""
    from pxr import Sdf, Tf

    where = path if os.path.realpath(path) == os.path.realpath(root) else f"{root}: its layer {path}"
    checked_input(path, error, "USD")
    try:
        layer = Sdf.Layer.Find(path)
        if layer is not None:
            layer.Reload()  # a layer still held from an earlier read: what the file holds now
        else:
            layer = Sdf.Layer.FindOrOpen(path)
    except Tf.ErrorException as exc:
        raise error(f"{where}: cannot read it as USD ({usd_reason(exc)})") from None
    except UnicodeError:  # USD takes UTF-8 names only
        raise error(f"{where}: USD cannot open a file whose name is not UTF-8; rename it") from None
    if layer is None:
        raise error(f"{where}: cannot read it as USD")
    record_read(path)
    return layer


def usd_reason(exc) -> str:
    """What a USD error says, without its C++ location and namespaces (``file.usda:2:1: parse error ...``)."""
    try:
        text = " ".join(str(exc).split())
    except Exception:  # pxr's message holds bytes that are not UTF-8
        return "the file is not valid USD"
    quoted = re.search(r" : '(.*)'$", text)
    text = quoted.group(1) if quoted else text
    text = re.sub(r"pxrInternal_\w*?__pxrReserved__(::|_+)?", "", text)
    return reason(text or type(exc).__name__)


def reads_usd(error=MeshError, path_argument: int = 0):
    """A function that reads values of a USD file named by its positional argument ``path_argument``: an error USD
    raises while it reads (a value it cannot decode in a damaged crate file, found only when read) becomes one
    ``error`` naming the file. The layer stack was checked when the stage opened; values are read on demand."""

    def wrap(function):
        @functools.wraps(function)
        def reading(*args, **kwargs):
            try:
                return function(*args, **kwargs)
            except RuntimeError as exc:
                if type(exc).__name__ != "ErrorException":  # not pxr's Tf.ErrorException
                    raise
                raise error(f"{args[path_argument]}: cannot read it as USD ({usd_reason(exc)})") from None

        return reading

    return wrap


def layer_stack(path, error=MeshError) -> LayerStack:
    """Open every layer of a USD file: its root, the layers it sublayers, references or takes as payloads, and the
    layers of its value clips, recursively; the other assets its attributes name (textures) are listed, not opened.

    Parameters
    ----------
    path : str | os.PathLike, a USD file
    error : the WarpStokesError subclass to raise

    Returns
    -------
    LayerStack

    Raises
    ------
    ``error`` naming the layer: missing, not a regular file, or not readable as USD

    Examples
    --------
    >>> stack = layer_stack("examples/arm/arm.usda")   # doctest: +SKIP
    >>> len(stack.layers), stack.files[0].endswith("arm.usda")   # doctest: +SKIP
    (1, True)
    """
    from pxr import UsdUtils

    root = os.fspath(path)
    layers, files, seen = [], [], set()
    pending = [os.path.abspath(root)]
    while pending:
        name = pending.pop(0)
        real = os.path.realpath(name.split("[", 1)[0])
        if real in seen:
            continue
        seen.add(real)
        files.append(real)
        layer = _open(name, root, error)
        layers.append(layer)
        sublayers, references, payloads = UsdUtils.ExtractExternalReferences(layer.identifier)
        names = list(sublayers) + list(references) + list(payloads) + _clip_paths(layer)
        for dependency in dict.fromkeys(names):
            absolute = layer.ComputeAbsolutePath(dependency) if dependency else ""
            if not absolute:
                continue
            if "#" in dependency:  # a clip template: the files it matches now
                pending += _template_files(absolute)
            elif _is_layer(absolute):
                pending.append(absolute)
            elif os.path.realpath(absolute) not in seen:  # a texture or another asset: an input, not a layer
                seen.add(os.path.realpath(absolute))
                files.append(os.path.realpath(absolute))
    return LayerStack(layers, files)
