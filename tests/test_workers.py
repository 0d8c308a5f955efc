"""The driver's workers: shared memory and the helper process that takes half of the rows."""
import os

import numpy as np
import pytest

from mcdenoise.runtime import workers
from mcdenoise.runtime.temporal import BAND_ROWS, reproject

pytestmark = pytest.mark.skipif(not workers.SHARED_SUPPORTED, reason="shared memory needs Linux memfd")


def _stamp(out, rows, value):
    """A job for run_split: write ``value`` and this process's id into ``rows`` of ``out``."""
    out[rows, 0] = value
    out[rows, 1] = os.getpid()
    return value * 2


def _fail(out, rows, value):
    if os.getpid() != value:
        raise ValueError("only in the helper")
    return _stamp(out, rows, 0)


@pytest.fixture
def fresh_helper(monkeypatch):
    """A helper process of this test's own, and the module's failure note restored after;
    the reprojection hands small frames to it too."""
    import mcdenoise.runtime.temporal

    monkeypatch.setattr(mcdenoise.runtime.temporal, "HELPER_MIN_PIXELS", 0)
    monkeypatch.setattr(workers, "helper_problem", None)
    workers.stop_helper()
    yield
    workers.stop_helper()


def test_shared_arrays_and_their_views_are_recognised_and_their_memory_reused():
    a = workers.shared_empty((3, 5, 7), np.float32)
    assert a.shape == (3, 5, 7) and a.dtype == np.float32 and a.flags.c_contiguous and a.flags.writeable
    assert workers.is_shared(a) and workers.is_shared(a[1]) and workers.is_shared(a[:, ::2, 3])
    assert not workers.is_shared(np.empty((3, 5, 7), np.float32)) and not workers.is_shared(a.copy())
    assert workers.shareable([a, {"x": a[0]}, (a[2], np.float32(0.5), 3)])
    assert not workers.shareable([a, {"x": np.zeros(3)}])
    before = len(workers._segments)
    del a
    for _ in range(20):                      # the driver's pattern: the same sizes every frame
        b = workers.shared_empty((3, 5, 7), np.float32)
        b[...] = 1
        del b
    assert len(workers._segments) <= before  # no segment per frame


def test_run_split_runs_the_second_job_in_the_helper_with_the_same_result(fresh_helper):
    out = workers.shared_empty((6, 2), np.float64)
    res = workers.run_split(_stamp, [(out, slice(0, 3), 1.0), (out, slice(3, 6), 2.0)], 2)
    assert res == [2.0, 4.0]
    np.testing.assert_array_equal(out[:, 0], [1, 1, 1, 2, 2, 2])
    assert (out[:3, 1] == os.getpid()).all()
    assert (out[3:, 1] == workers._helper.proc.pid).all() and workers._helper.proc.pid != os.getpid()
    # An array that is not shared: both jobs here (threads), same result.
    plain = np.zeros((6, 2))
    assert workers.run_split(_stamp, [(plain, slice(0, 3), 1.0), (plain, slice(3, 6), 2.0)], 2) == [2.0, 4.0]
    assert (plain[:, 1] == os.getpid()).all() and plain[3, 0] == 2
    # One thread: never the helper.
    out[:] = 0
    workers.run_split(_stamp, [(out, slice(0, 3), 1.0), (out, slice(3, 6), 2.0)], 1)
    assert (out[:, 1] == os.getpid()).all()


def test_a_failing_or_lost_helper_leaves_the_work_done_here(fresh_helper):
    out = workers.shared_empty((4, 2), np.float64)
    # The job raises in the helper only: it is redone here, and the helper stays in use.
    workers.run_split(_fail, [(out, slice(0, 2), os.getpid()), (out, slice(2, 4), os.getpid())], 2)
    assert (out[:, 1] == os.getpid()).all() and workers.helper_problem is None
    # The helper dies: the call still completes here, and the reason is kept for the driver.
    workers._helper.proc.kill()
    workers._helper.proc.wait()
    out[:] = 0
    assert workers.run_split(_stamp, [(out, slice(0, 2), 1.0), (out, slice(2, 4), 2.0)], 2) == [2.0, 4.0]
    np.testing.assert_array_equal(out[:, 0], [1, 1, 2, 2])
    assert "helper process failed" in workers.helper_problem
    assert not workers.helper_usable()


@pytest.mark.parametrize("h", [5, 2 * BAND_ROWS + 3])
def test_reprojection_split_with_the_helper_is_the_one_thread_result_to_the_bit(fresh_helper, h):
    rng = np.random.default_rng(h)
    n, w = 2, 9

    def shared(a):
        s = workers.shared_empty(a.shape, a.dtype)
        s[...] = a
        return s

    motion = shared(((rng.random((n, 2, h, w)) - 0.5) * 5).astype(np.float32))
    g = lambda: {"depth": shared(rng.random((n, 1, h, w), dtype=np.float32) + 0.5),  # noqa: E731
                 "normal": shared(np.broadcast_to(np.float32([0, 0, -1])[None, :, None, None], (n, 3, h, w))),
                 "position": shared(rng.random((n, 3, h, w), dtype=np.float32) * 0.05)}
    cur, prev = g(), g()
    states = [shared(rng.random((n, 3, h, w), dtype=np.float32)), shared(rng.random((n, 1, h, w), dtype=np.float32))]
    current = shared(rng.random((n, 3, h, w), dtype=np.float32))
    blend = [(current, 0.2), None]
    (a1, b1), h1 = reproject(states, motion, cur, prev, threads=1, blend=blend)
    (a2, b2), h2 = reproject(states, motion, cur, prev, threads=2, blend=blend, alloc=workers.shared_empty)
    assert workers.is_shared(a2) and workers._helper is not None and workers.helper_problem is None
    assert 0.1 < h1.mean() < 0.95
    for x, y in ((a1, a2), (b1, b2), (h1, h2)):
        np.testing.assert_array_equal(x, y)


def test_a_forked_child_neither_uses_the_parents_helper_nor_its_segments(fresh_helper):
    out = workers.shared_empty((4, 2), np.float64)
    workers.run_split(_stamp, [(out, slice(0, 2), 1.0), (out, slice(2, 4), 2.0)], 2)
    assert workers._helper is not None
    pid = os.fork()
    if pid == 0:                                       # the child: report through the exit code
        ok = (workers._helper is None and not workers.is_shared(out) and not workers._segments
              and workers.is_shared(workers.shared_empty((4, 2))))
        os._exit(0 if ok else 1)
    _, status = os.waitpid(pid, 0)
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
    # The parent's helper is unaffected.
    out[:] = 0
    workers.run_split(_stamp, [(out, slice(0, 2), 1.0), (out, slice(2, 4), 2.0)], 2)
    assert (out[2:, 1] == workers._helper.proc.pid).all()


def test_freed_segments_kept_for_reuse_are_bounded(monkeypatch):
    monkeypatch.setattr(workers, "KEEP_FREE_BYTES", 3 * 4096)
    arrays = [workers.shared_empty((1024,), np.float32) for _ in range(6)]   # one page each
    ids = set(workers._segments)
    del arrays
    free = [i for v in workers._free.values() for i in v]
    assert sum(workers._segments[i].size for i in free) <= 3 * 4096
    assert len(ids) - len(set(workers._segments)) >= 3
