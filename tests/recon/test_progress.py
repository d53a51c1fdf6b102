"""recon.progress: a bar on a terminal, one line per finished step elsewhere, nothing when off."""

import io

import pytest

from recon.progress import Silent, StepLine, is_terminal, progress_bar


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_log_gets_one_line_when_the_step_ends():
    log = io.StringIO()
    bar = progress_bar(total=5, desc="captures", unit="capture", file=log)
    assert isinstance(bar, StepLine)
    for _ in range(3):
        bar.update()
        bar.set_postfix({"psnr": "20.00 dB"}, refresh=False)
    assert log.getvalue() == ""                   # nothing while the work runs
    bar.close()
    bar.close()                                   # closed twice, written once
    lines = log.getvalue().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("captures: 3/5 capture in ")
    assert lines[0].endswith(" s (psnr 20.00 dB)")


def test_a_loop_over_an_iterable_writes_its_line_when_exhausted():
    log = io.StringIO()
    seen = list(progress_bar(range(4), desc="render", unit="band", file=log))
    assert seen == [0, 1, 2, 3]
    assert log.getvalue().startswith("render: 4/4 band in ")


def test_work_found_done_is_not_counted_as_done_now():
    log = io.StringIO()
    with progress_bar(total=10, initial=6, desc="render", unit="frame", file=log) as bar:
        bar.update(4)
    assert log.getvalue().startswith("render: 4/10 frame in ")
    assert "(6 done before)" in log.getvalue()


def test_off_shows_nothing_and_still_counts(capsys):
    bar = progress_bar(total=3, desc="x", show=False)
    assert isinstance(bar, Silent)
    with bar:
        bar.update(2)
    assert bar.n == 2
    assert list(progress_bar([1, 2], show=False)) == [1, 2]
    assert capsys.readouterr().err == ""


def test_a_terminal_gets_a_bar():
    tqdm = pytest.importorskip("tqdm").tqdm
    term = _Terminal()
    assert is_terminal(term) and not is_terminal(io.StringIO())
    bar = progress_bar(total=3, desc="x", file=term)
    assert isinstance(bar, tqdm)
    bar.close()


def test_the_commands_progress_bar_follows_the_same_rules(monkeypatch):
    import sys

    from kaleidospec.report import progress_bar as command_bar

    assert isinstance(command_bar(3, "calibration", show=False), Silent)
    log = io.StringIO()
    monkeypatch.setattr(sys, "stderr", log)
    with command_bar(3, "calibration") as bar:
        bar.update(3)
    assert log.getvalue().startswith("calibration: 3/3 step in ")
