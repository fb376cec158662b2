"""The examples in the package's docstrings run (numpy-style ``Examples`` sections; ``+SKIP`` marks those that
need data or a bind)."""

import doctest
import importlib
import os
import pkgutil
import warnings

import pytest

import warp_stokes

# the package's own folder (its __path__ also holds the checkout's root, for the kernels of a source tree)
MODULES = sorted(name for _, name, _ in pkgutil.walk_packages([os.path.dirname(warp_stokes.__file__)], "warp_stokes.")
                 if not name.startswith("warp_stokes.kernels") and not name.endswith(".__main__"))


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} docstring examples failed in {name}"
