"""Workers for the driver's numpy stages (layer conversion, reprojection): threads, and a
helper process for row-split work.

numpy releases the GIL inside each array operation, so a few threads that each run large
enough operations use more than one core; many small operations make the threads wait for
the GIL instead.  Measured on this project's 2-core machine at 1280x720: layer conversion
21.5 -> 12.3 ms, reprojection 65 -> 46 ms with two threads.  More threads than two were not
measured and contend for the GIL, so :func:`default_threads` stops at two.

The reprojection makes about a hundred numpy calls per band of rows, and two threads spend
much of it handing the GIL to each other: two *independent* one-thread reprojections take
124 ms in two threads of one process and 69 / 74 ms in two processes at once (1280x720).
So :func:`run_split` hands half of the rows to a **helper process** that works on the same
memory: arrays allocated by :func:`shared_empty` live in Linux ``memfd`` segments mapped by
both processes, and the helper receives only their descriptors.  1280x720 reprojection with
accumulation: 50-52 ms on two threads, 36 ms split with the helper, the same result to the
bit.  Where the helper cannot run (not Linux, an array not in shared memory, the helper
gone), the work runs on threads as before, with the same result; :data:`helper_problem`
says why once it failed.
"""
from __future__ import annotations

import atexit
import mmap
import os
import socket
import subprocess
import sys
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

#: Most threads the driver uses by default.
MAX_DEFAULT_THREADS = 2

_pools: dict[int, ThreadPoolExecutor] = {}
_lock = threading.Lock()


def default_threads() -> int:
    """Driver threads when the caller does not say: this machine's cores, at most two."""
    return max(1, min(MAX_DEFAULT_THREADS, os.cpu_count() or 1))


def executor(threads: int) -> ThreadPoolExecutor | None:
    """A shared pool of ``threads`` workers (created once per size), or None for one thread."""
    if threads <= 1:
        return None
    with _lock:
        pool = _pools.get(threads)
        if pool is None:
            pool = _pools[threads] = ThreadPoolExecutor(threads, thread_name_prefix="mcdenoise")
        return pool


def run_all(fn, args_list, threads: int) -> list:
    """``[fn(*args) for args in args_list]``, on ``threads`` workers when > 1 (results in
    order; the first exception is raised after every job has finished)."""
    pool = executor(threads)
    if pool is None or len(args_list) < 2:
        return [fn(*args) for args in args_list]
    jobs = [pool.submit(fn, *args) for args in args_list]
    errors = [j.exception() for j in jobs]
    for e in errors:
        if e is not None:
            raise e
    return [j.result() for j in jobs]


# ----------------------------------------------------------------------------------------------
# Shared memory and the helper process
# ----------------------------------------------------------------------------------------------

#: Whether this platform can share numpy arrays with a helper process (Linux ``memfd``).
SHARED_SUPPORTED = hasattr(os, "memfd_create") and sys.platform.startswith("linux")
#: Bytes of freed shared segments kept for reuse (the driver frees and reallocates the same
#: sizes every frame, and a fresh 11 MB segment costs its page faults, 2-4 ms at 720p); the
#: oldest beyond this are closed.
KEEP_FREE_BYTES = 128 << 20
#: Why the helper process is not used (None while it works or was never needed).
helper_problem: str | None = None


class _Segment(NamedTuple):
    fd: int
    mm: mmap.mmap
    addr: int
    size: int


class _Ref(NamedTuple):
    """An array inside a shared segment, as the helper rebuilds it."""
    seg: int
    offset: int
    shape: tuple
    strides: tuple
    dtype: str


class _NotShared(Exception):
    pass


_seg_lock = threading.RLock()
_segments: dict[int, _Segment] = {}      # live and free segments by id
_free: dict[int, list[int]] = {}         # size -> free segment ids (most recently freed last)
_freed_order: list[int] = []             # free segment ids, oldest first
_next_seg = [0]


def _on_free(seg: int) -> None:
    """A shared array's last view is gone: keep its segment for reuse (or close the oldest)."""
    with _seg_lock:
        s = _segments.get(seg)
        if s is None:
            return
        _free.setdefault(s.size, []).append(seg)
        _freed_order.append(seg)
        kept = sum(_segments[i].size for ids in _free.values() for i in ids)
        while kept > KEEP_FREE_BYTES:
            old = next(i for i in _freed_order if i in _segments and i in _free.get(_segments[i].size, ()))
            kept -= _segments[old].size
            _close_segment(old)


def _close_segment(seg: int) -> None:
    s = _segments.pop(seg)
    _free[s.size].remove(seg)
    if not _free[s.size]:
        del _free[s.size]
    while seg in _freed_order:
        _freed_order.remove(seg)
    try:
        s.mm.close()
    except BufferError:          # still exported somewhere: leave it to the garbage collector
        pass
    os.close(s.fd)
    if _helper is not None:
        _helper.forget(seg)


