"""Reconstruction from a calibration at its measured figures, against the exact operator, and
bad input."""

import pytest

from recon.errors import InputError


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


#: PSNR (dB) at this test size: the 50 nm ``small`` design, the ColorChecker at twice the
#: grid through the scene frames' own trace, FISTA-TV with the application's defaults (to a
#: relative change of 1e-3: 153 / 96 / 253 / 119 / 248 / 152 iterations), measured
#: with the calibration from its own captures and with the exact operator traced with its own
#: seed.  Honest figures: no capture shares the frame's realisation (tests/sim/test_transport.py
#: checks the realisations converge).  A change that moves one by more than TOLERANCE_DB, up or
#: down, must say why (and update these).
FIGURES = {("shifted", 1): 18.09, ("shifted", 5): 26.38, ("footprint", 1): 18.87,
           ("footprint", 5): 30.25, ("oracle", 1): 18.89, ("oracle", 5): 30.70}
TOLERANCE_DB = 0.3


@pytest.fixture(scope="module")
def oracle_psnr(setup):
    from kaleidospec.reconstruct import reconstruct_oracle

    d, cal, frame, meta, truth, wl = setup
    return {n: reconstruct_oracle(frame, meta, d, n, truth=truth)[1]["metrics"]["psnr"]
            for n in (1, 5)}


def test_shifted_model_figures(setup, oracle_psnr):
    from kaleidospec.reconstruct import reconstruct_views

    d, cal, frame, meta, truth, wl = setup
    for n in (1, 5):
        cube, info = reconstruct_views(frame, meta, cal, n, truth=truth)
        assert cube.shape == tuple(cal.cube_shape)
        got = info["metrics"]["psnr"]
        assert abs(got - FIGURES[("shifted", n)]) < TOLERANCE_DB, (n, got)
    for n in (1, 5):
        assert abs(oracle_psnr[n] - FIGURES[("oracle", n)]) < TOLERANCE_DB, (n, oracle_psnr[n])


def test_footprint_model_is_within_1db_of_the_exact_operator(setup, footprint_cal,
                                                              oracle_psnr):
    """The footprint model, measured with comb captures, reconstructs within 1 dB of the
    converged exact operator with 1 and 5 views at this size (the shifted model trails it by
    4.3 dB at 5 views), and at its measured figures."""
    from kaleidospec.reconstruct import reconstruct_views

    d, cal, frame, meta, truth, wl = setup
    for n in (1, 5):
        cube, info = reconstruct_views(frame, meta, footprint_cal, n, truth=truth,
                                       model="footprint")
        assert cube.shape == truth.shape                 # the comb target's grid is the scene's
        got = info["metrics"]["psnr"]
        assert got > oracle_psnr[n] - 1.0, (n, oracle_psnr[n], got)
        assert abs(got - FIGURES[("footprint", n)]) < TOLERANCE_DB, (n, got)


def test_default_stops_once_converged(setup):
    """The default stopping rule (relative change below ``tol``) ends well before the cap and
    where running on to it changes the PSNR by less than 0.1 dB; a fixed count without ``tol``
    runs every iteration."""
    from kaleidospec.reconstruct import DEFAULTS, reconstruct_views

    d, cal, frame, meta, truth, wl = setup
    _, info = reconstruct_views(frame, meta, cal, 1, truth=truth)
    assert info["converged"] and info["iters"] < DEFAULTS["iters"] * 0.6
    _, full = reconstruct_views(frame, meta, cal, 1, truth=truth, tol=None)
    assert full["iters"] == DEFAULTS["iters"] and not full["converged"]
    assert abs(full["metrics"]["psnr"] - info["metrics"]["psnr"]) < 0.1, \
        (info["metrics"]["psnr"], full["metrics"]["psnr"])


def test_bad_input(setup):
    from kaleidospec.reconstruct import reconstruct_views

    d, cal, frame, meta, truth, wl = setup
    with pytest.raises(InputError, match="design"):
        reconstruct_views(frame, dict(meta, design_hash="ffffffffffffffff"), cal, 1)
    with pytest.raises(InputError, match="missing"):
        reconstruct_views(frame, meta, cal, 9)
    with pytest.raises(InputError):
        reconstruct_views(frame, meta, cal, 0)
