"""fe_core.threads: the main process's independent pieces on threads, results in order and the same as in one
thread (the reduced model's scan and the screen's diagonal derivatives, the two products that use it)."""

from __future__ import annotations

import time

import numpy as np
import pytest

import fe_core.threads as threads
from fe_core.threads import thread_map


def test_results_come_in_the_items_order_whatever_ends_first():
    def slow_first(k):
        time.sleep(0.05 if k == 0 else 0.0)
        return k * k
    assert thread_map(slow_first, range(5), threads=2) == [0, 1, 4, 9, 16]
    assert thread_map(slow_first, [], threads=2) == []


def test_an_exception_in_a_piece_is_raised_to_the_caller():
    def fail_at_three(k):
        if k == 3:
            raise ValueError("piece 3")
        return k
    with pytest.raises(ValueError, match="piece 3"):
        thread_map(fail_at_three, range(5), threads=2)


def test_one_thread_runs_in_the_callers_thread():
    import threading
    here = threading.get_ident()
    assert thread_map(lambda _: threading.get_ident(), range(3), threads=1) == [here] * 3


def test_the_diagonal_derivatives_and_the_reduced_scan_are_the_same_on_one_thread_and_on_two(benchmark_model,
                                                                                              monkeypatch):
    """Bit for bit: each piece is the same computation whichever thread runs it."""
    import fe_core.solvers.adjoint as adjoint
    from fe_core.closure.effects import PointMass
    from fe_core.closure.far import ReducedModel, lowrank_factors
    from fe_core.solvers.adjoint import ReducedResponse
    from fe_core.solvers.frf import hz_to_rad

    model = benchmark_model
    freqs = np.linspace(20.0, 400.0, 40)
    alpha = np.array([0.1, -0.2, 0.05, 0.0, 0.1, -0.1])[:model.n_segments]
    monkeypatch.setattr(adjoint, "DIAGONAL_CHUNK", 7)
    effect = PointMass(model)
    locations = effect.locations()[:60]
    rm = ReducedModel(model, freqs, alpha)
    matrix, U = lowrank_factors(rm, effect, locations)
    sizes = np.array([0.01, 0.1, 1.0])
    log_u = np.zeros((freqs.size, model.outputs.shape[1]))
    out = {}
    for n in (1, 2):
        monkeypatch.setattr(threads, "THREADS", n)
        red = ReducedResponse(*_matrices(model, alpha), model.combined_load(), model.outputs, hz_to_rad(freqs))
        out[n] = (red.diagonal_dlog(*effect.diagonal(locations)), rm.scan(alpha, U, matrix, sizes, log_u, chunk=8))
    assert np.array_equal(out[1][0], out[2][0]) and np.array_equal(out[1][1], out[2][1])


def _matrices(model, alpha):
    from fe_core.closure.effects.extended import extended_matrices
    return extended_matrices(model, alpha, [])


def test_cores_reads_a_runs_n_jobs():
    assert threads.cores(1) == 1
    assert threads.cores(3) == 3
    assert threads.cores(0) == 1 and threads.cores(None) == 1
    assert threads.cores(-1) == threads._cores() >= 1


def test_at_most_bounds_the_pool_within_its_block_and_restores_it(monkeypatch):
    import threading
    monkeypatch.setattr(threads, "THREADS", 2)
    here = threading.get_ident()
    with threads.at_most(1):
        assert threads.THREADS == 1
        assert thread_map(lambda _: threading.get_ident(), range(3)) == [here] * 3
    assert threads.THREADS == 2
    with pytest.raises(RuntimeError), threads.at_most(1):
        raise RuntimeError("restored on an exception too")
    assert threads.THREADS == 2
    with threads.at_most(8):  # never more than the pool had
        assert threads.THREADS == 2
