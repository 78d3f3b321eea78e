import doctest
import importlib
import inspect
import pkgutil

import pytest

import athermal


def test_every_public_name_is_documented():
    missing = [n for n in athermal.__all__ if not inspect.getdoc(getattr(athermal, n))]
    assert missing == []


MODULES = sorted(
    m.name
    for m in pkgutil.walk_packages(athermal.__path__, "athermal.")
    if "__main__" not in m.name
)


@pytest.mark.parametrize("name", MODULES)
def test_the_examples_in_the_docstrings_run(name):
    failed, _ = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert failed == 0
