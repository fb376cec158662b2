"""The package's names: every public name a (sub)package hands on is the object it names, whatever was imported
before it. A lazily named function that shares its name with a module of its package would be that module once the
module is imported (Python sets a package's attribute to each submodule it imports): `ws.make_cage(...)` then called
a module."""

import importlib
import os
import pkgutil
import subprocess
import sys

import warp_stokes as ws

HOME = [os.path.dirname(ws.__file__)]  # the package's own folder (a checkout's __path__ also holds the kernels')
PACKAGES = ["warp_stokes", *(f"warp_stokes.{m.name}" for m in pkgutil.iter_modules(HOME) if m.ispkg)]


def test_no_public_name_of_a_package_is_also_one_of_its_modules():
    for name in PACKAGES:
        package = importlib.import_module(name)
        if not hasattr(package, "__path__"):
            continue
        modules = {m.name for m in pkgutil.iter_modules(package.__path__)}
        shadowed = [n for n in getattr(package, "__all__", []) if n in modules and not n[0].isupper()
                    and name != "warp_stokes"]
        # a function whose module has its name is kept only where the package imports it eagerly (binding.inbetween)
        for n in shadowed:
            importlib.import_module(f"{name}.{n}")
            assert callable(getattr(package, n)) and not isinstance(getattr(package, n), type(sys)), (name, n)


def test_every_public_name_is_what_it_names_after_every_module_is_imported():
    """In a fresh process: import every module of the package first, then look the public names up."""
    script = ("import importlib, os, pkgutil, sys, types\nimport warp_stokes as ws\n"
              "for m in pkgutil.walk_packages([os.path.dirname(ws.__file__)], 'warp_stokes.'):\n"
              "    if '.kernels' not in m.name and not m.name.endswith('__main__'):\n"
              "        try:\n            importlib.import_module(m.name)\n"
              "        except ImportError:\n            pass  # an optional extra (ray, matplotlib)\n"
              "bad = [n for n in ws.__all__ if isinstance(getattr(ws, n), types.ModuleType)]\n"
              "print('modules named as public objects:', bad)\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert "modules named as public objects: []" in proc.stdout, proc.stdout + proc.stderr
