import os

import numpy as np
import pytest

from athermal.errors import InputError
from athermal.model.contact import ContactModel, packing_energy
from athermal.model.neighbors import build_neighbor_list
from athermal.model.objective import Objective
from athermal.model.packing import random_packing


def test_evaluations_are_cached_counted_and_match_the_packing_energy():
    packing = random_packing(200, 0.9, seed=5)
    obj = Objective(packing, ContactModel(2.5))
    energy, _ = obj(obj.x0)
    obj(obj.x0.copy())
    assert obj.n_evaluations == 1
    assert energy == pytest.approx(packing_energy(packing, ContactModel(2.5)), rel=1e-12)
    np.testing.assert_array_equal(obj.packing(obj.x0).positions, packing.positions)


def test_start_from_moves_the_start_and_checks_the_shape():
    obj = Objective(random_packing(16, 0.5, seed=1), ContactModel())
    x = obj.x0 + 1e-3
    obj.start_from(x)
    np.testing.assert_array_equal(obj.x0, x)
    with pytest.raises(InputError, match="x:"):
        obj.start_from(x[:-1])


def test_contact_count_of_the_last_evaluation_matches_a_separate_pass():
    packing = random_packing(200, 0.86, seed=9)
    evaluated = Objective(packing, ContactModel(2.0))
    evaluated(evaluated.x0)  # counts from the energy pass
    fresh = Objective(packing, ContactModel(2.0))  # nothing evaluated: the compiled count
    brute = 0
    for i in range(packing.n):
        sep = packing.cell.minimum_image(packing.positions[i + 1 :] - packing.positions[i])
        reach = packing.radii[i + 1 :] + packing.radii[i]
        brute += int(np.sum(np.einsum("ij,ij->i", sep, sep) < reach**2))
    assert evaluated.count_contacts(evaluated.x0) == fresh.count_contacts(fresh.x0) == brute


def test_the_objective_takes_the_threads_kernel_for_large_lists(monkeypatch):
    """Above ``PARALLEL_PAIRS`` the objective evaluates on the threads (the same energy to
    round-off), in Python and in the compiled searches, and a relaxation converges."""
    import numba

    import athermal.model.loops as loops
    from athermal.relaxation import Minimizer, relax

    if min(numba.get_num_threads(), len(os.sched_getaffinity(0))) < 2:
        pytest.skip("one thread or core")
    p = random_packing(4096, 0.86, seed=3)
    model = ContactModel(2.0)
    serial = Objective(p, model)
    e_serial, g_serial = serial(serial.x0)
    monkeypatch.setattr(loops, "PARALLEL_PAIRS", 0)
    threaded = Objective(p, model)
    e, g = threaded(threaded.x0)
    assert threaded._slabs[0].size > 4 and threaded._slabs[1]
    assert e == pytest.approx(e_serial, rel=1e-13)
    np.testing.assert_allclose(g, g_serial, atol=1e-14 * np.abs(g_serial).max())
    result = relax(p, model, Minimizer("lbfgs", "exp"), gtol=1e-12)
    assert result.converged


def test_a_large_list_sums_in_its_slabs_order_on_any_number_of_threads(monkeypatch):
    """From ``PARALLEL_PAIRS`` on, the energy and gradient are summed slab by slab whether the
    threads run or not (a worker thread, one core): the same bits."""
    import athermal.model.contact as contact
    import athermal.model.loops as loops

    p = random_packing(2048, 0.86, seed=5)
    model = ContactModel(2.5)
    monkeypatch.setattr(loops, "PARALLEL_PAIRS", 0)
    nlist = build_neighbor_list(p.positions, p.radii, p.cell)
    slabs, _ = loops.parallel_slabs(nlist)
    assert slabs.size > 4
    results = []
    for threads in (True, False):
        grad = np.zeros_like(p.positions)
        energy = contact.energy_gradient_contacts(
            p.positions, p.radii, model.typeid(p), nlist.shifts(p.cell), nlist, model, grad,
            slabs=(slabs, threads),
        )  # fmt: skip
        results.append((energy, grad))
    assert results[0][0] == results[1][0]
    np.testing.assert_array_equal(results[0][1], results[1][1])
