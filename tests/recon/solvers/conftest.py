"""Operators shared by the solver tests: a standard CASSI and a three-view kaleidoscope, at two
sizes (``small_ops`` is small enough for the dense linear algebra of the prior and ADMM tests)."""

import numpy as np
import pytest

from recon.operators import kaleidoscope_cassi, standard_cassi


@pytest.fixture(scope="module")
def ops():
    rng = np.random.default_rng(1)
    return {"standard": standard_cassi((rng.random((32, 32)) > 0.5).astype(np.float32), 1, 8),
            "kaleido3": kaleidoscope_cassi((rng.random((3, 32, 32)) > 0.5).astype(np.float32),
                                           np.arange(8, dtype=float), 3)}


@pytest.fixture(scope="module")
def small_ops():
    L, H, W = 3, 10, 9
    rng = np.random.default_rng(3)
    return {"standard": standard_cassi((rng.random((H, W)) > 0.5).astype(np.float32), 1, L),
            "kaleido3": kaleidoscope_cassi((rng.random((3, H, W)) > 0.5).astype(np.float32),
                                           np.arange(L, dtype=float), 3)}
