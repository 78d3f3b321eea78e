"""Flat frictionless walls: the kernels against finite differences and an analytic case, the
pair list against brute force, mechanical equilibrium, isostaticity, the protocols and the
command line."""

import json
import warnings

import numpy as np
import pytest

from athermal.analysis.moduli import linear_response, relaxed_strain_curvature, stability
from athermal.analysis.observables import isostatic_contacts, measure, stress
from athermal.cli import main
from athermal.enthalpy import relax_at_pressure
from athermal.errors import InputError
from athermal.io import read_gsd, write_gsd
from athermal.model.cell import Cell, pure_shear, simple_shear, wall_axes
from athermal.model.contact import ContactModel, find_contacts, gradient, hessian, total_energy
from athermal.model.neighbors import brute_force_pairs, build_neighbor_list
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing
from athermal.model.walls import wall_pressures
from athermal.protocols.jamming import jam
from athermal.protocols.shear import shear_steps
from athermal.relaxation import Minimizer, relax
from conftest import network, network_strain

WALLED = [(2, (1,)), (2, (0, 1)), (3, (2,)), (3, (0, 2))]


def walled(dim, walls, n=40, phi=0.9, seed=3, lengths=None):
    cell = Cell(np.diag(lengths or np.ones(dim)), walls)
    return random_packing(n, phi if dim == 2 else 0.7, cell=cell, seed=seed)


def settled(packing, model, gtol=1e-14):
    """``packing`` relaxed by Newton-CG to ``gtol``."""
    result = relax(packing, model, Minimizer("newton"), gtol=gtol)
    assert result.converged
    return result.packing


@pytest.mark.parametrize("dim, walls", WALLED)
@pytest.mark.parametrize("alpha", [2.0, 2.5])
def test_compiled_energy_gradient_hessian_match_the_reference_and_finite_differences(
    dim, walls, alpha
):
    p = walled(dim, walls)
    model = ContactModel(alpha, wall_stiffness=1.7)
    contacts = find_contacts(p, model)
    assert contacts.walls is not None and contacts.walls.particle.size >= 4
    obj = Objective(p, model, sort=False)
    x = obj.x0.copy()
    e, g = obj(x)
    assert e == pytest.approx(total_energy(contacts), rel=1e-12)
    np.testing.assert_allclose(g.reshape(p.n, dim), gradient(contacts, p.n), atol=1e-13)
    # the wall terms alone: particles that touch no other particle near a wall
    v = np.random.default_rng(0).normal(size=x.size)
    h_op = obj.hessian(x)
    np.testing.assert_allclose(h_op.dot(v), h_op.matrix() @ v, atol=1e-12)
    np.testing.assert_allclose(
        h_op.matrix().toarray(), hessian(contacts, p.n).toarray(), atol=1e-12
    )
    errors = []
    for step in (1e-6, 5e-7):
        fd = (obj(x + step * v)[0] - obj(x - step * v)[0]) / (2 * step)
        fd_h = (obj(x + step * v)[1] - obj(x - step * v)[1]) / (2 * step)
        errors.append((abs(fd - g @ v), np.abs(fd_h - h_op.dot(v)).max()))
    assert errors[-1][0] <= 1e-6 * abs(g @ v)
    assert errors[-1][1] <= 1e-5 * np.abs(h_op.dot(v)).max()


def test_one_disk_against_a_wall_analytic():
    """A disk of radius r overlapping the lower wall by delta: energy k_w delta^2 / 2, force
    k_w delta up, a force per unit length k_w delta / L_x on that wall, sigma_yy from the branch
    (r - delta) e_y."""
    r, lx, ly, kw, delta = 0.2, 2.0, 0.5, 3.0, 0.01
    p = Packing([[0.1, -ly / 2 + r - delta]], [r], Cell(np.diag([lx, ly]), (1,)))
    model = ContactModel(2.0, wall_stiffness=kw)
    obs = measure(p, model)
    assert obs.energy == pytest.approx(kw * delta**2 / 2)
    assert obs.wall_pressure == pytest.approx({"y-": kw * delta / lx, "y+": 0.0})
    np.testing.assert_allclose(gradient(find_contacts(p, model), 1), [[0.0, -kw * delta]])
    assert obs.stress[1, 1] == pytest.approx((r - delta) * kw * delta / (lx * ly))
    assert obs.contacts == 1 and obs.walls == "y"
    with pytest.raises(InputError, match="leaves no room"):
        Packing([[0.0, 0.0]], [0.3], Cell(np.diag([lx, ly]), (1,)))


