"""FISTA's step metric in the application's solve (kaleidospec.reconstruct.DEFAULTS["metric"])."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators import kaleidoscope_cassi


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(2)
    op = kaleidoscope_cassi((rng.random((3, 24, 24)) > 0.5).astype(np.float32),
                            np.arange(6, dtype=float), 3)
    x = np.zeros(op.ishape, np.float32)
    x[:, 6:18, 4:15] = np.linspace(0.2, 1.0, op.ishape[0])[:, None, None]
    return op, op.forward(x)


def test_default_takes_the_band_metric_for_tv(problem):
    from kaleidospec.reconstruct import DEFAULTS, solve_views

    op, g = problem
    assert DEFAULTS["metric"] == "auto"
    _, info = solve_views(op, g, 3, tau=0.01, iters=20, tol=None)
    assert info["solver_info"]["metric"] == "bands"
    _, info = solve_views(op, g, 3, tau=0.01, iters=20, tol=None, metric="scalar")
    assert info["solver_info"]["metric"] == "scalar"


def test_other_priors_keep_the_scalar_step(problem):
    from kaleidospec.reconstruct import solve_views

    op, g = problem
    _, info = solve_views(op, g, 3, iters=5, tol=None, prior="subspace-tv", noise=0.01)
    assert info["solver_info"]["metric"] == "scalar"


def test_solver_metric():
    from kaleidospec.reconstruct import solver_metric

    assert solver_metric("fista-tv", "bands") == {"metric": "bands"}
    assert solver_metric("fista-tv", None) == {}
    assert solver_metric("twist", "auto") == {} and solver_metric("gap-tv", "scalar") == {}
    with pytest.raises(InputError, match="FISTA"):
        solver_metric("twist", "bands")
