"""Progress on long work: a bar on a terminal, one line per finished step elsewhere.

:func:`progress_bar` is what every long loop of the package reports through (captures, traces,
deconvolutions, solves, video frames).  On a terminal it is a ``tqdm`` bar, redrawn as the work
goes on and cleared when done.  When the stream is not a terminal (a log file, a CI job, a
pipe), each redraw would add a line to the log, so it is a :class:`StepLine` instead: nothing
while the work runs, then one line when it ends, with the count done, the wall time and the
last figures the loop reported (``set_postfix``).  ``show=False`` (``--no-progress``) gives a
:class:`Silent` bar.
"""

from __future__ import annotations

import sys
import time

__all__ = ["progress_bar", "StepLine", "Silent", "is_terminal"]


def is_terminal(stream=None) -> bool:
    """Whether ``stream`` (default: stderr) is a terminal, where a bar can redraw in place."""
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):     # no isatty, or a closed stream
        return False


class Silent:
    """A bar that shows nothing (``--no-progress``); counts like the others."""

    def __init__(self, iterable=None, total=None, initial: int = 0, **_):
        self.iterable, self.total, self.n = iterable, total, int(initial)

    def __iter__(self):
        for x in self.iterable:
            yield x
            self.n += 1

    def update(self, n: int = 1) -> None:
        self.n += n

    def set_postfix(self, *args, **kwargs) -> None:
        pass

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class StepLine(Silent):
    """A bar for a log: one line when the step ends, ``desc: n/total unit in T s (figures)``.

    Nothing is written while the step runs (no redraws); a step closed twice writes once.
    ``initial`` counts work found already done (a resumed video): the line gives the work
    done now and the total.
    """

    def __init__(self, iterable=None, total=None, desc: str = "", unit: str = "it",
                 initial: int = 0, file=None, **_):
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        super().__init__(iterable, total, initial)
        self.desc, self.unit, self.file = desc, unit, file
        self.initial = int(initial)
        self.postfix = ""
        self._t0 = time.perf_counter()
        self._closed = False

    def __iter__(self):
        yield from super().__iter__()
        self.close()                 # as tqdm does once its iterable is exhausted

    def set_postfix(self, ordered_dict=None, refresh: bool = True, **kwargs) -> None:
        items = dict(ordered_dict or {}, **kwargs)
        self.postfix = ", ".join(f"{k} {v}" for k, v in items.items())

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        seconds = time.perf_counter() - self._t0
        done = self.n - self.initial
        count = f"{done}/{self.total}" if self.total is not None else f"{done}"
        line = f"{self.desc}: {count} {self.unit} in {seconds:.1f} s"
        if self.initial:
            line += f" ({self.initial} done before)"
        if self.postfix:
            line += f" ({self.postfix})"
        stream = sys.stderr if self.file is None else self.file
        print(line, file=stream, flush=True)


def progress_bar(iterable=None, *, total=None, desc: str = "", unit: str = "it",
                 show: bool = True, leave: bool = False, initial: int = 0, file=None):
    """A progress report over ``iterable`` or ``total`` steps on stderr (or ``file``).

    ``show`` False: :class:`Silent`.  On a terminal: a ``tqdm`` bar (``leave`` keeps it on
    screen once done).  Elsewhere: a :class:`StepLine`, one line when the step ends.  Each
    supports iteration, ``update``, ``set_postfix``, ``n``, ``refresh`` and ``close``, and is a
    context manager.
    """
    if not show:
        return Silent(iterable, total, initial)
    stream = sys.stderr if file is None else file
    if not is_terminal(stream):
        return StepLine(iterable, total, desc, unit, initial, file)
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, initial=initial,
                file=file)
