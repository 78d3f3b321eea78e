import doctest
import importlib
import inspect
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import athermal

ROOT = Path(__file__).resolve().parent.parent


def test_every_public_name_is_documented():
    missing = [n for n in athermal.__all__ if not inspect.getdoc(getattr(athermal, n))]
    assert missing == []


def test_api_page_is_current():
    done = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "make_api.py"), "--check"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr


MODULES = sorted(
    m.name
    for m in pkgutil.walk_packages(athermal.__path__, "athermal.")
    if "__main__" not in m.name
)


@pytest.mark.parametrize("name", MODULES)
def test_the_examples_in_the_docstrings_run(name):
    failed, _ = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert failed == 0
