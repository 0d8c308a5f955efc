"""The driver's worker threads (runtime.workers)."""
import threading

import pytest

from mcdenoise.runtime import workers


def test_run_all_keeps_the_order_and_uses_the_pool():
    names = workers.run_all(lambda i: (i, threading.current_thread().name), [(i,) for i in range(6)], 2)
    assert [i for i, _ in names] == list(range(6))
    assert all(n.startswith("mcdenoise") for _, n in names)
    # One thread, or one job: in the calling thread.
    assert workers.run_all(lambda: threading.current_thread().name, [()], 2) == [threading.current_thread().name]
    assert workers.run_all(lambda i: i * 2, [(1,), (2,)], 1) == [2, 4]


def test_run_all_raises_after_every_job_has_finished():
    done = []

    def job(i):
        if i == 0:
            raise ValueError("first")
        done.append(i)

    with pytest.raises(ValueError, match="first"):
        workers.run_all(job, [(i,) for i in range(5)], 2)
    assert sorted(done) == [1, 2, 3, 4]


def test_default_threads_is_at_most_two():
    assert 1 <= workers.default_threads() <= workers.MAX_DEFAULT_THREADS == 2
