"""The how-to pages' examples run as pasted (those that need no cluster, GPU or hours)."""

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

import athermal as at
from athermal.io import count_frames
from pasted import Block, blocks, paste

HOWTO = Path(__file__).resolve().parent.parent / "docs" / "howto"


def test_a_killed_compression_resumes(tmp_path):
    (block,) = blocks(HOWTO / "resume.md")
    out = paste(block, tmp_path)
    resumed = int(re.findall(r"^resumed_steps +(\d+)", out, re.M)[-1])  # jam's comes first
    assert 0 < resumed < 121  # killed after its first step, before its last
    assert count_frames(tmp_path / "compressed.gsd") == 121
    # the resumed run ends where an uninterrupted one does, bit for bit
    paste(Block("bash", "athermal compress jammed.gsd -o clean.gsd --per-decade 20", ""), tmp_path)
    for frame in (0, -1):
        resumed = at.read_gsd(tmp_path / "compressed.gsd", frame=frame).packing.positions
        clean = at.read_gsd(tmp_path / "clean.gsd", frame=frame).packing.positions
        np.testing.assert_array_equal(resumed, clean)


def test_the_force_network_is_drawn_from_the_bonds_alone(tmp_path):
    model = at.ContactModel(2.0)
    jammed = at.jam(at.random_packing(64, 0.8, seed=1), model)
    at.write_gsd(tmp_path / "jammed.gsd", jammed.packing, model=model)
    (block,) = [b for b in blocks(HOWTO / "files.md") if "network.png" in b.code]
    paste(block, tmp_path)
    assert (tmp_path / "network.png").stat().st_size > 0


@pytest.mark.skipif(importlib.util.find_spec("ovito") is None, reason="ovito not installed")
def test_ovito_renders_the_force_network_of_the_quick_start(tmp_path):
    import ctypes.util

    if ctypes.util.find_library("vulkan") is None:  # what docs/howto/files.md says it needs
        pytest.skip("no Vulkan loader (apt-get install libvulkan1 mesa-vulkan-drivers)")
    paste(Block("bash", "athermal jam -o jammed.gsd --quiet", ""), tmp_path)
    (block,) = [b for b in blocks(HOWTO / "files.md") if "ovito" in b.code]
    out = paste(block, tmp_path)
    page = (HOWTO / "files.md").read_text()
    assert f"It prints `{out.strip()}`" in page  # the numbers the page quotes
    assert (tmp_path / "network-ovito.png").stat().st_size > 50_000


@pytest.mark.skipif(importlib.util.find_spec("freud") is None, reason="freud not installed")
@pytest.mark.filterwarnings("error")  # freud warns of nothing
def test_the_freud_example_reads_a_file(tmp_path):
    packing = at.random_packing(64, 0.9, seed=1)
    at.write_gsd(tmp_path / "jammed.gsd", packing, model=at.ContactModel(2.0))
    (block,) = [b for b in blocks(HOWTO / "files.md") if "freud" in b.code]
    paste(block, tmp_path)


def test_a_jamming_point_is_certified_and_its_exponents_fitted(tmp_path):
    one, read, below, hard, linear, many = blocks(HOWTO / "certify.md")
    paste(one, tmp_path)
    balance = re.search(r"force balance (\S+) of", paste(read, tmp_path)).group(1)
    assert float(balance) <= 1e-20
    width = re.search(r"\(bracket (\S+)\)", paste(below, tmp_path)).group(1)
    assert float(width) <= 1e-12
    out = paste(hard, tmp_path)  # as hard spheres: isostatic, tiny overlaps, rattlers clear
    assert re.search(r"contacts \(0 beyond isostatic\)", out)
    low, high = (float(v) for v in re.search(r"\[(\S+), (\S+)\]", out).groups())
    assert 0.0 < high - low <= 1e-12
    overlaps = re.search(r"contacts overlap (\S+) to (\S+)", out).groups()
    assert 0.0 < float(overlaps[0]) <= float(overlaps[1]) < 1e-12
    gap, clear = re.search(r"smallest gap (\S+), rattlers' (\S+)", out).groups()
    assert float(gap) > 0.0 and float(clear) > 0.0
    out = paste(linear, tmp_path)
    low, high = (float(v) for v in re.search(r"\[(\S+), (\S+)\]", out).groups())
    phi_c = float(re.search(r"phi_c = (\S+) ", out).group(1))
    assert low < phi_c < high
    out = paste(many, tmp_path)
    assert "theta_e" in out and "gamma" in out and (tmp_path / "criticality.png").exists()


def test_packings_between_walls(tmp_path):
    commands, read = blocks(HOWTO / "walls.md")
    paste(commands, tmp_path)
    out = paste(read, tmp_path)
    assert "walls y" in out and "sigma_yy = 0.001000000" in out
    assert "plane shear: tau" in out and "at strain 0.02" in out


def test_the_engine_page_registers_an_engine_that_jams(tmp_path):
    (block,) = blocks(HOWTO / "engine.md")
    assert paste(block, tmp_path).strip() == block.printed.strip()


def test_the_law_page_relaxes_a_law_of_its_own(tmp_path):
    (block,) = blocks(HOWTO / "law.md")
    assert paste(block, tmp_path).strip() == block.printed.strip()


def test_the_plasticity_page_locates_events_and_a_limit_cycle(tmp_path):
    """The page's commands and script as pasted: events located and written, the script's
    claims printed, and the cyclic run reaching the limit cycle it describes."""
    shear, script, cyclic, ensemble, summary, cycles = blocks(HOWTO / "plasticity.md")
    paste(shear, tmp_path)
    for name in ("events.gsd", "events.csv", "events.events.csv", "events.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert paste(script, tmp_path).strip() == "True True True"
    paste(cyclic, tmp_path)
    table = (tmp_path / "cycles.cycles.csv").read_text().splitlines()
    assert table[0].startswith("cycle,") and len(table) >= 2
    paste(ensemble, tmp_path)
    assert (tmp_path / "avalanches" / "avalanches.png").exists()
    assert paste(summary, tmp_path).strip() == "2 True True"
    paste(cycles, tmp_path)
    yielding = json.loads((tmp_path / "yielding" / "summary.json").read_text())["yielding"]
    assert [a["amplitude"] for a in yielding["amplitudes"]] == [0.002, 0.05]