def shared_empty(shape, dtype=np.float32) -> np.ndarray:
    """A new uninitialised C-contiguous array that :func:`run_split` can hand to the helper
    process (a plain ``np.empty`` where sharing is not supported).  Its memory goes back to a
    pool for reuse when the array and all its views are gone."""
    dtype = np.dtype(dtype)
    shape = tuple(int(n) for n in shape)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if not SHARED_SUPPORTED or nbytes == 0:
        return np.empty(shape, dtype)
    size = -(-nbytes // mmap.PAGESIZE) * mmap.PAGESIZE
    with _seg_lock:
        ids = _free.get(size)
        if ids:
            seg = ids.pop()
            if not ids:
                del _free[size]
            _freed_order.remove(seg)
            mm = _segments[seg].mm
        else:
            fd = os.memfd_create("mcdenoise", os.MFD_CLOEXEC)
            try:
                os.ftruncate(fd, size)
                mm = mmap.mmap(fd, size)
            except OSError:
                os.close(fd)
                return np.empty(shape, dtype)
            seg = _next_seg[0] = _next_seg[0] + 1
            addr = np.frombuffer(mm, np.uint8, 1).ctypes.data
            _segments[seg] = _Segment(fd, mm, addr, size)
    base = np.frombuffer(mm, np.uint8, nbytes)
    weakref.finalize(base, _on_free, seg)
    return base.view(dtype).reshape(shape)


def is_shared(a) -> bool:
    """Whether ``a`` (an array or a view) lies in memory from :func:`shared_empty`."""
    return _locate(a) is not None


def _locate(a: np.ndarray):
    """(segment id, byte offset) of ``a``'s data, or None when it is not in a live segment."""
    if not isinstance(a, np.ndarray) or not _segments:
        return None
    addr = a.__array_interface__["data"][0]
    # The extent of the view: its lowest and highest addressed bytes.
    lo = hi = addr
    for n, st in zip(a.shape, a.strides):
        if n == 0:
            return None
        if st < 0:
            lo += (n - 1) * st
        else:
            hi += (n - 1) * st
    hi += a.itemsize
    with _seg_lock:
        for seg, s in _segments.items():
            if s.addr <= lo and hi <= s.addr + s.size:
                return seg, addr - s.addr
    return None


def _encode(obj):
    """``obj`` with every array replaced by a :class:`_Ref`; raises _NotShared if one is not
    in shared memory."""
    if isinstance(obj, np.ndarray):
        where = _locate(obj)
        if where is None:
            raise _NotShared
        return _Ref(where[0], where[1], obj.shape, obj.strides, obj.dtype.str)
    if isinstance(obj, (list, tuple)) and not isinstance(obj, _Ref):
        return type(obj)(_encode(o) for o in obj)
    if isinstance(obj, dict):
        return {k: _encode(v) for k, v in obj.items()}
    return obj


def shareable(obj) -> bool:
    """Whether every array in ``obj`` (arrays, lists, tuples, dicts of them) is in shared
    memory, so that :func:`run_split` can hand it to the helper process."""
    try:
        _encode(obj)
        return True
    except _NotShared:
        return False


def helper_usable() -> bool:
    """Whether :func:`run_split` may use the helper process (supported, and not failed)."""
    return SHARED_SUPPORTED and helper_problem is None


def _segments_of(obj, out: set) -> set:
    if isinstance(obj, _Ref):
        out.add(obj.seg)
    elif isinstance(obj, (list, tuple)):
        for o in obj:
            _segments_of(o, out)
    elif isinstance(obj, dict):
        for o in obj.values():
            _segments_of(o, out)
    return out


class _Helper:
    """The helper process: runs ``module.function(*args)`` on shared arrays, one call at a time."""

    def __init__(self):
        from multiprocessing.connection import Connection

        parent, child = socket.socketpair()
        code = "import sys; from mcdenoise.runtime.workers import _helper_main; _helper_main(int(sys.argv[1]))"
        self.proc = subprocess.Popen([sys.executable, "-c", code, str(child.fileno())],
                                     pass_fds=(child.fileno(),), stdin=subprocess.DEVNULL)
        child.close()
        self.conn = Connection(parent.detach())
        self.mapped: set[int] = set()
        self._pending_unmap: list[int] = []
        self.conn.send(("ping",))
        if self.conn.recv() != ("ok", None):
            raise RuntimeError("the helper process did not answer")

    def forget(self, seg: int) -> None:
        if seg in self.mapped:
            self.mapped.discard(seg)
            self._pending_unmap.append(seg)

    def submit(self, fn, args) -> None:
        """Send the call (arrays encoded); the caller then does its own share and calls
        :meth:`result`."""
        from multiprocessing.reduction import send_handle

        enc = _encode(args)
        if self._pending_unmap:
            self.conn.send(("unmap", list(self._pending_unmap)))
            self._pending_unmap.clear()
        with _seg_lock:
            for seg in _segments_of(enc, set()) - self.mapped:
                s = _segments[seg]
                self.conn.send(("map", seg, s.size))
                send_handle(self.conn, s.fd, self.proc.pid)
                self.mapped.add(seg)
        self.conn.send(("call", fn.__module__, fn.__qualname__, enc))

    def close(self) -> None:
        try:
            self.conn.close()
        finally:
            try:
                self.proc.wait(timeout=2)
            except subprocess.TimeoutExpired:
                self.proc.kill()


_helper: _Helper | None = None
_helper_lock = threading.Lock()
atexit.register(lambda: stop_helper())


_inherited: list = []


def _after_fork_in_child() -> None:
    """A forked child (e.g. a data-loader worker) must neither talk to its parent's helper nor
    hand out segments the parent also uses: it starts with none of either (arrays it inherited
    stay valid, but are no longer "shared" for :func:`run_split`)."""
    global _helper, _helper_lock, _seg_lock
    if _helper is not None:
        try:
            _helper.conn.close()             # this process's copy of the socket only
        except OSError:
            pass
        _inherited.append(_helper.proc)      # not ours to wait for
    _helper = None
    _helper_lock = threading.Lock()
    _seg_lock = threading.RLock()
    _segments.clear()
    _free.clear()
    _freed_order.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def _get_helper() -> _Helper | None:
    global _helper, helper_problem
    if not SHARED_SUPPORTED or helper_problem is not None:
        return None
    if _helper is None:
        try:
            _helper = _Helper()
        except Exception as e:  # noqa: BLE001 - any failure means: use threads
            helper_problem = f"helper process did not start ({e})"
            return None
    return _helper


def stop_helper() -> None:
    """Stop the helper process (it is started again when next needed)."""
    global _helper
    with _helper_lock:
        if _helper is not None:
            h, _helper = _helper, None
            h.close()


def run_split(fn, args_list, threads: int) -> list:
    """:func:`run_all` for jobs that write disjoint parts of shared arrays: with two jobs and
    ``threads`` >= 2, the second runs in the helper process (when every array it touches is
    from :func:`shared_empty`) while this process runs the first; otherwise on threads.  The
    same results either way: a call that fails in the helper is run again here, and a helper
    that stops answering is left for good (:data:`helper_problem`).  ``fn`` must be a
    module-level function (the helper imports it by name)."""
    global helper_problem
    if threads < 2 or len(args_list) != 2 or not _helper_lock.acquire(blocking=False):
        return run_all(fn, args_list, threads)
    try:
        helper = _get_helper()
        if helper is None:
            return run_all(fn, args_list, threads)
        try:
            helper.submit(fn, args_list[1])
        except _NotShared:
            return run_all(fn, args_list, threads)
        except (OSError, EOFError) as e:
            helper_problem = f"helper process failed ({e}); numpy stages run on threads"
            _drop_helper()
            return run_all(fn, args_list, threads)
        first = fn(*args_list[0])
        try:
            status, second = helper.conn.recv()
        except (OSError, EOFError) as e:
            helper_problem = f"helper process failed ({e}); numpy stages run on threads"
            _drop_helper()
            status = "lost"
        if status != "ok":
            second = fn(*args_list[1])
        return [first, second]
    finally:
        _helper_lock.release()


def _drop_helper() -> None:
    global _helper
    h, _helper = _helper, None
    if h is not None:
        try:
            h.proc.kill()
            h.conn.close()
        except OSError:
            pass


def _helper_main(fd: int) -> None:
    """The helper process's loop: map segments, run calls, answer each."""
    import importlib
    from multiprocessing.connection import Connection
    from multiprocessing.reduction import recv_handle

    conn = Connection(fd)
    maps: dict[int, mmap.mmap] = {}
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        kind = msg[0]
        if kind == "ping":
            conn.send(("ok", None))
        elif kind == "map":
            seg_fd = recv_handle(conn)
            maps[msg[1]] = mmap.mmap(seg_fd, msg[2])
            os.close(seg_fd)
        elif kind == "unmap":
            for seg in msg[1]:
                m = maps.pop(seg, None)
                if m is not None:
                    try:
                        m.close()
                    except BufferError:
                        pass
        elif kind == "call":
            _, module, name, args = msg
            try:
                fn = importlib.import_module(module)
                for part in name.split("."):
                    fn = getattr(fn, part)
                value = fn(*_decode(args, maps))
                conn.send(("ok", value))
            except Exception as e:  # noqa: BLE001 - reported to the caller, who redoes the work
                conn.send(("error", f"{type(e).__name__}: {e}"))


def _decode(obj, maps):
    if isinstance(obj, _Ref):
        return np.ndarray(obj.shape, np.dtype(obj.dtype), buffer=maps[obj.seg], offset=obj.offset,
                          strides=obj.strides)
    if isinstance(obj, (list, tuple)):
        return type(obj)(_decode(o, maps) for o in obj)
    if isinstance(obj, dict):
        return {k: _decode(v, maps) for k, v in obj.items()}
    return obj
