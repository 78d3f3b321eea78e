"""The GSD files athermal writes, opened by OVITO and freud (where those packages install:
``pip install -e ".[interop]"``): the box (tilt included), radii and positions they see are
athermal's, to float32 precision."""

import gsd.hoomd
import numpy as np
import pytest

from athermal.io import write_gsd
from athermal.model.cell import simple_shear
from athermal.model.contact import ContactModel, find_contacts
from athermal.model.packing import random_packing

F32 = 2e-6  # relative precision of HOOMD's float32 chunks


@pytest.fixture(params=[2, 3])
def written(request, tmp_path):
    dim = request.param
    packing = random_packing(200, 0.85 if dim == 2 else 0.62, dim=dim, seed=4)
    packing = packing.deform(simple_shear(0.3, dim))  # a tilted box
    path = tmp_path / f"p{dim}.gsd"
    write_gsd(path, packing, model=ContactModel(2.0), seed=4)
    return path, packing


@pytest.mark.filterwarnings("error")
def test_ovito_reads_box_radii_and_positions(written):
    io = pytest.importorskip("ovito.io")
    path, packing = written
    data = io.import_file(str(path)).compute()
    d = packing.dim
    cell = np.asarray(data.cell[...])  # (3, 4): cell vectors as columns, then the origin
    np.testing.assert_allclose(cell[:d, :d], packing.cell.h, rtol=F32, atol=F32)
    radii = np.asarray(data.particles["Radius"])
    np.testing.assert_allclose(radii, packing.radii, rtol=F32)
    seen = np.asarray(data.particles.positions)[:, :d]
    wrapped = packing.wrapped().positions
    np.testing.assert_allclose(seen, wrapped, atol=F32 * float(np.abs(cell).max()))


def freud_box(freud, frame):
    """The recipe of docs/howto/files.md: a 2D box from Lx, Ly and xy only (the file's Lz = 1
    is HOOMD's 2D convention, which freud's ``from_box`` warns about)."""
    Lx, Ly, Lz, xy, xz, yz = frame.configuration.box
    if frame.configuration.dimensions == 2:
        return freud.box.Box(Lx=Lx, Ly=Ly, xy=xy, is2D=True)
    return freud.box.Box(Lx=Lx, Ly=Ly, Lz=Lz, xy=xy, xz=xz, yz=yz)


@pytest.mark.filterwarnings("error")  # opening the file warns of nothing
def test_freud_sees_the_same_contacts(written):
    freud = pytest.importorskip("freud")
    path, packing = written
    with gsd.hoomd.open(str(path)) as traj:
        frame = traj[0]
    d = packing.dim
    box = freud_box(freud, frame)
    np.testing.assert_allclose(box.to_matrix()[:d, :d], packing.cell.h, rtol=F32, atol=F32)
    points = np.asarray(frame.particles.position, dtype=np.float32)
    radii = np.asarray(frame.particles.diameter, dtype=np.float64) / 2.0
    np.testing.assert_allclose(radii, packing.radii, rtol=F32)
    query = freud.locality.AABBQuery(box, points)
    pairs = query.query(points, {"r_max": 2.0 * radii.max(), "exclude_ii": True}).toNeighborList()
    i, j, dist = pairs.query_point_indices, pairs.point_indices, pairs.distances
    overlap = radii[i] + radii[j] - dist
    contacts = find_contacts(packing, ContactModel(2.0))
    mine = {
        (min(a, b), max(a, b))
        for a, b, o in zip(contacts.i, contacts.j, contacts.overlap, strict=True)
        if o > 1e-4 * radii.mean()
    }
    theirs = {
        (min(a, b), max(a, b))
        for a, b, o in zip(i, j, overlap, strict=True)
        if o > 1e-4 * radii.mean()
    }
    assert mine == theirs and len(mine) > 100


@pytest.fixture(scope="module")
def jammed(tmp_path_factory):
    """A packing at its jamming point (N = 256, epsilon 1e-6: overlaps ~1e-7 of a radius,
    below float32's resolution of the positions), written with its contact model."""
    from athermal.protocols import jam

    model = ContactModel(2.0)
    result = jam(random_packing(256, 0.8, seed=3), model)
    path = tmp_path_factory.mktemp("jammed") / "jammed.gsd"
    write_gsd(path, result.packing, model=model)
    return path, result.packing, model


def test_the_bonds_are_the_contacts_at_the_jamming_point(jammed):
    """Any GSD reader gets athermal's float64 contact list as bonds, with each contact's overlap
    and force and the rattlers, where the float32 positions lose contacts."""
    from athermal.analysis.observables import rattlers

    path, packing, model = jammed
    with gsd.hoomd.open(str(path)) as traj:
        frame = traj[0]
    contacts = find_contacts(packing, model)
    assert frame.bonds.N == contacts.i.size > 200 and list(frame.bonds.types) == ["contact"]
    np.testing.assert_array_equal(frame.bonds.group, np.stack([contacts.i, contacts.j], axis=1))
    np.testing.assert_array_equal(frame.log["bonds/overlap"], contacts.overlap)
    np.testing.assert_array_equal(frame.log["bonds/force"], contacts.force_magnitude)
    expected = rattlers(contacts, packing.n, packing.dim)
    np.testing.assert_array_equal(frame.log["particles/rattler"], expected.astype(np.uint8))
    assert 0 < expected.sum() < packing.n // 5
    # why: the float32 positions of the same frame do not give the same contacts
    seen = packing.with_positions(
        np.asarray(frame.particles.position, dtype=np.float64)[:, : packing.dim]
    )
    assert find_contacts(seen, model).i.size != contacts.i.size


@pytest.mark.filterwarnings("error")
def test_ovito_reads_the_contact_network(jammed):
    io = pytest.importorskip("ovito.io")
    path, packing, model = jammed
    data = io.import_file(str(path)).compute()
    contacts = find_contacts(packing, model)
    assert data.particles.bonds.count == contacts.i.size
    topology = np.asarray(data.particles.bonds.topology)
    np.testing.assert_array_equal(topology, np.stack([contacts.i, contacts.j], axis=1))
    np.testing.assert_allclose(np.asarray(data.particles.bonds["force"]), contacts.force_magnitude)


def test_freud_loses_contacts_of_a_jammed_packing_even_from_float64_positions(tmp_path):
    """What docs/howto/files.md says: freud's distances are float32, so the bonds are the way."""
    freud = pytest.importorskip("freud")
    import athermal as at

    model = ContactModel(2.0)
    jammed = at.jam(at.random_packing(256, 0.8, seed=3), model).packing
    path = tmp_path / "j.gsd"
    write_gsd(path, jammed, model=model)
    with gsd.hoomd.open(str(path)) as traj:
        frame = traj[0]
    x = frame.log["athermal/position"]
    assert x.dtype == np.float64 and (x.min() < -0.5 or x.max() > 0.5)  # unwrapped
    box = freud_box(freud, frame)
    points = box.wrap(np.column_stack([x, np.zeros(len(x))]))
    radii = frame.particles.diameter / 2.0
    pairs = (
        freud.locality.AABBQuery(box, points)
        .query(points, {"r_max": 2.0 * radii.max(), "exclude_ii": True})
        .toNeighborList()
    )
    i, j, dist = pairs.query_point_indices, pairs.point_indices, pairs.distances
    assert dist.dtype == np.float32
    touching = int(((i < j) & (radii[i] + radii[j] - dist > 0)).sum())
    assert touching < 0.8 * frame.bonds.N  # 271 of 483 (the docs' figure)
