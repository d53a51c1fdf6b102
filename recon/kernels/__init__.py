r"""Fused Numba kernels for the hot loops of :mod:`recon`, with the NumPy code as reference.

The operators (:mod:`recon.operators`), the TV prox (:mod:`recon.prox`) and the solvers
(:mod:`recon.solvers`) each keep a plain NumPy implementation.  Where a kernel here is
measurably faster they call it instead; every kernel is tested against the NumPy path it
replaces (``tests/recon/kernels``).  A kernel makes one pass over memory where the NumPy code
makes several (a Chambolle prox of any number of dual iterations is a single pass, a CASSI
forward reads the cube once).  Kernels run in float32, the solvers' precision; float64 inputs
(precision checks) take the NumPy path.

Numba is optional: without it, or with ``KALEIDOSPEC_KERNELS=numpy`` in the environment, or
inside :func:`numpy_only`, :func:`enabled` is False and every caller takes its NumPy path.
Kernels are compiled on first use and cached on disk (``cache=True``, next to this package
or in ``NUMBA_CACHE_DIR``), so only the first process on a machine pays the compilation.  The
cache is keyed on each kernel module's source file: after changing the settings here
(:data:`FASTMATH`, :func:`jit`), touch the kernel modules or clear their ``__pycache__``.

Results never depend on the number of threads: work is split over bands or rows whose
results are independent, and reductions are summed per row, then in a fixed order.
"""

from __future__ import annotations

import contextlib
import os
import threading

import numpy as np

__all__ = ["cores", "each", "enabled", "usable", "numpy_only", "threads", "jit"]

_STATE = threading.local()
_NUMBA: list = []  # [numba module or None] once looked up: importing it costs ~0.2 s


def _numba():
    if not _NUMBA:
        # Threads that wait at the end of a parallel kernel sleep instead of spinning.  On a
        # machine whose cores are busy with other work a spinning thread burns the time slice
        # its peer needs: measured on 2 shared cores (load ~2.5), 50 GAP-TV iterations at
        # 256x256x28 took 0.40-0.44 s passive against 0.91-1.34 s spinning, and about the
        # same (0.21-0.28 s) either way while both cores were free.  Read by libgomp when
        # Numba first starts its threads; a value set by the user is kept.
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
        try:
            import numba
        except ImportError:  # pragma: no cover - depends on the installation
            numba = None
        _NUMBA.append(numba)
    return _NUMBA[0]


#: Fast-math flags of every kernel: reassociation (vectorised sums), contraction (FMA) and
#: reciprocal/approximate-function licences, but not ``nnan``/``ninf``: the solvers rely on
#: NaN and infinity propagating (and the stress tests check that they never appear).
FASTMATH = frozenset({"nsz", "arcp", "contract", "reassoc", "afn"})


def cores() -> int:
    """The CPUs this process may run on: its affinity set where the system keeps one (a batch
    scheduler's cpuset, ``taskset``), else every CPU of the machine.

    Thread pools and Numba's threads are sized by it, so that a process held to fewer CPUs
    than the machine has does not time-slice more threads than it has CPUs.
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - systems without affinity sets
        return max(1, os.cpu_count() or 1)


def each(fn, items) -> list:
    """``fn(item)`` for every item, in the items' order, on a thread per CPU the process may
    use (:func:`cores`; for work that releases the GIL: Numba kernels, OpenCV's transforms),
    or on this thread where there is one CPU or one item."""
    from concurrent.futures import ThreadPoolExecutor

    items = list(items)
    workers = min(len(items), cores())
    if workers > 1:
        with ThreadPoolExecutor(workers) as pool:
            return list(pool.map(fn, items))
    return [fn(i) for i in items]


def enabled() -> bool:
    """Whether the Numba kernels are used (Numba importable, not switched off)."""
    if getattr(_STATE, "numpy_only", False):
        return False
    if os.environ.get("KALEIDOSPEC_KERNELS", "").strip().lower() == "numpy":
        return False
    return _numba() is not None


def usable(*arrays) -> bool:
    """Whether the kernels run for these arrays: :func:`enabled`, and all of them float32.

    Kernels are compiled for float32 only, the solvers' working precision: float64 runs
    (precision checks, dot tests) take the NumPy path, which halves the compilation a fresh
    machine pays.
    """
    return enabled() and all(np.asarray(a).dtype == np.float32 for a in arrays)


@contextlib.contextmanager
def numpy_only():
    """Within this block (in this thread) every caller takes its NumPy reference path."""
    old = getattr(_STATE, "numpy_only", False)
    _STATE.numpy_only = True
    try:
        yield
    finally:
        _STATE.numpy_only = old


_LAUNCH = threading.RLock()


def _layer_is_threadsafe(nb) -> bool:
    """Whether Numba's threading layer takes concurrent launches from several threads.

    OpenMP and TBB do; the fallback "workqueue" (no libgomp or TBB on the machine) does not
    (it aborts the process), and before the first launch the layer is not chosen yet.
    """
    try:
        return nb.threading_layer() != "workqueue"
    except ValueError:
        return False


@contextlib.contextmanager
def threads(n: int | None = None):
    """Call kernels in this block: on at most ``n`` threads (``None``: one per CPU of
    :func:`cores`, at most Numba's).

    Every kernel call goes through this block.  Numba's thread count is per calling thread,
    so ``n`` does not affect other threads; where the threading layer is not thread-safe,
    launches from several Python threads (a Dask worker's, say) take turns.
    """
    nb = _numba()
    if nb is None:
        yield
        return
    lock = None if _layer_is_threadsafe(nb) else _LAUNCH
    if lock is not None:
        lock.acquire()
    old = nb.get_num_threads()
    n = cores() if n is None else n
    nb.set_num_threads(max(1, min(int(n), nb.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        nb.set_num_threads(old)
        if lock is not None:
            lock.release()


def jit(parallel: bool = False, refcount: bool = True, exact: bool = False):
    """``numba.njit`` with the package's settings (cached, :data:`FASTMATH`).

    ``exact=True`` compiles without fast-math: every operation rounds as IEEE arithmetic
    does, in the order written, so a kernel gives the same bits as the NumPy expressions it
    replaces (for paths whose outputs are kept to the bit, as the calibration's).

    ``refcount=False`` is for the row helpers, which slice but never allocate: without
    Numba's reference counting a slice costs no atomic update of its parent's count.  Those
    updates, on arrays that both threads slice, made the per-row overhead the larger part of
    a kernel's time (the cache line of the count moves between the cores at every slice).
    """
    # error_model="numpy": a float division by zero gives inf/nan as in NumPy instead of
    # raising, which also lets LLVM vectorise loops that divide.
    opts = dict(cache=True, parallel=parallel, fastmath=set() if exact else set(FASTMATH),
                nogil=True, error_model="numpy")
    if not refcount:
        opts["_nrt"] = False
    return _numba().njit(**opts)
