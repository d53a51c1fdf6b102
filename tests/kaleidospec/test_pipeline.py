"""The pipeline: calibration from rendered captures (cached), reconstruction, bad input."""

import numpy as np
import pytest

from recon.errors import InputError
from sim.design import get_design

OVR = {"band_step_nm": 50.0}


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


@pytest.fixture(scope="module")
def setup(cache):
    from kaleidospec import pipeline

    d = get_design("small", OVR)
    cal = pipeline.calibrate(d, progress=False)
    frame, meta, truth, wl = pipeline.render_scene("colorchecker", d, seed=3)
    return pipeline, d, cal, frame, meta, truth, wl


def test_calibration_is_cached_and_sane(setup, cache):
    pipeline, d, cal, *_ = setup
    from recon.calibration import calibration_path

    p = calibration_path(cache, d.hash)
    assert p.is_file() and p.with_suffix(".json").is_file()
    again = pipeline.calibrate(d, progress=False)
    np.testing.assert_array_equal(again.mask_images, cal.mask_images)
    assert cal.design_hash == d.hash and cal.view_ids == (0, 1, 2, 3, 4)
    assert np.all(cal.gains > 0)
    # The measured dispersion spans what the design says (within a pixel): the offsets are
    # where each band's light lands on average.
    span = cal.offsets[0, -1] - cal.offsets[0, 0]
    phi = pipeline.band_mean_dispersion(d, d.wavelengths)
    assert abs(span - (phi[-1] - phi[0])) < 1.0
    # The grid is the union of what the views code: the centre's coded columns and its guard
    # columns, which the mirrored views see (their x-scale differs from 1 by a few %).
    h, w, L = cal.cube_shape
    v = d.view_size_px
    assert L == d.n_bands and abs(h - v) <= 2 and v - 2 <= w <= v + 8
    assert cal.view_shape[1] >= v - d.guard_px


def test_truth_on_grid_matches_the_reconstruction_grid(setup):
    pipeline, d, cal, frame, meta, truth, wl = setup
    tg = pipeline.truth_on_grid(truth, d, cal)
    assert tg.shape == tuple(cal.cube_shape)
    cube, _ = pipeline.reconstruct_views(frame, meta, cal, 1, iters=20)
    # The reconstruction correlates best with the truth at zero shift (registration is right).
    a, b = cube.mean(axis=2)[8:-8, 8:-8], tg.mean(axis=2)
    corr = {}
    for dx in (-2, 0, 2):
        bb = b[8:-8, 8 + dx:b.shape[1] - 8 + dx]
        corr[dx] = np.corrcoef(a.ravel(), bb.ravel())[0, 1]
    assert corr[0] > max(corr[-2], corr[2])


def test_band_offsets_follow_where_the_simulator_puts_each_band(setup):
    """Every band's calibrated offset moves with the mean position of its light (the traced
    maps: pixel column minus the texel column it sees, averaged over the centre view's box and
    the band's wavelength nodes), first and last bands included: their nominal wavelengths sit
    at their intervals' edges, 1.5 px from the mean for 50 nm bands."""
    pipeline, d, cal, frame, meta, truth, wl = setup
    from sim.maps import evaluate, legendre_values
    from sim.pixel_integral import node_weights
    from sim.transport import SEEDS, load_or_build

    v = d.view_size_px
    tr = load_or_build(d, wl, seed=SEEDS["scene"])
    m, k = tr.maps, tr.views.index(0)
    y0, x0, h, w = cal.view_boxes[cal.view_ids.index(0)]
    rows, cols = np.arange(y0, y0 + h) + 0.5, np.arange(x0, x0 + w) + 0.5
    pr = legendre_values((rows - m.norm[k, 0]) / m.norm[k, 1], m.degree)
    pc = legendre_values((cols - m.norm[k, 2]) / m.norm[k, 3], m.degree)
    mean = np.empty(wl.size)
    for l, nodes in enumerate(tr.band_nodes):
        off = 0.0
        for j, wt in zip(nodes, node_weights(len(nodes))):
            tx = (m.relay[k, 0] + m.relay[k, 1] * evaluate(m.mask[k, j, 0], pr, pc)) * v
            off += wt * float(np.mean(cols[None, :] - tx))
        mean[l] = off
    o = cal.offsets[cal.view_ids.index(0)]
    np.testing.assert_allclose(o - o[0], mean - mean[0], atol=0.15)


#: PSNR (dB) at this test size: the 50 nm ``small`` design, the ColorChecker at twice the
#: grid through the scene frames' own trace, FISTA-TV with the pipeline's defaults, measured
#: with the calibration from its own captures and with the exact operator traced with its own
#: seed.  Honest figures: no capture shares the frame's realisation (tests/sim/test_transport.py
#: checks the realisations converge).  A change that moves one by more than TOLERANCE_DB, up or
#: down, must say why (and update these).
FIGURES = {("shifted", 1): 17.31, ("shifted", 5): 26.06, ("footprint", 1): 16.65,
           ("footprint", 5): 30.15, ("oracle", 1): 16.65, ("oracle", 5): 30.28}
