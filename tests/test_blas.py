"""numpy's BLAS on one thread in the hot loops (:mod:`stewart_gym.blas`): inside the ``with`` and the decorated
functions BLAS runs on one thread, and after them on as many as before; the batched simulator's steps and
``sysid``'s fit run inside it."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from stewart_gym.blas import OneBlasThread, one_blas_thread
from stewart_gym.sim.batched import BatchedSim


def blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


@pytest.fixture
def two_blas_threads():
    """BLAS on two threads for the test (whatever the machine's cores), as OpenBLAS starts on a 2-core machine.
    Where numpy's BLAS has no threads to limit (one threadpoolctl cannot see, such as Apple's Accelerate, or a
    single-threaded build) there is nothing to hold to one thread, and the tests that need it do not apply."""
    with threadpool_limits(limits=2, user_api="blas"):
        if 2 not in blas_threads():
            pytest.skip("numpy's BLAS here has no threads that threadpoolctl can set")
        yield


def test_one_thread_inside_and_as_many_as_before_after(two_blas_threads) -> None:
    before = blas_threads()
    with OneBlasThread():
        assert blas_threads() == [1] * len(before)
        with OneBlasThread():  # nested: still one
            assert blas_threads() == [1] * len(before)
        assert blas_threads() == [1] * len(before)
    assert blas_threads() == before

    @one_blas_thread
    def inside(x: int) -> tuple[list[int], int]:
        return blas_threads(), x + 1

    assert inside(1) == ([1] * len(before), 2) and inside.__name__ == "inside"
    assert blas_threads() == before


def test_a_failure_inside_still_gives_the_threads_back(two_blas_threads) -> None:
    before = blas_threads()
    with pytest.raises(ZeroDivisionError), OneBlasThread():
        1 / 0  # noqa: B018
    assert blas_threads() == before


def test_the_batched_steps_run_on_one_blas_thread(two_blas_threads, monkeypatch) -> None:
    """What each matrix product of the plate's anchors (``BatchedSim._arms``) saw in a step of the NumPy kernel (the
    compiled one makes no BLAS calls)."""
    seen: list[list[int]] = []
    arms = BatchedSim._arms

    def watched(self, rot):
        seen.append(blas_threads())
        return arms(self, rot)

    monkeypatch.setattr(BatchedSim, "_arms", watched)
    sim = BatchedSim(n=64, kernel="numpy")
    seen.clear()  # the reset's product runs once, outside any loop
    before = blas_threads()
    assert 2 in before
    sim.command(np.broadcast_to(sim.calibration.neutral_us + 20.0, (64, 6)))
    sim.step()
    assert seen and all(threads == [1] * len(before) for threads in seen)
    assert blas_threads() == before


def test_the_fits_run_on_one_blas_thread() -> None:
    """``sysid``'s fit and the camera's trim fit are :func:`one_blas_thread`'s (the decorator is tested above)."""
    from stewart_gym.plate_trims import fit_trims
    from stewart_gym.sysid import fit_twin

    for fit in (fit_twin, fit_trims):
        assert fit.__code__.co_name == "on_one_thread" and fit.__wrapped__.__name__ == fit.__name__
