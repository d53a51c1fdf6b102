"""The direct (reference) render: Mitsuba renders the scene through the whole optical system.

For each band *l* inside the filter's pass band and each used view, the scene (diffuser
emitting the cube, mirrors, lenses, mask, prism) is rendered with Mitsuba's ``path``
integrator through a ``specfilm`` whose response is a box on the band's wavelength interval
(:func:`sim.bands.band_intervals`), cropped to the view's sensor rectangle. ``specfilm``
records :math:`\\int L(\\lambda) r(\\lambda)\\, d\\lambda`; dividing by the box width gives the
band's mean radiance through the aperture, and :func:`sim.camera.irradiance_factor` turns that
into sensor irradiance.  The integrator is ``kaleidospec_path`` (:func:`sim.rays.register_integrator`):
Mitsuba's backward path tracing through the delta interactions, continued along the ray instead
of with ``spawn_ray``'s sideways step, which defocuses the optics by up to 1.4 px on ``paper``
(``integrator="mitsuba"`` renders with Mitsuba's own ``path`` integrator, artefact included, to
show it).  ``sampler="stratified"`` draws each pixel's samples from Mitsuba's ``multijitter``
sampler (stratified over the pixel, the aperture and the band) for a faster-converging
reference.

This is slow (~1 M samples/s on 2 cores) and exists to check the transport cache
(:mod:`sim.transport`) and for one-off monochromatic captures.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError

__all__ = ["render_direct"]


def render_direct(design, cube, wavelengths, spp: int = 16, seed: int = 0, *,
                  sampling: str = "box", intervals=None, views=None, crop=None,
                  lenses: str = "thin", mask_pattern=None, windows=None,
                  integrator: str = "exact", sampler: str = "independent",
                  progress: bool = True) -> np.ndarray:
    """Per-band sensor irradiance (L, Hs, Ws) float32 from Mitsuba's path tracer.

    Parameters
    ----------
    design : sim.design.Design
    cube : ndarray (H, W, L)
        Spectral radiance of the scene on the diffuser (before its transmittance).
    wavelengths : array_like (L,)
        The cube's band centres: bands of the design.
    spp : int
        Samples per pixel per band.
    seed : int
        Sampler seed (band *l* uses ``seed + l``); same seed, same image.
    sampling : {"box", "centre"}
        Wavelengths of each band: the whole band or its centre (:func:`band_intervals`).
    intervals : ndarray (L, 2), optional
        Explicit wavelength interval per band (overrides ``sampling``; monochromatic captures).
    views : sequence of int, optional
        Views to render (default ``design.views``); other pixels stay 0.
    crop : (row0, col0, h, w), optional
        Further restrict rendering to this window.
    lenses : {"thin", "real"}
        Lens model (:func:`sim.scene.build_scene`).
    windows : list of (row0, col0, h, w), optional
        Render exactly these sensor windows instead of the views' rectangles.
    mask_pattern : ndarray of bool, optional
        Replace ``design.mask_pattern()`` (e.g. all open, to image a target without coding).
    integrator : {"exact", "mitsuba"}
        ``kaleidospec_path`` (default) or Mitsuba's own ``path`` (module notes).
    sampler : {"independent", "stratified"}
        Mitsuba's ``independent`` or ``multijitter`` sampler.
    """
    from sim.bands import band_intervals, check_cube
    from sim.camera import band_response, irradiance_factor
    from sim.scene import build_scene
    from sim.variant import ensure_variant

    samplers = {"independent": "independent", "stratified": "multijitter"}
    if integrator not in ("exact", "mitsuba"):
        raise InputError(f"integrator must be 'exact' or 'mitsuba', got {integrator!r}")
    if sampler not in samplers:
        raise InputError(f"sampler must be 'independent' or 'stratified', got {sampler!r}")
    if intervals is None:
        cube, wl = check_cube(design, cube, wavelengths)
        iv = band_intervals(design, wl, sampling)
    else:
        c = np.asarray(cube, dtype=np.float32)
        cube = c[:, :, None] if c.ndim == 2 else c
        wl = np.atleast_1d(np.asarray(wavelengths, dtype=np.float64))
        iv = np.asarray(intervals, dtype=np.float64).reshape(-1, 2)
    mi = ensure_variant()
    spec = build_scene(design, np.ascontiguousarray(np.moveaxis(cube, 2, 0)), wl, lenses=lenses,
                       mask_pattern=mask_pattern)
    if integrator == "exact":
        from sim.rays import register_integrator

        spec.scene["integrator"] = {"type": register_integrator(),
                                    "max_depth": spec.scene["integrator"]["max_depth"]}
    scene = mi.load_dict(spec.scene)
    Hs, Ws = design.sensor_height_px, design.sensor_width_px
    out = np.zeros((wl.size, Hs, Ws), dtype=np.float32)
    rects = [tuple(int(x) for x in w) for w in windows] if windows is not None else []
    for v in (() if windows is not None else design.views if views is None else views):
        r0, c0, h, w = design.view_rect(v)
        r1, c1 = min(r0 + h, Hs), min(c0 + w, Ws)
        r0, c0 = max(r0, 0), max(c0, 0)
        if crop is not None:
            r0, c0 = max(r0, crop[0]), max(c0, crop[1])
            r1, c1 = min(r1, crop[0] + crop[2]), min(c1, crop[1] + crop[3])
        if r1 > r0 and c1 > c0:
            rects.append((r0, c0, r1 - r0, c1 - c0))
    k = irradiance_factor(design)
    bands = [l for l in range(wl.size)
             if design.filter_min_nm <= wl[l] <= design.filter_max_nm]
    it = bands
    if progress:
        from recon.progress import progress_bar

        it = progress_bar(bands, desc="render", unit="band", leave=True)
    for l in it:
        lo, hi = float(iv[l, 0]), float(iv[l, 1])
        resp = band_response(lo, hi)
        width = resp["wavelength_max"] - resp["wavelength_min"]
        for (r0, c0, h, w) in rects:
            cam = mi.load_dict(spec.camera(design, film={"type": "specfilm", "band": resp},
                                           crop=(r0, c0, h, w), seed=seed + l, spp=spp,
                                           sampler=samplers[sampler]))
            img = mi.render(scene, sensor=cam, spp=int(spp), seed=int(seed) * 1000 + l)
            out[l, r0:r0 + h, c0:c0 + w] = np.asarray(img, dtype=np.float32)[:, :, 0] * (k / width)
    return out