@pytest.mark.parametrize("dim, walls", WALLED)
def test_no_pair_across_a_wall_and_the_list_matches_brute_force(dim, walls):
    p = walled(dim, walls, n=60, phi=0.6)
    skin = 0.3 * float(p.radii.mean())
    nl = build_neighbor_list(p.positions, p.radii, p.cell, skin)
    got = {
        (int(i), int(j), tuple(int(v) for v in nl.images[c]))
        for i, j, c in zip(nl.first, nl.second, nl.code, strict=True)
    }
    assert got == brute_force_pairs(p.positions, p.radii, p.cell, skin)
    assert all(image[a] == 0 for _, _, image in got for a in walls)
    # two disks at the two walls, a periodic image apart: no contact through the wall
    cell = Cell(np.eye(2), (1,))
    pair = Packing([[0.0, -0.49], [0.0, 0.49]], [0.1, 0.1], cell)
    assert find_contacts(pair, ContactModel()).i.size == 0


def test_cell_walls_are_validated_and_kept():
    assert wall_axes("xy", 2) == (0, 1) and wall_axes("", 3) == ()
    for bad in ("q", "yy", "z"):
        with pytest.raises(InputError, match="walls"):
            wall_axes(bad, 2)
    with pytest.raises(InputError, match="untilted"):
        Cell(simple_shear(0.1) @ np.eye(2), (1,))
    with pytest.raises(InputError, match="untilted"):
        Cell(np.eye(2), (0,)).deform(simple_shear(0.1))
    cell = Cell(np.eye(2), (1,))
    assert cell.deform(pure_shear(0.1)).walls == (1,) and cell.periodic_axes == 1
    x = np.array([[0.7, 0.45], [-0.2, -0.45]])
    np.testing.assert_allclose(cell.wrap(x), [[-0.3, 0.45], [-0.2, -0.45]])
    np.testing.assert_allclose(cell.minimum_image(x[:1] - x[1:]), [[-0.1, 0.9]])
    with pytest.raises(InputError, match="beyond the walls"):
        Packing([[0.0, 0.6]], [0.1], cell)


@pytest.mark.parametrize("method", ["lbfgs", "fire", "newton", "cg"])
def test_wall_pressure_equals_the_virial_stress_at_equilibrium(method):
    p = walled(2, (1,), n=128, phi=0.88, seed=2)
    model = ContactModel()
    result = relax(p, model, Minimizer(method), gtol=1e-14)
    assert result.converged
    q = result.packing
    contacts = find_contacts(q, model)
    sigma = stress(contacts, q.cell)
    walls = wall_pressures(contacts.walls, q.cell)
    for value in walls.values():
        assert value == pytest.approx(sigma[1, 1], rel=1e-8)
    assert abs(sigma[0, 1]) <= 1e-10 * sigma[1, 1]


def test_isostatic_count_with_walls():
    # d N' - t + 1 with t the periodic axes
    assert isostatic_contacts(100, 2) == 199
    assert isostatic_contacts(100, 2, periodic=1) == 200
    assert isostatic_contacts(100, 2, periodic=0) == 201
    assert isostatic_contacts(100, 3, periodic=2) == 299


