"""The package's layout: data flows one way (io -> geometry -> solver -> binding -> commands), nothing imports
upward, and the kernels import nothing of the package."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "warp_stokes"
#: each folder's place in the flow; a module may import from its own place and the ones before it
LAYERS = {"errors": 0, "arguments": 0, "lazy": 0, "threads": 0, "memory": 0, "kernel_cache": 0, "cluster": 0,
          "device": 0, "kernels": 0, "io": 1, "geometry": 2, "solver": 3,
          "binding": 4, "quality": 5, "batch": 5, "sweep": 5, "show": 5, "edit": 5, "cli": 5}


def layer_of(parts: tuple[str, ...]) -> int:
    """The layer of a module given by its path inside the package, e.g. ("geometry", "grid")."""
    return LAYERS[parts[0]] if parts and parts[0] in LAYERS else 6  # the package's __init__ is on top


def imported_modules(path: Path):
    """(line, module path inside the package) for every relative import of the file at ``path``."""
    here = path.relative_to(PACKAGE).with_suffix("").parts
    package = here[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = package[: len(package) - (node.level - 1)]
            target = base + (tuple(node.module.split(".")) if node.module else ())
            if node.module is None:  # from . import name: each name is a module of that package, or a name of it
                for alias in node.names:
                    yield node.lineno, target + (alias.name,)
            else:
                yield node.lineno, target


MODULES = sorted(p for p in PACKAGE.rglob("*.py") if p.name != "__init__.py")


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_nothing_imports_upward(path):
    own = layer_of(path.relative_to(PACKAGE).with_suffix("").parts)
    for line, target in imported_modules(path):
        if target in ((), ("__version__",)):
            continue  # the package's version
        assert layer_of(target) <= own, f"{path.relative_to(ROOT)}:{line} imports {'.'.join(target)} from above"


def test_the_kernels_are_math_only():
    for path in (ROOT / "kernels").glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level > 1:
                raise AssertionError(f"{path.name}:{node.lineno} imports from the package")
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("warp_stokes"):
                raise AssertionError(f"{path.name}:{node.lineno} imports the package")


def test_every_public_name_resolves():
    import warp_stokes as ws

    for name in ws.__all__:
        assert getattr(ws, name) is not None, name
    assert set(ws.__all__) <= set(dir(ws))


def test_help_and_version_start_without_warp():
    """The package's names are imported on first use: the command's help and version load no Warp, numpy or
    trimesh (0.05 s instead of 0.8 s on the 2-core development machine)."""
    import subprocess
    import sys

    script = ("import sys; from warp_stokes.cli import main\n"
              "code = main(sys.argv[1:])\n"
              "heavy = sorted(m for m in ('warp', 'numpy', 'trimesh', 'pxr') if m in sys.modules)\n"
              "print('HEAVY', heavy); sys.exit(code)")
    for flag in ("--help", "--version"):
        result = subprocess.run([sys.executable, "-c", script, flag], capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
        assert "HEAVY []" in result.stdout, (flag, result.stdout[-200:])


def module_graph() -> dict:
    """Each module of the package (a dotted path inside it; a package by its ``__init__``) -> the modules of the
    package it imports anywhere in its file, at its top or inside a function: an import put inside a function still
    ties the two modules."""
    modules = {p.relative_to(PACKAGE).with_suffix("").parts: p for p in PACKAGE.rglob("*.py")}
    names = {(parts[:-1] if parts[-1] == "__init__" else parts): path for parts, path in modules.items()}
    graph = {}
    for name, path in names.items():
        targets = set()
        for _, target in imported_modules(path) if path.name != "__init__.py" else _init_imports(path, name):
            while target and target not in names:  # a name of a module: the module
                target = target[:-1]
            if target and target != name:
                targets.add(target)
        graph[name] = targets
    return graph


def _init_imports(path: Path, package: tuple):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = package[: len(package) - (node.level - 1)]
            yield node.lineno, base + (tuple(node.module.split(".")) if node.module else ())


def cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(".".join(c) for c in component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_modules_import_each_other_in_a_circle():
    # imports inside functions count: one put there to break an import-time circle still ties the modules
    assert cycles(module_graph()) == []


def test_every_import_of_the_package_names_one_of_its_modules():
    # an import inside a function is checked only when it runs: here, every one is, at once
    modules = {p.relative_to(PACKAGE).with_suffix("").parts for p in PACKAGE.rglob("*.py")}
    names = {m[:-1] if m[-1] == "__init__" else m for m in modules} | {("kernels",), ("__version__",), ()}
    kernels = {("kernels", p.stem) for p in (ROOT / "kernels").glob("*.py")}
    for path in MODULES:
        for line, target in imported_modules(path):
            assert target in names | kernels or target[:-1] in names | kernels, \
                f"{path.relative_to(ROOT)}:{line} imports {'.'.join(target)}, which is no module of the package"
