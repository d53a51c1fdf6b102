"""A calibrated solve's operator constants kept in the cache (kaleidospec.solve_constants)."""

import dataclasses
import json

import numpy as np
import pytest


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """An empty cache folder for the constants (the calibration is already in memory)."""
    monkeypatch.setenv("KALEIDOSPEC_CACHE", str(tmp_path))
    return tmp_path


def entries(folder):
    return sorted(folder.glob("solve-*.json"))


def solve(setup, n=5, **kw):
    from kaleidospec.reconstruct import reconstruct_views

    d, cal, frame, meta, truth, wl = setup
    return reconstruct_views(frame, meta, cal, n, iters=20, tol=None, **kw)


def no_estimates(monkeypatch):
    """Make every estimate of a constant fail."""
    import sys

    from kaleidospec import reconstruct as rc
    from recon.solvers import band_metric as bmod

    def fail(*a, **k):
        raise AssertionError("a constant was estimated again")
    monkeypatch.setattr(rc, "unit_row_scale", fail)
    monkeypatch.setattr(bmod, "band_metric", fail)
    monkeypatch.setattr(sys.modules["recon.solvers.fista_tv"], "operator_norm_sq", fail)


def test_the_second_solve_takes_the_first_ones_constants(setup, folder, monkeypatch):
    from recon.solvers.band_metric import DEFAULT_EXPONENT
    from recon.solvers.constants import band_metric_name

    plain, _ = solve(setup, cached_constants=False)
    assert entries(folder) == []                         # nothing kept without the cache
    first, info = solve(setup)
    (path,) = entries(folder)
    kept = json.loads(path.read_text())["constants"]
    assert set(kept) == {"row_scale", band_metric_name(DEFAULT_EXPONENT, np.float32)}
    assert kept[band_metric_name(DEFAULT_EXPONENT, np.float32)] == \
        info["solver_info"]["band_metric"]
    with monkeypatch.context() as mp:
        no_estimates(mp)
        second, _ = solve(setup)
    # The same bits whether the constants were estimated or read back.
    np.testing.assert_array_equal(first, plain)
    np.testing.assert_array_equal(second, plain)
    # Another view set is another operator: its own entry.
    solve(setup, n=1)
    assert len(entries(folder)) == 2


def test_a_damaged_entry_is_removed_and_estimated_again(setup, folder, monkeypatch, capsys):
    want, _ = solve(setup)
    (path,) = entries(folder)
    text = path.read_text()
    obj = json.loads(text)
    obj["constants"]["row_scale"] *= 2                   # a value changed behind the checksum
    for damaged in (json.dumps(obj), text[: len(text) // 2], "\x00garbage"):
        path.write_text(damaged)
        capsys.readouterr()
        got, _ = solve(setup)
        assert "warning" in capsys.readouterr().err
        np.testing.assert_array_equal(got, want)
        assert json.loads(path.read_text())["constants"] == json.loads(text)["constants"]


def test_the_key_follows_the_calibrations_content(setup, folder):
    from kaleidospec.solve_constants import calibration_digest, constants_for

    d, cal, *_ = setup
    solve(setup)
    assert len(constants_for(cal, (0, 1, 2, 3, 4), "shifted").as_dict()) == 2
    other = dataclasses.replace(cal, gains=cal.gains * 2)
    assert calibration_digest(other) != calibration_digest(cal)
    assert constants_for(other, (0, 1, 2, 3, 4), "shifted").as_dict() == {}
    assert constants_for(cal, (0,), "shifted").as_dict() == {}
    assert constants_for(cal, (0, 1, 2, 3, 4), "footprint").as_dict() == {}


def test_a_cache_folder_that_cannot_be_written_still_solves(setup, tmp_path, monkeypatch,
                                                           capsys):
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")
    monkeypatch.setenv("KALEIDOSPEC_CACHE", str(blocked))
    want, _ = solve(setup, cached_constants=False)
    got, _ = solve(setup)
    assert "kept for this solve only" in capsys.readouterr().err
    np.testing.assert_array_equal(got, want)


def test_a_sequence_takes_the_constants_of_earlier_solves(setup, folder, monkeypatch):
    from kaleidospec.reconstruct import Reconstructor

    d, cal, frame, meta, truth, wl = setup
    still, _ = solve(setup)
    with monkeypatch.context() as mp:
        no_estimates(mp)
        rec = Reconstructor.calibrated(cal, 5, solver="fista-tv")
        cube, _ = rec.solve(rec.measurement(frame, meta), iters=20)
    assert rec.constants.estimated == []
    np.testing.assert_array_equal(cube, still)
