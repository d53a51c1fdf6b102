"""Fixtures shared across the test packages."""

import pytest


@pytest.fixture(scope="module")
def shared_cache(tmp_path_factory):
    """``$KALEIDOSPEC_CACHE`` set, for one test module, to a folder that every module using this
    fixture shares: the transports and calibrations of a design are traced once per test run."""
    path = tmp_path_factory.getbasetemp() / "kaleidospec-cache"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("KALEIDOSPEC_CACHE", str(path))
        yield path


@pytest.fixture(scope="module")
def spectral_variant():
    """Skips the module where Mitsuba's spectral variant is not usable on this machine."""
    pytest.importorskip("mitsuba")
    from sim.optics.variant import ensure_variant

    try:
        ensure_variant()
    except Exception as err:  # no usable LLVM for drjit on this machine
        pytest.skip(f"Mitsuba's spectral variant is not usable here: {err}")


@pytest.fixture(scope="module")
def fresh_cache(tmp_path_factory, spectral_variant):
    """``$KALEIDOSPEC_CACHE`` set, for one test module, to a fresh, empty folder (nothing reused
    from earlier runs); the module is skipped where Mitsuba's spectral variant is not usable."""
    path = tmp_path_factory.mktemp("kaleidospec-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("KALEIDOSPEC_CACHE", str(path))
        yield path
