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