@pytest.mark.parametrize("walls", [(1,), (0, 1)])
def test_jamming_between_walls_is_isostatic_counting_wall_contacts(walls):
    model = ContactModel()
    excess = []
    for seed in (1, 2, 3):
        start = walled(2, walls, n=128, phi=0.75, seed=seed)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # jam warns when a check fails
            result = jam(start, model)
        assert result.check.passed and result.check.unjams
        excess.append(result.check.excess_contacts)
        obs = result.observables
        assert obs.wall_pressure and all(v > 0 for v in obs.wall_pressure.values())
        # a wall contact counts once: z = (2 C_p + C_w) / N'
        contacts = find_contacts(result.packing, model)
        assert obs.contacts == contacts.i.size + contacts.walls.particle.size
        # the walls lower phi_c below the periodic value (~0.84): the boundary layer
        assert 0.75 < result.phi_c < 0.835
    assert min(excess) == 0  # exactly d N' - t + 1 counts the wall contacts right


def test_wall_at_a_fixed_force_per_unit_area():
    model = ContactModel()
    p = walled(2, (1,), n=128, phi=0.8, seed=1)
    result = relax_at_pressure(p, model, 1e-3, cell="walls", precon="exp")
    assert result.result.converged
    q = result.packing
    assert q.cell.walls == (1,) and q.cell.h[0, 0] == 1.0  # the periodic length kept
    assert result.stress[1, 1] == pytest.approx(1e-3, rel=1e-7)
    walls = wall_pressures(find_contacts(q, model).walls, q.cell)
    assert walls == pytest.approx({"y-": 1e-3, "y+": 1e-3}, rel=1e-7)
    with pytest.raises(InputError, match="tilt"):
        relax_at_pressure(p, model, 1e-3, cell="shape")
    with pytest.raises(InputError, match="has none"):
        relax_at_pressure(random_packing(16, 0.8), model, 1e-3, cell="walls")


@pytest.fixture(scope="module")
def compressed_between_walls():
    model = ContactModel()
    start = walled(2, (1,), n=128, phi=0.75, seed=4)
    result = jam(start, model)
    return settled(result.packing.at_phi(result.phi_c + 1e-2), model, 1e-15), model


def test_moduli_between_walls_match_finite_strain(compressed_between_walls):
    """The relaxed curvature against the central difference of the relaxed energy's slope
    ``dE/dg = -V tr(d1 (I + g d1)^-1 sigma)`` at ``g = +-h``, with ``h`` a quarter of
    :func:`network_strain`: a weak contact can part within a fixed step, and the energy then
    follows another network (asserted not to happen)."""
    p, model = compressed_between_walls
    assert stability(p, model).stable
    for d1 in (np.diag([0.0, 1.0]), np.eye(2)):
        _, relaxed = relaxed_strain_curvature(p, model, d1)
        h = min(1e-5, 0.25 * network_strain(p, model, d1))
        slopes = []
        for g in (-h, h):
            q = settled(p.deform(np.eye(2) + g * d1), model, 1e-15)
            m = d1 @ np.linalg.inv(np.eye(2) + g * d1)
            slopes.append(-q.cell.volume * np.trace(m @ stress(find_contacts(q, model), q.cell)))
            assert network(q, model) == network(p, model)
        assert relaxed == pytest.approx((slopes[1] - slopes[0]) / (2 * h), rel=1e-3)
    # the biaxial test's G: (1/2) d tau / d gamma under pure shear, walls moving
    taus = []
    for g in (-1e-6, 1e-6):
        q = settled(p.deform(pure_shear(g)), model, 1e-15)
        sigma = stress(find_contacts(q, model), q.cell)
        taus.append(0.5 * (sigma[1, 1] - sigma[0, 0]))
    g_fd = 0.5 * (taus[1] - taus[0]) / 2e-6
    assert linear_response(p, model).shear == pytest.approx(g_fd, rel=1e-4)


