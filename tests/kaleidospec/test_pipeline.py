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
    """Every band's calibrated offset moves with the mean position of its light (the
    transport's own pixel - texel column, centre view), first and last bands included: their
    nominal wavelengths sit at their intervals' edges, 1.5 px from the mean for 50 nm bands."""
    pipeline, d, cal, frame, meta, truth, wl = setup
    from sim.transport import load_or_build

    v = d.view_size_px
    tr = load_or_build(d, (v, v), wl)
    y0, x0, h, w = cal.view_boxes[cal.view_ids.index(0)]
    mean = np.empty(wl.size)
    for l in range(wl.size):
        py, px = np.divmod(tr.pix[l].astype(np.int64), tr.sensor[1])
        keep = (py >= y0) & (py < y0 + h) & (px >= x0) & (px < x0 + w)
        tx = tr.tex[l][keep] % v
        mean[l] = np.average(px[keep] - tx, weights=tr.w[l][keep])
    o = cal.offsets[cal.view_ids.index(0)]
    np.testing.assert_allclose(o - o[0], mean - mean[0], atol=0.15)


def test_more_views_reconstruct_better(setup):
    pipeline, d, cal, frame, meta, truth, wl = setup
    res = {}
    for n in (1, 5):
        cube, info = pipeline.reconstruct_views(frame, meta, cal, n, truth=truth)
        assert cube.shape == tuple(cal.cube_shape)
        res[n] = info["metrics"]["psnr"]
    assert res[5] > res[1]
    flat = np.full_like(info["truth_grid"], info["truth_grid"].mean())
    from recon.metrics import psnr

    assert res[1] > psnr(flat, info["truth_grid"]) + 3


#: Measured on this design and frame (FISTA-TV, the pipeline's defaults, 5 views): the exact
#: operator reaches 36.6 dB, the calibrated one 25.7 dB.  The exact operator is the transport
#: the frame was rendered with, so it knows which texel and wavelength each of a pixel's 4 rays
#: met; the same optics traced with another seed reach 17.1 dB (see the next test).  The margin
#: is the measured gap plus 1 dB: a regression guard, not a target.
ORACLE_MARGIN_DB = 12.0


def test_calibrated_is_within_a_margin_of_the_oracle(setup):
    pipeline, d, cal, frame, meta, truth, wl = setup
    _, info = pipeline.reconstruct_views(frame, meta, cal, 5, truth=truth)
    _, oinfo = pipeline.reconstruct_oracle(frame, meta, d, 5, truth=truth)
    gap = oinfo["metrics"]["psnr"] - info["metrics"]["psnr"]
    assert gap < ORACLE_MARGIN_DB, (oinfo["metrics"]["psnr"], info["metrics"]["psnr"])


def test_calibrated_is_within_1db_of_the_retraced_exact_operator(setup):
    """The exact operator traced with another seed has the instrument's optics but not this
    frame's Monte Carlo draw (which texel and wavelength each of a pixel's 4 rays met).  At
    the instrument's 4 rays it carries its own draw's error (0.24 relative per band and pixel,
    ``tools/bench_sampler.py``), so it is not the converged physics (on `small`, a 32-sample Sobol
    trace reconstructs the ColorChecker 2.3 dB better than calibration; README), but it is
    what any operator traced like the instrument reaches: calibration must stay within 1 dB."""
    pipeline, d, cal, frame, meta, truth, wl = setup
    _, info = pipeline.reconstruct_views(frame, meta, cal, 5, truth=truth)
    op = pipeline.oracle_operator(d, 5, seed=1)
    _, oinfo = pipeline.reconstruct_oracle(frame, meta, d, 5, truth=truth, op=op)
    assert info["metrics"]["psnr"] > oinfo["metrics"]["psnr"] - 1.0, \
        (oinfo["metrics"]["psnr"], info["metrics"]["psnr"])


@pytest.fixture(scope="module")
def footprint_cal(setup):
    pipeline, d, *_ = setup
    return pipeline.calibrate(d, progress=False, footprint=True)


def test_footprint_model_is_within_1db_of_the_exact_operator(setup, footprint_cal):
    """The issue's target: the footprint model, measured with comb captures, reconstructs within
    1 dB of the exact operator (the transport the frame was rendered with) with 1 and 5 views,
    where the shifted model trails it by ~11 dB at 5 views (ORACLE_MARGIN_DB)."""
    pipeline, d, cal, frame, meta, truth, wl = setup
    for n in (1, 5):
        cube, info = pipeline.reconstruct_views(frame, meta, footprint_cal, n, truth=truth,
                                                model="footprint")
        assert cube.shape == truth.shape                 # the comb target's grid is the scene's
        assert info["truth_grid"] is truth or np.array_equal(info["truth_grid"], truth)
        _, oinfo = pipeline.reconstruct_oracle(frame, meta, d, n, truth=truth)
        assert info["metrics"]["psnr"] > oinfo["metrics"]["psnr"] - 1.0, \
            (n, oinfo["metrics"]["psnr"], info["metrics"]["psnr"])


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
