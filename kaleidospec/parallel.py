"""Independent tasks in parallel: local worker processes or a Dask cluster, results as they come.

A sweep's design points and a video's segments are independent pieces of work, each a call of
one module-level function.  :func:`map_unordered` runs them in ``spawn`` worker processes
(drjit/LLVM state and the threads of a parent that has rendered must not be forked) or, given a
scheduler address, on a Dask cluster (``dask.distributed``, an optional dependency imported only
then), and yields each result as soon as its task finishes.
"""

from __future__ import annotations

from typing import Callable, Iterable, Iterator

from recon.errors import InputError

__all__ = ["map_unordered", "dask_client"]


def dask_client(address: str):
    """A ``dask.distributed`` client of the scheduler at ``address`` (``tcp://host:port``).

    Raises
    ------
    InputError
        dask.distributed is not installed, or the scheduler cannot be reached (10 s).
    """
    try:
        from dask.distributed import Client
    except ImportError:
        raise InputError("--scheduler needs dask.distributed, which is not installed "
                         "(pip install 'dask[distributed]')") from None
    try:
        return Client(address, timeout="10s")
    except (OSError, TimeoutError) as err:
        raise InputError(f"cannot reach the Dask scheduler at {address} ({err})") from None


def map_unordered(fn: Callable, args: Iterable[tuple], *, workers: int = 1,
                  scheduler: str | None = None, initializer: Callable | None = None,
                  initargs: tuple = (), poll_s: float | None = None,
                  on_poll: Callable[[], None] | None = None) -> Iterator:
    """Yield ``fn(*a)`` for every tuple ``a`` of ``args``, in the order the calls finish.

    Parameters
    ----------
    fn : callable
        A module-level function (worker processes import it by name).
    args : iterable of tuple
        The positional arguments of each call.
    workers : int
        Local worker processes; 1 runs the calls here, one after the other.  Ignored with
        ``scheduler``.
    scheduler : str, optional
        A Dask scheduler's address: the calls run on its workers.
    initializer, initargs
        Run once in every local worker process (and here, for ``workers=1``) before its calls.
    poll_s, on_poll
        With ``poll_s``, ``on_poll()`` is called at least every ``poll_s`` seconds while
        calls run in parallel, and after each result (progress shown while waiting).
    """
    items = [tuple(a) for a in args]
    if scheduler:
        yield from _on_dask(fn, items, scheduler, poll_s, on_poll)
        return
    if workers <= 1:
        if initializer is not None:
            initializer(*initargs)
        for a in items:
            yield fn(*a)
        return
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                             initializer=initializer, initargs=initargs) as ex:
        futs = {ex.submit(fn, *a) for a in items}
        while futs:
            finished, futs = wait(futs, timeout=poll_s, return_when=FIRST_COMPLETED)
            for f in finished:
                yield f.result()
            if on_poll is not None:
                on_poll()


def _on_dask(fn, items, scheduler, poll_s, on_poll):
    from concurrent.futures import FIRST_COMPLETED

    from dask.distributed import wait as dask_wait

    client = dask_client(scheduler)
    try:
        remaining = set(client.map(fn, *zip(*items), pure=False)) if items else set()
        while remaining:
            try:
                res = dask_wait(list(remaining), timeout=poll_s, return_when=FIRST_COMPLETED)
            except TimeoutError:
                # Dask's wait raises when nothing finished within the poll interval (unlike
                # concurrent.futures.wait): show the progress, wait again.
                if on_poll is not None:
                    on_poll()
                continue
            for f in res.done:
                yield f.result()
            remaining = set(res.not_done)
            if on_poll is not None:
                on_poll()
    finally:
        client.close()