@pytest.mark.parametrize("alpha", [2.0, 2.5])
def test_wall_pressure_against_wall_strain_near_jamming(alpha):
    """Uniaxial compression of jammed packings by their walls: sigma_yy ~ strain^(alpha - 1),
    as p ~ Delta phi^(alpha - 1) in a periodic cell, along each packing's elastic branch (the
    slope averaged over three packings). Jammed, a packing is isostatic: the first contact the
    compression parts leaves it floppy, and it rearranges, often to zero stress. The branch
    ends before the first step whose stress falls; the steps are refined until it holds three."""
    model = ContactModel(alpha)
    slopes = []
    for seed in (5, 6, 7):
        start = jam(walled(2, (1,), n=128, phi=0.75, seed=seed), model).packing
        step, branch = 1e-4, []
        while len(branch) < 4:
            branch = []
            compress = shear_steps(
                start, model, mode="uniaxial", strain=10 * step, step=step, rtol=1e-10
            )
            for s in compress:
                if s.plastic:
                    break
                branch.append(s)
            step /= 4
        strain = np.array([s.strain for s in branch[1:]])
        tau = np.array([s.tau for s in branch[1:]])
        walls = np.array([s.observables.wall_pressure["y+"] for s in branch[1:]])
        np.testing.assert_allclose(walls, tau, rtol=1e-6)
        slopes.append(np.polyfit(np.log(strain), np.log(tau), 1)[0])
    assert np.mean(slopes) == pytest.approx(alpha - 1.0, abs=0.05)


def test_simple_shear_between_walls_is_refused():
    p = walled(2, (1,), n=16, phi=0.8)
    with pytest.raises(InputError, match="simple shear"):
        next(shear_steps(p, ContactModel(), mode="simple"))


def test_gsd_keeps_the_walls_and_the_wall_stiffness(tmp_path):
    p = walled(2, (1,), n=32, phi=0.8)
    model = ContactModel(2.5, wall_stiffness=3.0)
    write_gsd(tmp_path / "w.gsd", p, model=model)
    frame = read_gsd(tmp_path / "w.gsd")
    assert frame.packing.cell.walls == (1,) and frame.model.wall_stiffness == 3.0
    np.testing.assert_array_equal(frame.packing.positions, p.positions)


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_command_line_walls(tmp_path, capsys):
    out = tmp_path / "w.gsd"
    code, text, _ = run(capsys, "random", "--n", "64", "--walls", "y", "-o", str(out), "--json")
    assert code == 0
    made = json.loads(text)
    assert made["walls"] == "y" and set(made["wall_pressure"]) == {"y-", "y+"}
    code, text, _ = run(capsys, "measure", str(out), "--json")
    assert code == 0 and json.loads(text)["walls"] == "y"
    # bad input: one line, exit 2, nothing written
    bad = str(tmp_path / "bad.gsd")
    for argv in (
        ("random", "--walls", "q", "-o", bad),
        ("shear", str(out), "--mode", "simple", "-o", bad),
        ("relax", str(out), "--pressure", "1e-3", "--cell", "shape", "-o", bad),
        ("jam", "--walls", "y", "--certify", "-o", bad),
        ("certify", str(out), "-o", bad),
    ):
        code, _, err = run(capsys, *argv)
        assert code == 2 and len(err.strip().splitlines()) == 1, (argv, err)
        assert not (tmp_path / "bad.gsd").exists()


def test_the_jax_engine_refuses_walls(tmp_path, capsys):
    pytest.importorskip("jax")
    out = tmp_path / "w.gsd"
    write_gsd(out, walled(2, (1,), n=32, phi=0.8), model=ContactModel())
    bad = str(tmp_path / "bad.gsd")
    for argv in (
        ("jam", "--walls", "y", "--backend", "jax", "-o", bad),
        ("relax", str(out), "--backend", "jax", "-o", bad),
        ("compress", str(out), "--backend", "jax", "-o", bad),
    ):
        code, _, err = run(capsys, *argv)
        assert code == 2 and "no walls" in err and len(err.strip().splitlines()) == 1, argv
        assert not (tmp_path / "bad.gsd").exists()


