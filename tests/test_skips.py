"""What kaleidospec skips when a scene does not need it (docs/skips.md), each skip checked by
counting the work done, not by timing it: a test fails if the skip stops happening.

- a frame integrates and blurs only the bands with light (a band-pass capture: one band);
- the exact operator integrates only the views whose blurred light reaches a measured pixel,
  forward and adjoint;
- a solve stops once its stopping rule holds, and spends no operator work after that;
- diffraction within a pixel is neither deconvolved in the calibration nor modelled by a PSF.

The page's figures (the time each skip saves) come from ``tools/bench_skips.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from cases import piecewise_cube


def _three_bands(shape, n_bands, bands):
    """(H, W, L): a square of light in ``bands`` over black."""
    h, w = shape
    cube = np.zeros((h, w, n_bands), np.float32)
    cube[h // 3:2 * h // 3, w // 3:2 * w // 3, list(bands)] = 1.0
    return cube


@pytest.fixture(scope="module")
def frames(shared_cache):
    """The `small` design's frame model (its scene frames' trace)."""
    pytest.importorskip("mitsuba")
    from kaleidospec.instrument import FrameRenderer
    from sim.design import get_design
    from sim.frame import scene_grid

    d = get_design("small")
    return FrameRenderer(d, scene_grid(d, "natural"))


@pytest.mark.parametrize("bands", [(2, 5, 8), (4,)], ids=["three bands", "a band-pass capture"])
def test_a_frame_integrates_and_blurs_only_the_bands_with_light(frames, bands, monkeypatch):
    from sim.sensor import BlurredSum
    from sim.transport import Transport

    d = frames.design
    cube = _three_bands(frames.shape, d.wavelengths.size, bands)
    integrated, blurred = [], []
    view_blocks, spectrum = Transport.view_blocks, BlurredSum.spectrum

    def counting_blocks(self, f, k, bands=None, out=None):
        integrated.append((k, list(bands), f.shape[2]))
        return view_blocks(self, f, k, bands, out)

    def counting_spectrum(self, images, bands, *args, **kw):
        blurred.append(list(bands))
        return spectrum(self, images, bands, *args, **kw)

    monkeypatch.setattr(Transport, "view_blocks", counting_blocks)
    monkeypatch.setattr(BlurredSum, "spectrum", counting_spectrum)
    frame = frames.electrons(cube)
    n_views = len(frames.model.transport.maps.rects)
    # Every view integrated, each with the lit bands alone (the cube handed over holds only them).
    assert sorted(k for k, _, _ in integrated) == list(range(n_views))
    assert all(b == list(bands) and n == len(bands) for _, b, n in integrated)
    # Only lit bands are blurred.
    assert blurred and all(b == list(bands) for b in blurred)
    # The skip changes nothing: the same frame with the dark bands lit by 1e-30 (which makes
    # them count as lit) is the same to float32's resolution.
    monkeypatch.setattr(Transport, "view_blocks", view_blocks)
    monkeypatch.setattr(BlurredSum, "spectrum", spectrum)
    lit = cube.copy()
    lit[0, 0, [l for l in range(d.wavelengths.size) if l not in bands]] = 1e-30
    np.testing.assert_allclose(frame, frames.electrons(lit), rtol=0, atol=1e-6 * frame.max())


def test_a_dark_scene_integrates_nothing(frames, monkeypatch):
    from sim.transport import Transport

    calls = []
    monkeypatch.setattr(Transport, "view_blocks", lambda *a, **k: calls.append(a))
    cube = np.zeros(frames.shape + (frames.design.wavelengths.size,), np.float32)
    assert not frames.electrons(cube).any()
    assert calls == []


@pytest.mark.parametrize("diffraction", [False, True], ids=["no blur", "Airy blur"])
def test_the_exact_operator_integrates_only_the_views_that_reach_a_measured_pixel(
        shared_cache, diffraction, monkeypatch):
    pytest.importorskip("mitsuba")
    from sim.design import get_design
    from sim.oracle import oracle_operator

    d = get_design("small")
    op = oracle_operator(d, 1, diffraction=diffraction)
    n_traced = len(op.all_rects)
    if not diffraction:
        assert op.lit_views == [0]        # no blur: the centre's light alone reaches the centre
    assert len(op.lit_views) < n_traced
    tr = op.tr
    seen = {"forward": set(), "adjoint": set()}
    view_band, view_band_adjoint = type(tr).view_band, type(tr).view_band_adjoint

    def counting_forward(self, f, k, l, out=None):
        seen["forward"].add(k)
        return view_band(self, f, k, l, out)

    def counting_adjoint(self, e, k, l, *args, **kw):
        seen["adjoint"].add(k)
        return view_band_adjoint(self, e, k, l, *args, **kw)

    monkeypatch.setattr(type(tr), "view_band", counting_forward)
    monkeypatch.setattr(type(tr), "view_band_adjoint", counting_adjoint)
    x = np.ascontiguousarray(np.moveaxis(_three_bands(op.ishape[1:], op.ishape[0], (2, 5, 8)),
                                         2, 0))
    y = op.forward(x)
    op.adjoint(y)
    assert seen["forward"] == set(op.lit_views)
    assert seen["adjoint"] <= set(op.lit_views) and 0 in seen["adjoint"]


def _counting(op, calls):
    """``op`` with every application (forward, adjoint and their fused variants) counted in
    ``calls``: the instance's own methods wrapped, so the solvers' fast paths still run."""
    for name in ("forward", "adjoint", "adjoint_add", "adjoint_gather"):
        method = getattr(op, name, None)
        if method is None:
            continue

        def counted(*a, _method=method, **k):
            calls.append(1)
            return _method(*a, **k)

        setattr(op, name, counted)
    return op


@pytest.mark.parametrize("solver", ["fista-tv", "twist", "gap-tv"])
def test_a_converged_solve_stops_and_does_no_more_work(solver):
    from recon.operators import standard_cassi
    from recon.solvers import solve

    x = piecewise_cube(l=8, h=32, w=32)
    mask = (np.random.default_rng(1).random((32, 32)) < 0.5).astype(np.float32)
    g = standard_cassi(mask, 1, 8).forward(x)

    def run(iters, tol):
        calls = []
        op = _counting(standard_cassi(mask, 1, 8), calls)
        return solve(solver, op, g, iters=iters, tau=0.01, tol=tol), len(calls)

    res, calls = run(400, 1e-3)
    assert res.converged and res.iterations < 400
    # It costs what a solve of that many iterations costs, and less than running on.
    assert calls == run(res.iterations, None)[1]
    assert calls < run(400, None)[1]


def test_diffraction_within_a_pixel_is_neither_deconvolved_nor_modelled(monkeypatch):
    """Where every band's Airy radius stays inside a pixel (``small``) the calibration does not
    deconvolve its mask images and the calibrated model carries no PSF (no blur a solve
    iteration)."""
    import dataclasses

    import recon.calibration.mask as mask
    from calibrations import three_view_calibration
    from kaleidospec.calibrate import deconvolution_radii
    from recon.calibration import airy_kernel
    from recon.calibration.operator import operator_from_calibration
    from recon.operators.blur import BlurredOperator
    from sim.design import get_design

    assert deconvolution_radii(get_design("small")) is None
    assert deconvolution_radii(get_design("paper")) is not None
    # No radius: none of the deconvolutions runs.
    for name in ("tv_deconvolve", "wiener_deconvolve", "deconvolve"):
        monkeypatch.setattr(mask, name, lambda *a, _n=name, **k: pytest.fail(f"{_n} ran"))
    whites = np.ones((2, 20, 30), np.float32)
    views = mask.white_views(whites, [(0, 0, 20, 30)], airy_radius=None)
    assert views.shape == (1, 2, 20, 30)
    # No PSF: the calibrated model is not wrapped in a blur.
    rng = np.random.default_rng(0)
    cal = three_view_calibration((rng.random((3, 4, 12, 40)) < 0.5).astype(np.float32))
    assert cal.psf is None
    assert not isinstance(operator_from_calibration(cal, (0, 1, 2)), BlurredOperator)
    blurred = dataclasses.replace(cal, psf=airy_kernel(1.2))         # what `paper` carries
    assert isinstance(operator_from_calibration(blurred, (0, 1, 2)), BlurredOperator)
