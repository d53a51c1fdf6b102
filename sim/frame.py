"""Glue: scene cube → per-band sensor irradiance (optics) → raw frame (sensor) → files.

:func:`simulate_frame` renders the optics with the transport cache (default) or the direct
path tracer, hands the per-band irradiance to :func:`sim.sensor.capture` (Airy blur per band,
QE, shot and read noise, 12-bit ADC) and returns the raw frame in DN with its metadata.
:func:`write_frame` writes ``raw.exr`` + its JSON sidecar through :mod:`recon.io.raw` and the
ground truth: the scene cube on the reconstruction grid of the centre view (the view's
``view_size_px`` square, cube row 0 at the top of the centre view, column 0 at its left; the
cube is placed so that one grid pixel is one sensor pixel of the centre view at the centre band).

Exposure: scene cubes are in relative radiance, so unless ``radiance_scale`` is given the
frame is exposed so that the brightest pixel's expected charge is ``auto_exposure`` of the full
well; the scale actually used (radiance units per cube unit) is recorded in the sidecar, and
passing it back as ``radiance_scale`` reproduces the same exposure for other scenes (e.g. a
calibration capture and the scene it calibrates).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.errors import InputError

__all__ = ["ground_truth", "simulate_frame", "write_frame", "monochromatic_irradiance"]


def ground_truth(design, cube) -> np.ndarray:
    """The cube (H, W, L) resampled onto the centre view's grid (v, v, L), float32.

    Each cube pixel covers an equal part of the centre view (:func:`sim.diffuser.cube_region`),
    so this is an area resize (identity when the cube is already v × v).
    """
    v = design.view_size_px
    c = np.asarray(cube, dtype=np.float32)
    if c.shape[:2] == (v, v):
        return c
    from skimage.transform import resize

    return resize(c, (v, v, c.shape[2]), order=1, anti_aliasing=True,
                  preserve_range=True).astype(np.float32)


def monochromatic_irradiance(design, cube, wavelengths, wavelength_nm: float, *,
                             direct: bool = False, spp: int = 4, seed: int = 0,
                             progress: bool = False) -> tuple[np.ndarray, int]:
    """Irradiance (1, Hs, Ws) of a monochromatic capture at ``wavelength_nm``.

    The scene's radiance at λ is that of the band containing λ (the cube is piecewise constant
    in λ). Returns the image and the band index used.
    """
    wl = np.asarray(wavelengths, dtype=np.float64)
    lam = float(wavelength_nm)
    if not np.isfinite(lam) or lam < design.filter_min_nm or lam > design.filter_max_nm:
        raise InputError(
            f"wavelength {wavelength_nm} nm is outside the design's pass band "
            f"{design.filter_min_nm:g}–{design.filter_max_nm:g} nm"
        )
    from sim.diffuser import band_edges

    e = band_edges(wl, design)
    l = int(np.clip(np.searchsorted(e, lam, side="right") - 1, 0, wl.size - 1))
    c = np.ascontiguousarray(np.asarray(cube, dtype=np.float32)[:, :, l:l + 1])
    if direct:
        from sim.render import render_direct

        img = render_direct(design, c, [lam], spp=spp, seed=seed, intervals=[[lam, lam]],
                            progress=progress)
    else:
        from sim.transport import load_or_build

        tr = load_or_build(design, c.shape[:2], [lam], spp=spp, seed=0, sampling="centre",
                           progress=progress)
        img = tr.apply(c)
    return img, l


def simulate_frame(design, cube, wavelengths, *, direct: bool = False, spp: int | None = None,
                   seed: int = 0, sampling: str = "box", wavelength_nm: float | None = None,
                   diffraction: bool = True, noise: bool = True, auto_exposure: float = 0.8,
                   radiance_scale: float | None = None, progress: bool = False):
    """Render one raw frame.

    Parameters
    ----------
    design : sim.design.Design
    cube : ndarray (H, W, L)
        Scene radiance at ``wavelengths`` (bands of the design).
    direct : bool
        Use Mitsuba's path tracer (slow reference) instead of the transport cache.
    spp : int, optional
        Samples per pixel per band (default 4 cached, 16 direct). The transport cache is traced
        with seed 0 whatever ``seed`` is, so frames with different seeds share it.
    seed : int
        Sensor noise seed (and the direct render's sampler seed); same seed → same frame.
    sampling : {"box", "centre"}
        Wavelengths within each band (:func:`sim.transport.band_intervals`).
    wavelength_nm : float, optional
        Monochromatic capture at this wavelength (calibration) instead of the full spectrum.
    diffraction, noise : bool
        Airy blur per band; shot + read noise.
    auto_exposure : float
        Fraction of the full well for the brightest pixel when ``radiance_scale`` is None.
    radiance_scale : float, optional
        Multiply the cube by this (its radiance units) instead of auto-exposing.

    Returns
    -------
    frame : ndarray (Hs, Ws) float32, DN
    metadata : dict
        JSON-ready: design, hash, exposure, wavelengths, seed, method, radiance scale, views.
    """
    from sim import sensor
    from sim.render import check_cube, render_direct
    from sim.transport import render_cached

    spp = int(spp if spp is not None else (16 if direct else 4))
    if spp < 1:
        raise InputError(f"spp must be at least 1, got {spp}")
    cube, wl = check_cube(design, cube, wavelengths)
    if wavelength_nm is not None:
        irr, l = monochromatic_irradiance(design, cube, wl, wavelength_nm, direct=direct,
                                          spp=spp, seed=seed, progress=progress)
        bands_wl = np.array([float(wavelength_nm)])
    else:
        if direct:
            irr = render_direct(design, cube, wl, spp=spp, seed=seed, sampling=sampling,
                                progress=progress)
        else:
            irr = render_cached(design, cube, wl, spp=spp, sampling=sampling, progress=progress)
        bands_wl = wl
    e = np.moveaxis(irr, 0, 2)  # (Hs, Ws, L) view, no copy
    ne = sensor.mean_electrons(e, design, bands_wl, diffraction=diffraction)
    # FFT convolution leaves round-off around zero (|x| ~ 1e-9 of the peak); charge is ≥ 0.
    np.maximum(ne, 0.0, out=ne)
    if radiance_scale is None:
        peak = float(ne.max())
        if peak <= 0:
            raise InputError("the scene is dark: no light reaches the sensor")
        radiance_scale = auto_exposure * design.full_well_e / peak
    ne *= np.float32(radiance_scale)
    frame = sensor.digitise(ne, design, seed=seed, noise=noise)
    meta = {
        "kind": "kaleidospec raw frame",
        "units": "DN",
        "design": design.to_dict(),
        "design_hash": design.hash,
        "exposure_ms": design.exposure_ms,
        "wavelengths_nm": [float(x) for x in bands_wl],
        "band_wavelengths_nm": [float(x) for x in design.wavelengths],
        "monochromatic_nm": None if wavelength_nm is None else float(wavelength_nm),
        "seed": int(seed),
        "method": "direct" if direct else "transport",
        "spp": spp,
        "band_sampling": "centre" if wavelength_nm is not None else sampling,
        "diffraction": bool(diffraction),
        "noise": bool(noise),
        "radiance_scale": float(radiance_scale),
        "views": list(design.views),
        "view_rects": {str(k): list(v) for k, v in design.view_rects().items()},
        "sensor_shape": [design.sensor_height_px, design.sensor_width_px],
    }
    return frame, meta


def write_frame(out, frame, metadata, design=None, cube=None, wavelengths=None, *,
                protect=()) -> dict:
    """Write ``out`` (``.exr``) + sidecar, and ``<stem>_gt.npz`` (the ground truth) when a
    cube is given. Returns the written paths."""
    from recon.io.cubes import write_cube
    from recon.io.raw import write_raw

    out = Path(out)
    paths = {}
    exr, side = write_raw(out, frame, metadata, protect=protect)
    paths["raw"], paths["sidecar"] = exr, side
    if cube is not None and design is not None:
        gt = out.with_name(out.stem + "_gt.npz")
        write_cube(gt, ground_truth(design, cube), wavelengths, protect=protect)
        paths["ground_truth"] = gt
    return paths
