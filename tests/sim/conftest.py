"""Fixtures of the simulator's tests."""

import pytest


@pytest.fixture
def small_transport(shared_cache):
    """The `small` design's transport (seed 0), traced once into the shared test cache."""
    pytest.importorskip("mitsuba")
    from sim.optics.design import get_design
    from sim.transport.exact import load_or_build

    return load_or_build(get_design("small"), seed=0)
