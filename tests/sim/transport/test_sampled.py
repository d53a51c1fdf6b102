"""The Monte Carlo (sampled) transport: its samplers, its cache, and its draw."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.mitsuba


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    from sim.transport import sampled

    monkeypatch.setenv("KALEIDOSPEC_CACHE", str(tmp_path))
    sampled._MEMO.clear()
    yield tmp_path
    sampled._MEMO.clear()


@pytest.fixture(scope="module")
def design():
    from sim.optics.design import get_design

    return get_design("small")


def _scene(d, bands):
    """A smooth, spatially and spectrally varying cube on two bands."""
    v = d.view_size_px
    y, x = np.mgrid[0:v, 0:v] / v
    a = 0.5 + 0.4 * np.sin(6 * x) * np.cos(4 * y)
    b = 0.3 + 0.6 * (x > 0.4) * (y < 0.7)
    return np.stack([a, b][:len(bands)], axis=2).astype(np.float32)


def test_sobol_sampler_is_closer_to_the_converged_frame_than_independent(design, cache):
    """Stratified (randomised QMC) samples estimate each pixel's integral better than i.i.d.
    ones at the same count: the frame of a 16-sample Sobol trace is nearer a 256-sample
    reference than an independent 16-sample trace (by more than 15 %), and both are unbiased
    (same total)."""
    from sim.transport.sampled import load_or_build

    d = design
    wl = d.wavelengths[[2, 8]]
    cube = _scene(d, wl)
    r0, c0 = d.view_rect(0)[:2]
    crop = (r0 + 20, c0 + 30, 48, 48)
    win = np.s_[:, crop[0]:crop[0] + crop[2], crop[1]:crop[1] + crop[3]]

    def frame(spp, sampler, seed):
        tr = load_or_build(d, cube.shape[:2], wl, spp=spp, sampler=sampler, seed=seed,
                           crop=crop, use_disk=False)
        return tr.apply(cube)[win].astype(np.float64)

    ref = frame(256, "sobol", seed=99)
    err = {}
    for sampler in ("independent", "sobol"):
        e = [frame(16, sampler, seed=s) for s in (0, 1)]
        err[sampler] = np.mean([np.linalg.norm(x - ref) / np.linalg.norm(ref) for x in e])
        for x in e:
            assert abs(x.sum() / ref.sum() - 1) < 0.01
    assert err["sobol"] < 0.85 * err["independent"], err


def test_sobol_sampler_is_deterministic_and_keyed_apart(design, cache):
    from recon.errors import InputError
    from sim.transport import sampled as transport

    d = design
    wl = d.wavelengths[[4]]
    cube = _scene(d, wl)
    r0, c0 = d.view_rect(0)[:2]
    crop = (r0 + 40, c0 + 40, 24, 24)
    a = transport.render_cached(d, cube, wl, spp=4, sampler="sobol", crop=crop)
    transport._MEMO.clear()
    b = transport.build_transport(d, cube.shape[:2], wl, spp=4, sampler="sobol", crop=crop)
    np.testing.assert_array_equal(a, b.apply(cube))
    c = transport.render_cached(d, cube, wl, spp=4, sampler="independent", crop=crop)
    assert not np.array_equal(a, c)
    assert len(list(cache.glob(f"sampled-{d.hash}-*.npz"))) == 2
    with pytest.raises(InputError, match="sampler"):
        transport.render_cached(d, cube, wl, spp=4, sampler="halton", crop=crop)


def test_sobol_samples_are_stratified_in_every_dimension():
    """Each pixel's 4 samples fall one in each quarter of every coordinate (after the
    pixel's toroidal shift, on the shifted grid)."""
    from sim.transport.sampled import pixel_samples

    n, spp = 50, 4
    draw = pixel_samples(n, spp, "sobol", np.random.default_rng(0))
    u = draw(np.arange(n * spp)).reshape(5, n, spp)
    assert u.min() >= 0 and u.max() < 1
    # Stratified on a grid shifted by t: some t in [0, 1/4) puts one sample in each quarter.
    t = np.linspace(0, 0.25, 501, endpoint=False)[:, None, None, None]
    q = np.floor(((u[None] - t) % 1.0) * spp).astype(int)                  # (T, 5, n, spp)
    distinct = np.sort(q, axis=-1)
    ok = np.all(np.diff(distinct, axis=-1) > 0, axis=-1).any(axis=0)        # (5, n)
    assert ok.all(), np.argwhere(~ok)[:5]
    # Independent samples are not: most pixels have two samples in one quarter.
    v = pixel_samples(n, spp, "independent", np.random.default_rng(0))(np.arange(n * spp))
    q = np.floor(((v.reshape(5, n, spp)[None] - t) % 1.0) * spp).astype(int)
    strat = np.all(np.diff(np.sort(q, axis=-1), axis=-1) > 0, axis=-1).any(axis=0)
    assert strat.mean() < 0.5
