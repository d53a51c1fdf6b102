"""kaleidospec.parallel: every call's result once, from worker processes or in this one."""

from __future__ import annotations

import operator

from kaleidospec.parallel import map_unordered


def test_worker_processes_return_every_result_once():
    polls = []
    got = map_unordered(operator.add, [(1, 2), (3, 4), (5, 6), (7, 8)], workers=2,
                        poll_s=0.05, on_poll=lambda: polls.append(1))
    assert sorted(got) == [3, 7, 11, 15]
    assert len(polls) >= 1            # progress is shown while the workers run


def test_one_worker_runs_the_calls_here_in_order_after_the_initializer():
    calls = []

    def record(*a):
        calls.append(a)
        return len(calls)

    got = list(map_unordered(record, [("a",), ("b", 2)], workers=1, initializer=record,
                             initargs=("init",)))
    assert calls == [("init",), ("a",), ("b", 2)]
    assert got == [2, 3]


def test_no_calls_no_results():
    assert list(map_unordered(operator.add, [], workers=2)) == []
