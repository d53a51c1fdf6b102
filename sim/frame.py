"""Glue: scene cube → per-band sensor irradiance (optics) → raw frame (sensor) → files.

:func:`simulate_frame` renders the optics with the transport's exact pixel integrals
(:class:`FrameModel`, the default) or Mitsuba's path tracer (a Monte Carlo reference), applies
the sensor (Airy blur per band, QE, shot and read noise, 12-bit ADC, :mod:`sim.sensor`) and
returns the raw frame in DN with its metadata.
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

import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from recon.errors import InputError

__all__ = ["SCENE_OVERSAMPLE", "scene_grid", "area_weights", "ground_truth", "FrameModel",
           "simulate_frame", "exposure", "frame_metadata", "write_frame"]


#: Built-in scenes are rendered at this many times the reconstruction grid's resolution, so a
#: frame carries detail finer than any reconstruction grid, as a real scene does.
SCENE_OVERSAMPLE = 2


def scene_grid(design, scene=None):
    """The grid a scene is rendered on: ``SCENE_OVERSAMPLE`` × the centre view's ``v × v`` for
    a built-in scene, ``None`` (the file's own resolution) for a cube file."""
    from scenes.registry import list_scenes

    if scene is not None and str(scene) not in list_scenes():
        return None
    v = design.view_size_px * SCENE_OVERSAMPLE
    return (v, v)


def area_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) weights of an exact area resampling along one axis: output cell i is the
    mean of the input over the same fraction [i/n_out, (i+1)/n_out) of the side."""
    a = np.arange(n_in + 1) / n_in
    b = np.arange(n_out + 1) / n_out
    lo = np.maximum(b[:-1, None], a[None, :-1])
    hi = np.minimum(b[1:, None], a[None, 1:])
    return np.clip(hi - lo, 0.0, None) * n_out


def ground_truth(design, cube) -> np.ndarray:
    """The cube (H, W, L) averaged onto the centre view's grid (v, v, L), float32.

    Each cube pixel covers an equal part of the centre view (:func:`sim.optics.diffuser.cube_region`),
    so a grid pixel's truth is the exact area mean of the cube over it (:func:`area_weights`;
    the identity when the cube is already v × v, a 2 × 2 block mean at twice the resolution).
    """
    v = design.view_size_px
    c = np.asarray(cube, dtype=np.float32)
    if c.shape[:2] == (v, v):
        return c
    wy = area_weights(c.shape[0], v).astype(np.float32)
    wx = area_weights(c.shape[1], v).astype(np.float32)
    return np.ascontiguousarray(np.einsum("ij,jkl,mk->iml", wy, c, wx, optimize=True),
                                dtype=np.float32)


class FrameModel:
    r"""The expected frame of a cube through a design, before noise: the transport's pixel
    integrals (:mod:`sim.transport.exact`), each band's Airy blur, and the sensor's photo-electrons,

    .. math:: \bar N_e = \sum_l c_l\, (K_l * E_l), \qquad c_l = \eta(\lambda_l)\,
              \frac{\lambda_l}{hc}\, A_{px}\, t\, \Delta\lambda_l

    (:func:`sim.sensor.electron_scale`, :func:`sim.sensor.airy_kernel`).  Only the views are
    integrated (all bands of a view at once, :mod:`sim.transport.view_integral`) and only the pixels the
    blur reaches from them are blurred, scaled and summed.

    Parameters
    ----------
    design : sim.optics.design.Design
    wavelengths : array_like (L,), optional
        The cube's bands (the design's by default).
    sampling : {"box", "centre"}
        Each band's whole interval, or its centre wavelength (:func:`sim.bands.band_intervals`).
    wavelength_nm : float, optional
        A monochromatic capture at this wavelength: one band, the cube's band holding it.
    trace_seed : int
        The transport's realisation (:data:`sim.transport.exact.SEEDS`).
    diffraction : bool
        Airy blur per band.
    """

    def __init__(self, design, wavelengths=None, *, sampling: str = "box",
                 wavelength_nm: float | None = None, trace_seed: int = 0,
                 diffraction: bool = True, progress: bool = False):
        from sim.bands import band_edges, band_intervals
        from sim.sensor import BlurredSum, airy_kernel, electron_scale
        from sim.transport.exact import load_or_build

        wl = design.wavelengths if wavelengths is None else np.atleast_1d(
            np.asarray(wavelengths, np.float64))
        self.design, self.wavelengths = design, wl
        if wavelength_nm is not None:
            lam = float(wavelength_nm)
            if not np.isfinite(lam) or lam < design.filter_min_nm or lam > design.filter_max_nm:
                raise InputError(
                    f"wavelength {wavelength_nm} nm is outside the design's pass band "
                    f"{design.filter_min_nm:g}–{design.filter_max_nm:g} nm")
            e = band_edges(wl, design)
            self.source_band = int(np.clip(np.searchsorted(e, lam, side="right") - 1, 0,
                                           wl.size - 1))
            self.bands_nm = np.array([lam])
            intervals = np.array([[lam, lam]])
        else:
            self.source_band = None
            self.bands_nm = wl
            intervals = band_intervals(design, wl, sampling)
        self.transport = load_or_build(design, intervals=intervals, seed=int(trace_seed),
                                       progress=progress)
        self.trace_seed = int(trace_seed)
        self.scale = electron_scale(design, self.bands_nm).astype(np.float32)
        self.kernels = None
        if diffraction:
            self.kernels = [airy_kernel(float(design.airy_radius_um(lam)) / design.sensor_pixel_um)
                            for lam in self.bands_nm]
        self.blur = BlurredSum(self.kernels, self.scale)
        self._buffers = {}
        self._lock = threading.Lock()

    def electrons(self, cube) -> np.ndarray:
        """Mean photo-electrons (Hs, Ws) float32 of ``cube`` (H, W, L) for a radiance scale of 1.

        View by view: every lit band's irradiance in one pass over the view's rows
        (:meth:`sim.transport.exact.Transport.view_blocks`, blocks of rows on threads), then the
        bands' blurs of the view alone, weighted and summed by FFT (:class:`sim.sensor.
        BlurredSum`), added over the view widened by the blur's reach.  The views overlap: the
        threads take the previous view's blur (its bands' spectra, in two fixed halves) between
        the first blocks of rows of the next, so that a transform, bound by memory, runs beside
        an integral, bound by arithmetic, and no thread waits between the two, nor at a view's
        end (a view's blur waits for its last blocks instead); this thread adds each view's
        blur to the frame as its halves come in.  The blur is linear, so the views'
        blurs add up to the blur of the whole sensor; every sum is taken in a fixed order, so a
        frame is the same to the bit whichever thread finishes first and on any number of
        cores.  Dark bands are skipped: a band-pass capture lights one.

        The zero-padded images the blurs transform (two per view size: one integrated while
        the other is blurred; 91 MiB each on ``paper``), each half's spectra and the inverse
        transform (25 MiB) are kept for the next frame.
        """
        from concurrent.futures import ThreadPoolExecutor
        from functools import partial

        from recon.kernels import cores
        from sim.bands import check_cube
        from sim.sensor import halves

        cube, _, peaks = check_cube(self.design, cube, self.wavelengths, peaks=True)
        if self.source_band is not None:
            cube = cube[:, :, self.source_band:self.source_band + 1]
            peaks = peaks[self.source_band:self.source_band + 1]
        tr = self.transport
        Hs, Ws = tr.sensor
        total = np.zeros(tr.sensor, np.float32)
        n_bands = cube.shape[2]
        # Radiance is never negative (checked), so a band is lit where its maximum is.
        lit = [int(l) for l in np.flatnonzero(peaks > 0)]
        if not lit:
            return total
        f = np.ascontiguousarray(cube if len(lit) == n_bands else cube[:, :, lit], np.float32)
        tr.prepare(lit, f.shape[1])
        R = self.blur.reach(lit)

        def size(k):
            return int(tr.maps.rects[k][2]), int(tr.maps.rects[k][3])

        def window(k):
            # The view widened by the blur's reach, on the sensor.
            r0, c0 = (int(v) for v in tr.maps.rects[k][:2])
            h, w = size(k)
            return (slice(max(r0 - R, 0), min(r0 + h + R, Hs)),
                    slice(max(c0 - R, 0), min(c0 + w + R, Ws)))

        def add(k, part):
            r0, c0 = (int(v) for v in tr.maps.rects[k][:2])
            a, b = window(k)
            total[a, b] += part[a.start - (r0 - R):a.stop - (r0 - R),
                                b.start - (c0 - R):b.stop - (c0 - R)]

        def add_blur(k, parts):
            r0, c0 = (int(v) for v in tr.maps.rects[k][:2])
            shape = self.blur.shape(*size(k), lit)
            inverse = buffers.setdefault(("inverse", shape), [np.empty(shape, np.float32)])
            used.add(("inverse", shape))
            self.blur.add_image(parts, lit, size(k), total, (r0 - R, c0 - R), inverse[0])

        def blur(k, images, rows):
            shape = self.blur.shape(*size(k), lit)

            def half(part, work):
                # A view's blur reads its images once their blocks of rows are done; they
                # were queued before it, so another thread is finishing them, if any.
                for r in rows:
                    r.result()
                return self.blur.spectrum(images, lit, part, size(k), work)

            # Each half's sum and transforms in buffers kept for the next view: its sum is
            # added to the frame (add_blur) before the next view's halves are queued.
            jobs = []
            for i, part in enumerate(halves(len(lit))):
                key = ("spectra", i, shape)
                used.add(key)
                work = buffers.setdefault(key, [np.empty(shape, np.float32) for _ in range(3)])
                jobs.append(partial(half, part, work))
            return jobs

        with self._workspace() as buffers, ThreadPoolExecutor(cores()) as pool:
            due = None      # (view, its images, their blocks) whose blur the threads take next
            used = set()
            for k in range(len(tr.maps.rects)):
                h, w = size(k)
                shape = self.blur.shape(h, w, lit)
                # Each band's image is integrated straight into the zero-padded buffer its
                # blur transforms (its padding stays zero: only the view's (h, w) is ever
                # written); two per size, so that one is blurred while the other is written.
                key = (len(lit), h, w, shape)
                used.add(key)
                pair = buffers.setdefault(key, [])
                irr = next((b for b in pair if due is None or b is not due[1]), None)
                if irr is None:
                    irr = np.zeros((len(lit),) + shape, np.float32)
                    pair.append(irr)
                _, blocks = tr.view_blocks(f, k, lit, out=irr)
                if R == 0:
                    for job in [pool.submit(b) for b in blocks]:
                        job.result()
                    add(k, self.blur(irr, lit, size=(h, w)))
                    continue
                self.blur.prepare(lit, shape)        # the kernels' spectra, before the threads
                jobs = [(False, b) for b in blocks]
                if due is not None:
                    # The previous view's blur after the first block of rows and after
                    # the second: each thread starts on a different kind of work.
                    for i, half in enumerate(blur(*due)):
                        jobs.insert(2 * i + 1, (True, half))
                running = [(is_blur, pool.submit(job)) for is_blur, job in jobs]
                if due is not None:
                    # Once the previous view's blur is in, its buffer is free for the next
                    # view: no thread waits for this view's last block before taking the
                    # next view's rows.
                    add_blur(due[0], [r.result() for b, r in running if b])
                due = (k, irr, [r for b, r in running if not b])
            if due is not None and R > 0:
                spectra = [pool.submit(half) for half in blur(*due)]
                add_blur(due[0], [r.result() for r in spectra])
            for key in set(buffers) - used:       # only the last frame's sizes are kept
                del buffers[key]
        # Blur with zero padding leaves round-off around zero; charge is never negative.  Only
        # the views' windows hold charge: the rest of the sensor is left untouched (its
        # pages never written).
        for k in range(len(tr.maps.rects)):
            a, b = window(k)
            np.maximum(total[a, b], 0.0, out=total[a, b])
        return total

    @contextmanager
    def _workspace(self):
        """The blurs' padded images kept from the last frame, {(bands, h, w, shape): [images]};
        a frame computed at the same time on this model (another thread) gets none."""
        if not self._lock.acquire(blocking=False):
            yield {}
            return
        try:
            yield self._buffers
        finally:
            self._lock.release()


def simulate_frame(design, cube, wavelengths, *, direct: bool = False, spp: int | None = None,
                   seed: int = 0, trace_seed: int | None = None, sampling: str = "box",
                   wavelength_nm: float | None = None, diffraction: bool = True,
                   noise: bool = True, auto_exposure: float = 0.8,
                   radiance_scale: float | None = None, progress: bool = False):
    """Render one raw frame.

    Parameters
    ----------
    design : sim.optics.design.Design
    cube : ndarray (H, W, L)
        Scene radiance at ``wavelengths`` (bands of the design), at any resolution.
    direct : bool
        Mitsuba's path tracer (:func:`sim.optics.render.render_direct`: a Monte Carlo reference, slow)
        instead of the transport's exact pixel integrals.
    spp : int, optional
        Samples per pixel per band of a direct render (default 64; direct renders only).
    seed : int
        Sensor noise seed (and the direct render's sampler seed); same seed → same frame.
    trace_seed : int, optional
        The transport's realisation (:data:`sim.transport.exact.SEEDS`; default: the scene frames').
    sampling : {"box", "centre"}
        Wavelengths within each band (:func:`sim.bands.band_intervals`).
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
        JSON-ready: design, hash, exposure, wavelengths, seeds, method, radiance scale, views.
    """
    from sim import sensor
    from sim.bands import check_cube
    from sim.transport.exact import SEEDS

    if spp is not None and not direct:
        raise InputError("spp sets the samples of a direct render; the transport integrates "
                         "every pixel exactly and takes no sample count")
    spp = int(spp if spp is not None else 64)
    if spp < 1:
        raise InputError(f"spp must be at least 1, got {spp}")
    trace_seed = SEEDS["scene"] if trace_seed is None else int(trace_seed)
    cube, wl = check_cube(design, cube, wavelengths)
    if direct:
        from sim.optics.render import render_direct

        if wavelength_nm is not None:
            model = FrameModel(design, wl, wavelength_nm=wavelength_nm, trace_seed=trace_seed,
                               diffraction=False)
            l = model.source_band
            irr = render_direct(design, cube[:, :, l:l + 1], [wavelength_nm], spp=spp,
                                seed=seed, intervals=[[wavelength_nm, wavelength_nm]],
                                progress=progress)
            bands_wl = np.array([float(wavelength_nm)])
        else:
            irr = render_direct(design, cube, wl, spp=spp, seed=seed, sampling=sampling,
                                progress=progress)
            bands_wl = wl
        ne = sensor.mean_electrons(np.moveaxis(irr, 0, 2), design, bands_wl,
                                   diffraction=diffraction)
        np.maximum(ne, 0.0, out=ne)
    else:
        model = FrameModel(design, wl, sampling=sampling, wavelength_nm=wavelength_nm,
                           trace_seed=trace_seed, diffraction=diffraction, progress=progress)
        ne = model.electrons(cube)
        bands_wl = model.bands_nm
    radiance_scale = exposure(ne, design, auto_exposure, radiance_scale)
    ne *= np.float32(radiance_scale)
    frame = sensor.digitise(ne, design, seed=seed, noise=noise)
    meta = frame_metadata(design, bands_wl, wavelength_nm=wavelength_nm, seed=seed,
                          method="direct" if direct else "transport", spp=spp if direct else None,
                          trace_seed=None if direct else trace_seed, scene_shape=cube.shape[:2],
                          sampling=sampling, diffraction=diffraction, noise=noise,
                          radiance_scale=radiance_scale)
    return frame, meta


def exposure(electrons, design, auto_exposure: float = 0.8, radiance_scale=None) -> float:
    """``radiance_scale`` if given, else the one that puts the brightest pixel's expected charge
    at ``auto_exposure`` of the full well."""
    if radiance_scale is not None:
        return float(radiance_scale)
    peak = float(np.max(electrons))
    if peak <= 0:
        raise InputError("the scene is dark: no light reaches the sensor")
    return float(auto_exposure) * design.full_well_e / peak


def frame_metadata(design, bands_wl, *, wavelength_nm, seed, method, spp, trace_seed,
                   scene_shape, sampling, diffraction, noise, radiance_scale) -> dict:
    """The JSON sidecar of a raw frame (:func:`simulate_frame`)."""
    return {
        "kind": "kaleidospec raw frame",
        "units": "DN",
        "design": design.to_dict(),
        "design_hash": design.hash,
        "exposure_ms": design.exposure_ms,
        "wavelengths_nm": [float(x) for x in bands_wl],
        "band_wavelengths_nm": [float(x) for x in design.wavelengths],
        "monochromatic_nm": None if wavelength_nm is None else float(wavelength_nm),
        "seed": int(seed),
        "method": method,
        "spp": None if spp is None else int(spp),
        "trace_seed": None if trace_seed is None else int(trace_seed),
        "scene_shape": [int(x) for x in scene_shape],
        "band_sampling": "centre" if wavelength_nm is not None else sampling,
        "diffraction": bool(diffraction),
        "noise": bool(noise),
        "radiance_scale": float(radiance_scale),
        "views": list(design.views),
        "view_rects": {str(k): list(v) for k, v in design.view_rects().items()},
        "sensor_shape": [design.sensor_height_px, design.sensor_width_px],
    }


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
