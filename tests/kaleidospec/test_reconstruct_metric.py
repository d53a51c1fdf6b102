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


def test_subspace_tv_takes_the_band_metric_weighted_and_nlr_the_scalar_step(problem):
    """subspace-nlr's first stage is the subspace-tv solve, in the band metric; its denoiser
    stage, after a first stage the rule stopped, takes the scalar step."""
    from kaleidospec.reconstruct import solve_views
    from recon.priors.nonlocal_lowrank import denoise_iters_for

    op, g = problem
    _, info = solve_views(op, g, 3, iters=5, tol=None, prior="subspace-tv", noise=0.01)
    assert info["solver_info"]["metric"] == "bands" and info["solver_info"]["band_weighted"]
    _, info = solve_views(op, g, 3, iters=2, tol=None, prior="subspace-nlr", noise=0.01)
    assert info["solver_info"]["metric"] == "bands" and info["iters"] == 2
    assert info["solver_info"]["first_stage"]["prior"] == "subspace-tv"
    # Five boxes of five spectra: the default rank, 4, is not held up by empty directions.
    rng = np.random.default_rng(3)
    x = np.zeros(op.ishape, np.float32)
    for y0, x0 in ((2, 2), (2, 13), (13, 2), (13, 13), (8, 8)):
        x[:, y0:y0 + 8, x0:x0 + 8] += rng.random(op.ishape[0]).astype(np.float32)[:, None, None]
    _, info = solve_views(op, op.forward(x), 3, iters=1000, prior="subspace-nlr", noise=0.01)
    first = info["solver_info"]["first_stage"]
    assert first["converged"] and info["iters"] == first["iterations"] + denoise_iters_for(3)
    assert info["solver_info"]["metric"] == "scalar"
    assert info["solver_info"]["prior"] == "subspace-nlr"


def test_solver_metric():
    from kaleidospec.reconstruct import solver_metric

    assert solver_metric("fista-tv", "bands") == {"metric": "bands"}
    assert solver_metric("fista-tv", None) == {}
    assert solver_metric("twist", "auto") == {} and solver_metric("gap-tv", "scalar") == {}
    with pytest.raises(InputError, match="FISTA"):
        solver_metric("twist", "bands")


def test_reconstructor_computes_fistas_step_once(problem, monkeypatch):
    # A sequence's frames share the operator: FISTA-TV's band metric is estimated once (and
    # no ||H||^2 besides), and the frames come out as a plain solve of each in the
    # application's metric would give them, to the bit.
    import sys

    from kaleidospec.reconstruct import DEFAULTS, Reconstructor
    from recon import solvers
    from recon.solvers import band_metric as bmod
    from recon.solvers import fista_tv

    op, g = problem
    rec = Reconstructor(op, lambda frame, meta: frame, solver="fista-tv", tau=0.01)
    calls = {"metric": 0, "norm": 0}
    real_metric, real_norm = bmod.band_metric, solvers.operator_norm_sq

    def counted_metric(*a, **k):
        calls["metric"] += 1
        return real_metric(*a, **k)

    def counted_norm(*a, **k):
        calls["norm"] += 1
        return real_norm(*a, **k)
    monkeypatch.setattr(bmod, "band_metric", counted_metric)
    monkeypatch.setattr(solvers, "operator_norm_sq", counted_norm)
    monkeypatch.setattr(sys.modules["recon.solvers.fista_tv"], "operator_norm_sq", counted_norm)
    frames = [g, g * np.float32(0.8)]
    cubes = []
    for i, frame in enumerate(frames):
        gm = rec.measurement(frame, {})
        cubes.append(rec.solve(gm, iters=10, x0=None if i == 0 else cubes[-1])[0])
    assert calls == {"metric": 1, "norm": 0}
    monkeypatch.undo()
    gm = rec.measurement(frames[1], {})
    x0 = np.ascontiguousarray(np.moveaxis(cubes[0], 2, 0))
    want = fista_tv(rec.op, gm, iters=10, tau=0.01, x0=x0, metric=DEFAULTS["metric"])
    assert want.info["metric"] == "bands"
    np.testing.assert_array_equal(cubes[1], np.moveaxis(want.x, 0, 2))
