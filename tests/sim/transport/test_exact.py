"""The converged transport against the independent references: Mitsuba's path tracer and the
Monte Carlo transport (small design)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.mitsuba


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


@pytest.fixture(scope="module")
def design():
    from sim.optics.design import get_design

    return get_design("small")


def _scene(d, bands, scale=2):
    """Sharp patches, a smooth ramp and single-texel detail at ``scale`` × the view grid."""
    v = d.view_size_px * scale
    y, x = np.mgrid[0:v, 0:v] / v
    a = 0.5 + 0.4 * np.sin(9 * x) * np.cos(7 * y)
    b = 0.2 + 0.7 * (x > 0.43) * (y < 0.61) + 0.1 * ((np.arange(v) % 3) == 0)[None, :]
    return np.stack([a, b][:len(bands)], axis=2).astype(np.float32)


def _window(d, view=0):
    r0, c0, h, w = d.view_rect(view)
    return (r0 + h // 2 - 12, c0 + w // 2 - 12, 24, 24)


def _bias_and_noise(c, a, b):
    """Relative RMS bias of ``c`` against two independent unbiased estimates ``a``, ``b``
    (E[(c−a)(c−b)] is the squared bias: the estimates' noise averages out) and their noise."""
    rms = np.sqrt(np.mean(a * b))
    bias2 = float(np.mean((c - a) * (c - b)))
    noise = float(np.sqrt(np.mean((a - b) ** 2) / 2))
    return np.sign(bias2) * np.sqrt(abs(bias2)) / rms, noise / rms


def test_transport_matches_mitsubas_path_tracer(design):
    """The pixel integrals against Mitsuba rendering the same scene through the instrument
    (stratified, 256 samples per pixel, two seeds): no bias beyond 0.5 % per pixel and band
    (the renders' own noise is ~2 %), the same total within 0.3 %."""
    from sim.optics.render import render_direct
    from sim.transport.exact import load_or_build

    d = design
    wl = d.wavelengths[[2, 8]]
    cube = _scene(d, wl)
    win = _window(d)
    s = np.s_[:, win[0]:win[0] + win[2], win[1]:win[1] + win[3]]
    tr = load_or_build(d, wl, seed=0)
    c = tr.apply(cube)[s].astype(np.float64)
    a, b = (render_direct(d, cube, wl, spp=256, seed=seed, windows=[win], sampler="stratified",
                          progress=False)[s].astype(np.float64) for seed in (3, 4))
    bias, noise = _bias_and_noise(c, a, b)
    assert 0.005 < noise < 0.05              # the references are noisy, but not broken
    assert bias < 0.005, (bias, noise)
    assert abs(c.sum() / (0.5 * (a + b)).sum() - 1) < 0.003


def test_transport_matches_the_sampled_transport_in_the_vignetted_view(design):
    """The left view's outer columns, where the tube's exit cuts the aperture (the analytic
    disc ∩ square of the throughput), against the Monte Carlo transport (Sobol, 256 samples)."""
    from sim.transport import sampled
    from sim.transport.exact import load_or_build

    d = design
    wl = d.wavelengths[[9]]
    cube = _scene(d, wl, scale=1)
    r0, c0, h, w = d.view_rect(1)
    win = (r0 + h // 2 - 12, c0, 24, 24)
    s = np.s_[:, win[0]:win[0] + 24, win[1]:win[1] + 24]
    ref = sampled.build_transport(d, cube.shape[:2], wl, spp=256, sampler="sobol", seed=7,
                                  crop=win).apply(cube)[s].astype(np.float64)
    c = load_or_build(d, wl, seed=0).apply(cube)[s].astype(np.float64)
    tau = load_or_build(d, wl, seed=0).throughput(1, 0)
    assert tau[:, :10].mean() < 0.97 * tau[:, 40:].mean()        # vignetted indeed
    assert np.linalg.norm(c - ref) / np.linalg.norm(ref) < 0.02
    assert abs(c.sum() / ref.sum() - 1) < 0.003


def test_energy_is_conserved_up_to_the_elements_losses(design):
    """A uniform diffuser of radiance 1 at the centre wavelength, open mask: a pixel of the
    centre view (no mirror) receives exactly π/(1+4N²)·T_d·T_quartz·T_prism, in the direct
    render and in the transport alike; the mirrored views receive less (Al reflectance)."""
    from sim.optics.camera import irradiance_factor
    from sim.optics.glass import refractive_index
    from sim.optics.mask import quartz_transmittance
    from sim.optics.render import render_direct
    from sim.transport.exact import load_or_build

    d = design
    lam = d.prism_center_nm
    v = d.view_size_px
    ones = np.ones((v, v, 1), np.float32)
    open_mask = np.ones((d.mask_cells, d.mask_cells), dtype=bool)
    n = float(refractive_index(d.prism_glass, lam))
    A = np.radians(d.prism_apex_deg)
    t1 = np.arcsin(n * np.sin(A / 2))
    t2 = A / 2
    rs = (np.cos(t1) - n * np.cos(t2)) / (np.cos(t1) + n * np.cos(t2))
    rp = (n * np.cos(t1) - np.cos(t2)) / (n * np.cos(t1) + np.cos(t2))
    t_face = 1 - 0.5 * (rs ** 2 + rp ** 2)
    expect = (irradiance_factor(d) * d.diffuser_transmittance * float(quartz_transmittance(lam))
              * t_face ** 2)
    direct = render_direct(d, ones, [lam], spp=2, intervals=[[lam, lam]], mask_pattern=open_mask,
                           progress=False)[0]
    import copy

    tr = copy.copy(load_or_build(d, intervals=[[lam, lam]], seed=0))
    tr.code = np.where(open_mask, d.mask_owner(), -1).astype(np.int8)
    cached = tr.apply(ones)[0]
    r0, c0 = d.code_region_px(0)[:2]
    for img in (direct, cached):
        core = img[r0 + 10:r0 + v - 10, c0 + 10:c0 + v - 30]   # inside the rendered rectangle
        np.testing.assert_allclose(core, expect, rtol=2e-3)
        assert img.max() <= expect * (1 + 2e-3)
        for view in (1, 2, 3, 4):
            r, c, h, w = d.view_rect(view)
            mid = img[r + h // 2 - 10:r + h // 2 + 10, c + w // 2 - 10:c + w // 2 + 10]
            assert 0.8 < float(mid.mean()) / expect < 1.0, view   # one Al reflection: ~0.9


def test_independent_traces_agree(design):
    """Three realisations of the trace (the captures', the scenes' and the oracle's seeds)
    give the same frame to 3·10⁻⁴ (measured ~1·10⁻⁴: the maps' fit of float32 round-off)."""
    from sim.transport.exact import SEEDS, load_or_build

    d = design
    wl = d.wavelengths[[0, 5, 10]]
    cube = _scene(d, wl[:2], scale=1)
    cube = np.concatenate([cube, cube[:, :, :1]], axis=2)
    frames = [load_or_build(d, wl, seed=s).apply(cube).astype(np.float64)
              for s in sorted(SEEDS.values())]
    for a in frames[1:]:
        assert np.linalg.norm(a - frames[0]) / np.linalg.norm(frames[0]) < 3e-4
    assert not np.array_equal(frames[0], frames[1])          # really traced afresh


def test_the_scene_grid_does_not_change_the_integral(design):
    """The same content at the view's grid and repeated 2 × 2 (every texel split in four):
    the pixel integrals are equal, so the integral does not depend on how the scene is cut."""
    from sim.transport.exact import load_or_build

    d = design
    wl = d.wavelengths[[1, 6]]
    rng = np.random.default_rng(3)
    v = d.view_size_px
    cube = rng.random((v, v, 2)).astype(np.float32)
    fine = np.repeat(np.repeat(cube, 2, axis=0), 2, axis=1)
    tr = load_or_build(d, wl, seed=0)
    a, b = tr.apply(cube), tr.apply(fine)
    np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-5 * float(a.max()))


def test_adjoint_of_every_view_and_band(design):
    from sim.transport.exact import load_or_build

    d = design
    tr = load_or_build(d, seed=0)
    rng = np.random.default_rng(0)
    for shape in ((d.view_size_px,) * 2, (2 * d.view_size_px + 3, 2 * d.view_size_px - 5)):
        for k in range(len(tr.views)):
            for l in (0, 5, tr.n_bands - 1):
                f = rng.random(shape).astype(np.float32)
                h, w = (int(x) for x in tr.maps.rects[k][2:])
                e = rng.standard_normal((h, w)).astype(np.float32)
                lhs = np.vdot(tr.view_band(f, k, l).astype(np.float64), e.astype(np.float64))
                rhs = np.vdot(f.astype(np.float64), tr.view_band_adjoint(e, k, l, shape))
                # float32 outputs: a relative 1e-5 is their round-off, a wrong term is O(1).
                assert abs(lhs - rhs) <= 1e-5 * abs(lhs), (shape, k, l)


def test_frames_are_deterministic(design):
    from sim.frame import simulate_frame
    from sim.optics.render import render_direct

    d = design
    wl = d.wavelengths[[3, 6]]
    cube = _scene(d, wl)
    f1, m1 = simulate_frame(d, cube, wl, seed=3)
    f2, m2 = simulate_frame(d, cube, wl, seed=3)
    f3, _ = simulate_frame(d, cube, wl, seed=4)
    np.testing.assert_array_equal(f1, f2)
    assert not np.array_equal(f1, f3)
    assert m1 == m2 and m1["seed"] == 3 and m1["design_hash"] == d.hash
    assert m1["trace_seed"] == 1 and m1["scene_shape"] == list(cube.shape[:2])
    r1 = render_direct(d, cube, wl, spp=1, seed=9, views=(0,), progress=False)
    r2 = render_direct(d, cube, wl, spp=1, seed=9, views=(0,), progress=False)
    np.testing.assert_array_equal(r1, r2)


def test_spp_belongs_to_direct_renders(design):
    from recon.errors import InputError
    from sim.frame import simulate_frame

    d = design
    wl = d.wavelengths[[3]]
    with pytest.raises(InputError, match="direct"):
        simulate_frame(d, _scene(d, wl), wl, spp=4)


def test_cache_is_written_once_and_reused(design, tmp_path, monkeypatch):
    from sim.transport import exact as transport

    monkeypatch.setenv("KALEIDOSPEC_CACHE", str(tmp_path))
    monkeypatch.setattr(transport, "_MEMO", {})
    d = design
    wl = d.wavelengths[[1]]
    cube = _scene(d, wl)
    built = transport.STATS["built"]
    a = transport.render_cached(d, cube, wl)
    assert transport.STATS["built"] == built + 1
    files = list(tmp_path.glob(f"maps-{d.hash}-*.npz"))
    assert len(files) == 1
    assert not list(tmp_path.glob(".*tmp*"))  # the atomic write left no temporary file
    transport._MEMO.clear()  # a new process: only the file remains
    loaded = transport.STATS["loaded"]
    b = transport.render_cached(d, cube, wl)
    assert transport.STATS["built"] == built + 1  # not traced again
    assert transport.STATS["loaded"] == loaded + 1
    np.testing.assert_array_equal(a, b)
    # Another seed or another design is another cache entry.
    transport.render_cached(d, cube, wl, seed=5)
    transport.render_cached(d.replace(mask_seed=1), cube, wl)
    assert transport.STATS["built"] == built + 3
    with np.load(files[0], allow_pickle=False) as z:  # plain arrays, no pickle
        assert str(z["design_hash"]) == d.hash
    # A damaged file is traced again, not trusted.
    transport._MEMO.clear()
    files[0].write_bytes(b"not a zip")
    np.testing.assert_array_equal(transport.render_cached(d, cube, wl), a)


def test_bad_cube_is_rejected(design):
    from recon.errors import InputError
    from sim.bands import check_cube

    d = design
    v = d.view_size_px
    with pytest.raises(InputError):
        check_cube(d, np.ones((v, v, 2), np.float32), [500.0])
    with pytest.raises(InputError):
        check_cube(d, np.full((v, v, 1), np.nan, np.float32), [500.0])
    with pytest.raises(InputError):
        check_cube(d, np.ones((v, v, 1), np.float32), [510.0])  # not a band of the design


@pytest.mark.parametrize("cpus", [{0}, {0, 1}])
def test_threads_follow_the_cpus_the_process_may_use(monkeypatch, cpus):
    """A process held to one CPU (``taskset``, a batch scheduler's cpuset) runs the frame's
    items in its own thread, not two threads time-slicing one CPU; with two, on two threads."""
    import os
    import threading

    from sim.transport.exact import each, ordered_sum

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(cpus), raising=False)
    seen = []

    def work(i):
        seen.append(threading.get_ident())
        return np.full(3, float(i))

    each(work, range(6))
    out = ordered_sum(work, range(6), np.zeros(3))
    assert np.array_equal(out, np.full(3, 15.0))
    own = threading.get_ident()
    if len(cpus) == 1:
        assert set(seen[:6]) == {own}
        assert len(set(seen[6:])) == 1
    else:
        assert own not in seen


@pytest.mark.parametrize("h, workers", [(900, 2), (900, 1), (900, 3), (97, 2), (5, 4), (1, 2)])
def test_row_blocks_cover_the_rows_once_in_equal_shares(h, workers):
    """Every row in exactly one block, in order; blocks of at most 48 rows and within a row of
    each other; as many as a multiple of the threads wherever there are rows enough."""
    from sim.transport.exact import row_blocks

    blocks = row_blocks(h, workers)
    assert [r for a, b in blocks for r in range(a, b)] == list(range(h))
    sizes = [b - a for a, b in blocks]
    assert max(sizes) <= 48 and max(sizes) - min(sizes) <= 1
    if h >= workers:
        assert len(blocks) % workers == 0


def test_release_drops_the_transports_asked_for(monkeypatch):
    """By key (what a step added), by trace realisation, or all; unknown keys are ignored."""
    from types import SimpleNamespace

    from sim.transport import exact

    def fake(seed):
        return SimpleNamespace(maps=SimpleNamespace(seed=seed))

    monkeypatch.setattr(exact, "_MEMO", {"a": fake(0), "b": fake(1), "c": fake(1), "d": fake(2)})
    assert exact.held() == {"a", "b", "c", "d"}
    exact.release(keys={"a", "gone"})
    assert exact.held() == {"b", "c", "d"}
    exact.release(seed=1)
    assert exact.held() == {"d"}
    exact.release()
    assert exact.held() == set()
