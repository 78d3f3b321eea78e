"""The tutorial (docs/tutorial.md) runs as pasted, in order, in one empty folder, and what it
prints is the physics it describes."""

import re
from pathlib import Path

import pytest

from pasted import blocks, check_printed, paste

TUTORIAL = Path(__file__).resolve().parent.parent / "docs" / "tutorial.md"


@pytest.mark.slow
def test_the_tutorial_runs_in_order_in_one_folder(tmp_path):
    out = {}
    for block in blocks(TUTORIAL):
        printed = paste(block, tmp_path)
        check_printed(block, printed)  # the lines the page quotes, exactly: every CPU's
        out.setdefault(block.section, []).append(printed)
    assert list(out) == [
        "1. Jam",
        "2. Compress",
        "3. Moduli",
        "4. Shear",
        "5. Modes",
        "6. An ensemble",
    ]
    jam, look = out["1. Jam"]
    assert "passed                    yes" in jam
    contacts, bonds = (int(v) for v in re.search(r"contacts (\d+)  bonds (\d+)", look).groups())
    assert contacts == bonds > 0
    for name in (
        "jammed.gsd",
        "jammed.png",
        "compressed.csv",
        "compression.png",
        "shear.png",
        "modes.npz",
        "phic256/summary.json",
    ):
        assert (tmp_path / name).exists(), name
    finite = out["3. Moduli"][0].splitlines()[-3]  # the last frame against finite strain
    assert finite.split()[6] == "0.164013" and finite.split()[11] == "0.164013"  # as quoted
    modes = out["5. Modes"][1]
    assert "zero modes 2  negative 0" in modes
    ensemble = out["6. An ensemble"][1]
    phi_c = float(re.search(r"phi_c (\S+)", ensemble).group(1))
    assert 0.82 < phi_c < 0.85 and "all checks passed: True" in ensemble
