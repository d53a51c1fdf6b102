"""The reconstruction's application layer (recon.app): what it computes beside the solve."""

import numpy as np
import pytest

from recon import app
from recon.kernels import vector as kvec
from recon.operators import standard_cassi


@pytest.fixture
def problem():
    rng = np.random.default_rng(13)
    op = standard_cassi((rng.random((16, 20)) < 0.5).astype(np.float32), step=1, n_bands=4)
    truth = rng.random((16, 20, 4)).astype(np.float32)
    g = op.forward(np.ascontiguousarray(np.moveaxis(truth, 2, 0)))
    return op, g, truth


@pytest.fixture
def psnr_passes(monkeypatch):
    """The PSNRs taken (each a pass over the cube and the truth)."""
    calls = []
    fn = kvec.squared_distance
    monkeypatch.setattr(kvec, "squared_distance", lambda a, b: calls.append(1) or fn(a, b))
    return calls


def test_the_psnr_history_is_taken_only_when_asked(problem, psnr_passes):
    # With a truth the metrics come at the end either way; the PSNR after every iteration only
    # with `history`, and the solve is the same without it.
    op, g, truth = problem
    kw = dict(solver="fista-tv", iters=12, tol=None, truth=truth)
    cube, info = app.reconstruct(g, op, **kw)
    assert len(psnr_passes) == 12 and len(info["psnr_history"]) == 12
    assert info["psnr_history"][-1] == pytest.approx(info["metrics"]["psnr"], abs=1e-3)
    psnr_passes.clear()
    lean, lean_info = app.reconstruct(g, op, history=False, **kw)
    assert psnr_passes == [] and "psnr_history" not in lean_info
    np.testing.assert_array_equal(lean, cube)
    assert lean_info["metrics"] == info["metrics"]
    assert lean_info["iters"] == 12


def test_the_progress_bar_shows_a_psnr_now_and_then(problem, psnr_passes, monkeypatch,
                                                    capsys):
    # Without a history the bar's PSNR is taken at most every PSNR_SHOWN_EVERY seconds (the
    # first iteration's, then none within the interval; every iteration's with no interval)
    # and once more for the result, whose PSNR the bar's closing line shows.
    op, g, truth = problem
    kw = dict(solver="fista-tv", iters=12, tol=None, truth=truth, history=False,
              progress=True)
    monkeypatch.setattr(app, "PSNR_SHOWN_EVERY", 1e9)
    capsys.readouterr()
    _, info = app.reconstruct(g, op, **kw)
    assert len(psnr_passes) == 2
    assert f"psnr {info['metrics']['psnr']:.2f}" in capsys.readouterr().err
    psnr_passes.clear()
    monkeypatch.setattr(app, "PSNR_SHOWN_EVERY", 0.0)
    app.reconstruct(g, op, **kw)
    assert len(psnr_passes) == 12 + 1