def test_the_wall_stiffness_travels_through_the_command_line(tmp_path, capsys):
    p = walled(2, (1,), n=64, phi=0.85)
    model = ContactModel(2.0, wall_stiffness=5.0)
    write_gsd(tmp_path / "w.gsd", p, model=model)
    code, text, _ = run(capsys, "measure", str(tmp_path / "w.gsd"), "--json")
    assert code == 0
    assert json.loads(text)["energy"] == pytest.approx(measure(p, model).energy, rel=1e-12)
    assert measure(p, model).energy != pytest.approx(measure(p, ContactModel(2.0)).energy)


def test_what_walls_cannot_take_is_refused():
    from athermal.certify.criticality import weak_forces_and_gaps
    from athermal.studies.ensemble import EnsembleSpec
    from athermal.studies.experiments import JamSpec, ShearSpec

    p = walled(2, (1,), n=32, phi=0.85)
    model = ContactModel()
    with pytest.raises(InputError, match="simple shear"):
        EnsembleSpec("shear", jam=JamSpec(n=64, walls="y"), shear=ShearSpec(mode="simple"))
    with pytest.raises(InputError, match="iteration"):
        EnsembleSpec("iterations", jam=JamSpec(n=64, walls="y"))
    with pytest.raises(InputError, match="walls"):
        weak_forces_and_gaps(p, model)
    with pytest.raises(InputError, match="tilt"):
        relaxed_strain_curvature(p, model, simple_shear(1.0) - np.eye(2))
    with pytest.raises(InputError, match="tuple of axes"):
        Cell(np.eye(2), "y")  # type: ignore[arg-type]


def test_moduli_finite_strain_is_refused_between_walls(tmp_path, capsys):
    write_gsd(tmp_path / "w.gsd", walled(2, (1,), n=32, phi=0.85), model=ContactModel())
    code, _, err = run(capsys, "moduli", str(tmp_path / "w.gsd"), "--finite-strain", "1e-5")
    assert code == 2 and "--finite-strain" in err and len(err.strip().splitlines()) == 1


def test_fire_time_step_bound_counts_stiff_walls():
    p = walled(2, (1,), n=40, phi=0.9)
    model = ContactModel(2.0, wall_stiffness=1000.0)
    obj = Objective(p, model, sort=False)
    largest = np.linalg.eigvalsh(obj.hessian(obj.x0).matrix().toarray())[-1]
    assert largest > 500.0  # the walls dominate
    assert obj.curvature_bound(obj.x0) >= largest


def test_files_carry_the_walls_force_on_each_particle(tmp_path):
    import gsd.hoomd

    p = walled(2, (1,), n=64, phi=0.85)
    model = ContactModel()
    write_gsd(tmp_path / "w.gsd", p, model=model)
    with gsd.hoomd.open(str(tmp_path / "w.gsd")) as traj:
        stored = traj.file.read_chunk(frame=0, name="log/particles/wall_force")
    walls = find_contacts(p, model).walls
    expected = np.zeros(p.n)
    np.add.at(expected, walls.particle, walls.force_magnitude)
    np.testing.assert_array_equal(stored, expected)
    assert (stored > 0).sum() == np.unique(walls.particle).size > 0


def test_jamming_between_walls_in_3d():
    """Spheres between walls normal to z: isostatic with t = 2 periodic axes, each wall's force
    per unit area equal to sigma_zz."""
    model = ContactModel()
    start = random_packing(128, 0.5, cell=Cell(np.eye(3), (2,)), seed=1)
    result = jam(start, model)
    assert result.check.passed and 0 <= result.check.excess_contacts
    assert 0.55 < result.phi_c < 0.64  # below the periodic ~0.64: the boundary layer
    obs = result.observables
    assert set(obs.wall_pressure) == {"z-", "z+"}
    for value in obs.wall_pressure.values():
        assert value == pytest.approx(obs.stress[2, 2], rel=1e-5)
