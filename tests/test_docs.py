import inspect
import subprocess
import sys
from pathlib import Path

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