TOLERANCE_DB = 0.3


@pytest.fixture(scope="module")
def oracle_psnr(setup):
    pipeline, d, cal, frame, meta, truth, wl = setup
    return {n: pipeline.reconstruct_oracle(frame, meta, d, n, truth=truth)[1]["metrics"]["psnr"]
            for n in (1, 5)}


def test_shifted_model_figures(setup, oracle_psnr):
    pipeline, d, cal, frame, meta, truth, wl = setup
    for n in (1, 5):
        cube, info = pipeline.reconstruct_views(frame, meta, cal, n, truth=truth)
        assert cube.shape == tuple(cal.cube_shape)
        got = info["metrics"]["psnr"]
        assert abs(got - FIGURES[("shifted", n)]) < TOLERANCE_DB, (n, got)
    for n in (1, 5):
        assert abs(oracle_psnr[n] - FIGURES[("oracle", n)]) < TOLERANCE_DB, (n, oracle_psnr[n])


@pytest.fixture(scope="module")
def footprint_cal(setup):
    pipeline, d, *_ = setup
    return pipeline.calibrate(d, progress=False, footprint=True)


def test_footprint_model_is_within_1db_of_the_exact_operator(setup, footprint_cal,
                                                              oracle_psnr):
    """The footprint model, measured with comb captures, reconstructs within 1 dB of the
    converged exact operator with 1 and 5 views at this size (the shifted model trails it by
    4.2 dB at 5 views), and at its measured figures."""
    pipeline, d, cal, frame, meta, truth, wl = setup
    for n in (1, 5):
        cube, info = pipeline.reconstruct_views(frame, meta, footprint_cal, n, truth=truth,
                                                model="footprint")
        assert cube.shape == truth.shape                 # the comb target's grid is the scene's
        got = info["metrics"]["psnr"]
        assert got > oracle_psnr[n] - 1.0, (n, oracle_psnr[n], got)
        assert abs(got - FIGURES[("footprint", n)]) < TOLERANCE_DB, (n, got)


def test_footprint_calibration_is_cached_with_its_own_gains(setup, footprint_cal, cache):
    pipeline, d, cal, *_ = setup
    # The cached file now holds both models; asking without footprints reuses it.
    again = pipeline.calibrate(d, progress=False)
    assert again.has_footprint and again.footprint_data.size == footprint_cal.footprint_data.size
    assert pipeline.model_of(again) == "shifted"            # the default model is unchanged
    g = footprint_cal.footprint_gains
    # The comb captures are divided by the lit texel's radiance: the ColorChecker refit moves
    # the gains by a few % only.
    assert np.all(np.abs(g - 1.0) < 0.1), g
    assert pipeline.grid_offset(d, footprint_cal, "footprint") == (0.0, 0.0)
    assert pipeline.cube_grid(footprint_cal, "footprint") == (d.view_size_px,) * 2
    assert len(pipeline.colorchecker_patches(d, footprint_cal, "footprint")) == 24


def test_bad_input(setup):
    pipeline, d, cal, frame, meta, truth, wl = setup
    with pytest.raises(InputError, match="design"):
        pipeline.reconstruct_views(frame, dict(meta, design_hash="ffffffffffffffff"), cal, 1)
    with pytest.raises(InputError, match="missing"):
        pipeline.reconstruct_views(frame, meta, cal, 9)
    with pytest.raises(InputError):
        pipeline.reconstruct_views(frame, meta, cal, 0)
    with pytest.raises(InputError, match="views"):
        pipeline.parse_views("1,x")
    assert pipeline.parse_views("5,1,1") == (1, 5)
    wide = pipeline.design_for_views(d, 9)
    assert wide.views == tuple(range(9)) and wide.hash != d.hash
    assert pipeline.design_for_views(d, 5) is d


def test_colorchecker_patches_and_their_colour_error(setup):
    pipeline, d, cal, frame, meta, truth, wl = setup
    patches = pipeline.colorchecker_patches(d, cal)
    h, w, _ = cal.cube_shape
    assert len(patches) >= 12
    tg = pipeline.truth_on_grid(truth, d, cal)
    for y, x, ph, pw in patches.values():
        assert 0 <= y and y + ph <= h and 0 <= x and x + pw <= w and ph > 1 and pw > 1
        # The middle half of a patch is flat in the truth: one reflectance under one light.
        block = tg[y:y + ph, x:x + pw]
        assert np.allclose(block, block[0, 0], rtol=1e-3, atol=1e-6)
    boxes = list(patches.values())
    assert pipeline.patch_delta_e2000(tg, tg, boxes, wl) == pytest.approx(0.0, abs=1e-9)
    tinted = tg * np.linspace(0.7, 1.3, tg.shape[2], dtype=np.float32)
    assert pipeline.patch_delta_e2000(tinted, tg, boxes, wl) > 2.0
