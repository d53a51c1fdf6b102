r"""Calibration captures → one calibration file, cached by design hash.

:func:`calibrate` renders the captures (:func:`kaleidospec.instrument.render_captures`) and
runs :mod:`recon.calibration` on them, as a lab would with its targets:

1. **views** — each view's box on the sensor, from the monochromatic whites;
2. **dispersion** — :math:`\varphi_k(\lambda)` from the line captures (a polynomial fit), and
   where each band's light lands on average over the band-pass filter's interval;
3. **masks** — each view's per-band mask image from the whites (deconvolved for the Airy
   blur where it spans a pixel: total-variation-regularised,
   :func:`recon.calibration.mask.tv_deconvolve`), chrome below :data:`MASK_FLOOR` set to zero;
4. **geometry** — homographies to the centre view from the checkerboard at 550 nm, what they
   miss of each view (a smooth displacement field, :func:`recon.calibration.board_field`: the
   prism bends a view's image along x), and each view's *lead*: how many columns before its
   offsets its light begins, where the shifted model starts its image
   (:mod:`recon.calibration.extent`);
5. the steps of the other calibrated models asked for (:data:`STEPS`: the smeared model's view
   masks, the footprint model's comb captures);
6. **radiometry** — per model, the per-band gains :math:`c_l` (radiance per DN/s).  By
   default (:data:`RADIOMETRY` ``"flat"``) they come from the flat field: the band-pass whites
   are a source of known radiance (an integrating sphere's, in a lab), so a white's level per
   unit exposure is the gain of an open pixel (the comb targets' lit texels, of known radiance
   too, give the footprint model's); where the mask images are deconvolved and the model
   blurs them again, the gains are those with which the model reproduces each white
   (:func:`model_flat_gains`: a blurred white's level is not its deconvolution's).
   ``"colorchecker"`` refits them as the paper does: the ColorChecker reconstructed with
   those gains, per-band least squares of its patches against
   their reference radiance.  That refit is biased by the reconstruction itself (its errors
   become the gains' errors), so the ColorChecker is a check here, not a fit.

The result (:class:`recon.calibration.Calibration`) is one ``.npz`` + ``.json`` in the cache
folder (:func:`calibration_file`), keyed by the design's hash and the calibration code's
version; a later call loads it.  Nothing here reads the simulator's internals: only captures,
their sidecars and what a lab knows of its targets and filters.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["MASK_FLOOR", "BOX_MARGIN_X", "DECONVOLVE_MIN_PX", "RADIOMETRY", "RADIOMETRY_VIEWS",
           "STEPS", "Measured", "calibrate", "calibrate_from_captures", "calibration_file",
           "deconvolution_radii", "floor_chrome", "is_cached", "model_flat_gains",
           "sensor_noise"]

#: Calibrated mask values below this (fraction of the white level) are taken as chrome (0).
MASK_FLOOR = 0.05
#: Columns added (at most: never so many that boxes overlap) on each side of a view's lit extent:
#: a view's outermost columns are lit by one band only and fall under the box threshold.
BOX_MARGIN_X = 2
#: The mask images are deconvolved (and the shifted and smeared models blurred by the PSF) when
#: the largest Airy radius reaches this many pixels (``small``: 0.39 px, ``paper``: 2.11 px).
DECONVOLVE_MIN_PX = 0.75
#: Where the radiometric gains come from: "flat" (the flat field's known radiance) or
#: "colorchecker" (refitted on the reconstructed chart; module notes).
RADIOMETRY = "flat"
#: Views used to reconstruct the ColorChecker for the "colorchecker" radiometry.
RADIOMETRY_VIEWS = 5


@dataclass
class Measured:
    """What the shared steps measured, for the steps of the other models (:data:`STEPS`)."""

    design: object
    captures: object
    #: (K, 4) the views' boxes.
    boxes: np.ndarray
    #: Line centroids per view and band (:func:`recon.calibration.line_centroids`).
    centroids: np.ndarray
    #: :class:`recon.calibration.DispersionFit` of the line captures.
    fit: object
    #: (L,) Airy radius per band (px), and the radii deconvolved (None: below a pixel).
    radii: np.ndarray
    airy: np.ndarray | None
    #: (L, 2) the band-pass filters' wavelength intervals.
    intervals: np.ndarray
    #: (L,) each white capture's exposure factor ``radiance_scale``.
    exposures: np.ndarray
    repeats: int
    progress: bool


def _smeared(cal, m: Measured) -> dict:
    """The smeared model's view masks, from all the band whites jointly; its white levels are
    those of an open mask pixel (a smear wider than a mask cell lowers the captured level),
    hence its own provisional gains.  Its smear kernels are assembled with the offsets
    (:func:`recon.calibration.build_calibration`'s ``band_positions``)."""
    from recon.calibration.mask import view_masks

    vm, vlevels = view_masks(m.captures.white, m.boxes, cal.tap_start, cal.tap_weights,
                             cal.view_shape[1], airy_radius=m.airy)
    vm = floor_chrome(vm)
    return {"view_masks": vm, "smear_gains": m.exposures / vlevels}


def _footprints(cal, m: Measured) -> dict:
    """The footprint model: the system matrix decoded from the comb captures (streamed, one
    frame at a time) of a period wider than a band's smear and the Airy core; provisional gains
    1 (the captures are divided by the lit texels' radiance)."""
    from kaleidospec.instrument import comb_captures
    from kaleidospec.models import SMEAR_SAMPLES
    from recon.calibration.dispersion import band_positions
    from recon.calibration.footprint import (comb_period, footprint_matrix, line_anchor,
                                             predicted_positions)

    smear = np.ptp(band_positions(m.fit, m.intervals, SMEAR_SAMPLES), axis=2).max()
    period = comb_period(smear, float(m.radii.max()))
    i = cal.view_ids.index(0)
    column = m.captures.meta["line"][0]["column"]
    shift = (0.0, line_anchor(m.centroids, cal.offsets, column, centre=i))
    pos = predicted_positions(cal.homographies, cal.offsets, cal.view_boxes[0, 2:], shift)
    caps = comb_captures(m.design, period, repeats=m.repeats, progress=m.progress)
    a, grid = footprint_matrix(caps, cal.view_boxes, pos)
    py, px = period
    names = [f"comb{py}x{px}@{w:g}nm" for w in cal.wavelengths]
    return {"footprint_grid": np.array(grid, np.int64),
            "footprint_indptr": a.indptr.astype(np.int64), "footprint_indices": a.indices,
            "footprint_data": a.data, "footprint_gains": np.ones(cal.n_bands),
            "captures": list(cal.captures) + names}


#: The steps of the calibrated models beyond the shifted one (:data:`kaleidospec.models.MODELS`),
#: in the order they run: model → (progress label, ``step(cal, measured) -> fields``).  A
#: step returns the :class:`recon.calibration.Calibration` fields its model adds, its
#: flat-field gains among them (the radiometry keeps them, or refits them on the ColorChecker).
STEPS: dict[str, tuple[str, Callable[..., dict]]] = {
    "smeared": ("view masks", _smeared),
    "footprint": ("footprints", _footprints),
}


def deconvolution_radii(design, wavelengths=None) -> np.ndarray | None:
    """(L,) the Airy radii (px) the mask images are deconvolved with, or None where the lens's
    diffraction stays inside a pixel (then the calibrated models carry no PSF either)."""
    from recon.calibration import airy_radius_px

    wl = design.wavelengths if wavelengths is None else np.asarray(wavelengths, np.float64)
    radii = airy_radius_px(wl, design.imaging_f_number, design.sensor_pixel_um)
    # Below ~0.75 px the Airy core stays inside one pixel: deconvolution would only add noise.
    return radii if float(radii.max()) >= DECONVOLVE_MIN_PX else None


def calibrate(design, *, model: str | None = None, cache_dir=None, progress: bool = True,
              force: bool = False, repeats: int = 4):
    """The calibration of ``design`` from rendered captures, cached by design hash.

    Parameters
    ----------
    design : sim.optics.design.Design
    model : str, optional
        The calibrated model it must hold (:data:`kaleidospec.models.MODELS`; default
        :data:`kaleidospec.models.DEFAULT_MODEL`).  ``"footprint"`` adds L·P_y·P_x comb
        captures (:func:`recon.calibration.footprint.comb_period`); a cached calibration
        without the model is redone with it.
    cache_dir : path, optional
        Where ``calibration-<hash>.npz/.json`` live (default: the simulator's cache folder,
        ``$KALEIDOSPEC_CACHE`` or ``~/.cache/kaleidospec``).
    progress : bool
        Progress bars on stderr.
    force : bool
        Recalibrate even if a cached calibration exists.
    repeats : int
        Noisy frames averaged per capture (:mod:`sim.captures`); 0 renders noise-free.

    Returns
    -------
    recon.calibration.Calibration
        ``view_ids`` = the design's views (sorted), gains from the flat field (:data:`RADIOMETRY`).
    """
    from kaleidospec.instrument import cache_dir as folder
    from kaleidospec.models import DEFAULT_MODEL, holds
    from recon.calibration import load_cached, save_cached

    model = DEFAULT_MODEL if model is None else model
    cdir = folder(cache_dir)
    if not force:
        # None also for a damaged entry (removed with one warning line): calibrated again.
        cal = load_cached(cdir, design.hash)
        if cal is not None and holds(cal, model):
            return cal
    cal = calibrate_from_captures(design, models=(model,), repeats=repeats, progress=progress)
    save_cached(cdir, cal)
    return cal


def calibrate_from_captures(design, *, models=None, repeats: int = 4, progress: bool = False,
                            captures=None, radiometry: str | None = None):
    """Render the captures (unless given) and run every calibration step; nothing is cached.

    ``models`` names the calibrated models to measure (default
    :data:`kaleidospec.models.DEFAULT_MODEL`); the shifted model is always measured, the
    others by their :data:`STEPS`, each with gains of its own.  ``radiometry`` is
    :data:`RADIOMETRY`'s choice by default.
    """
    from kaleidospec.instrument import CHECKER_NM, band_intervals, render_captures
    from kaleidospec.models import DEFAULT_MODEL, GAINS, MODELS, SMEAR_SAMPLES, model_gains
    from kaleidospec.report import progress_bar
    from recon.calibration import (airy_kernel, airy_radius_px, build_calibration,
                                   find_view_boxes, fit_dispersion, line_centroids,
                                   view_homographies, with_leads)
    from recon.calibration.dispersion import (band_mean_positions, band_positions,
                                              line_profiles, profile_centroids)
    from recon.calibration.mask import (deconvolve_views, normalise_mask_images, view_stack,
                                        white_levels)
    from recon.errors import InputError

    radiometry = RADIOMETRY if radiometry is None else radiometry
    if radiometry not in ("flat", "colorchecker"):
        raise InputError(f"radiometry must be 'flat' or 'colorchecker', got {radiometry!r}")
    wanted = {DEFAULT_MODEL} if models is None else set(models)
    unknown = sorted(wanted - set(MODELS))
    if unknown:
        raise InputError(f"unknown calibrated model(s) {unknown}; known: {', '.join(MODELS)}")
    extra = [name for name in STEPS if name in wanted]
    ids = tuple(sorted(design.views))
    owned = captures is None
    profiles = {}
    if owned:
        # Nothing reads a line capture but its column profiles, and the whites, which give
        # the views' boxes, are all rendered before the lines: each line frame is reduced to
        # its profiles as it is read out, so the line stack (26 full frames, 0.95 GB on
        # `paper`) is never held beside the whites (the same numbers as from the stack,
        # recon.calibration.dispersion.line_profiles).
        def on_line(l, frame, whites):
            if "boxes" not in profiles:
                profiles["boxes"] = find_view_boxes(whites, ids, margin_x=BOX_MARGIN_X)
                profiles["bands"] = [None] * len(whites)
            profiles["bands"][l] = line_profiles(frame[None], profiles["boxes"])[:, 0]

        # No capture is rendered after these but the comb captures: without them the
        # captures' transport is not needed again in this process.
        keep = "footprint" in extra
        captures = render_captures(design, repeats=repeats, progress=progress,
                                   keep_transport=keep, on_line=on_line)
        if not keep:
            from kaleidospec.instrument import release_transports

            release_transports("captures")
    caps = captures
    wl = caps.wavelengths
    steps = ["views", "dispersion", "masks", "geometry"] + [STEPS[m][0] for m in extra] \
        + ["radiometry"]
    bar = progress_bar(len(steps), "calibration", progress)
    try:
        if owned:
            boxes = profiles["boxes"]
            bar.update()
            cen = profile_centroids(np.stack(profiles["bands"], axis=1))
        else:
            boxes = find_view_boxes(caps.white, ids, margin_x=BOX_MARGIN_X)
            bar.update()
            cen = line_centroids(caps.line, boxes)
        fit = fit_dispersion(wl, cen, ref_nm=CHECKER_NM, degree=min(3, wl.size - 1))
        bar.update()
        radii = airy_radius_px(wl, design.imaging_f_number, design.sensor_pixel_um)
        airy = deconvolution_radii(design, wl)
        # The whites' crops once: the mask images are deconvolved from a copy of them and
        # the flat-field gains below fit them again; the full white frames (0.95 GB on
        # `paper`) go once cropped, unless the smeared model's step reads them.
        whites = view_stack(caps.white, boxes)
        if owned and "smeared" not in extra:
            caps.white = None
        masks = normalise_mask_images(deconvolve_views(whites.copy(), airy_radius=airy,
                                                       progress=progress))
        masks = floor_chrome(masks, out=masks)
        bar.update()
        # The board's layout is what a lab knows from its target: read it from the sidecar.
        pattern = tuple(caps.meta["checker"]["pattern_size"])
        hb, fields = view_homographies(caps.checker, caps.checker_white, boxes, ids, pattern,
                                       return_fields=True)
        bar.update()
        # Provisional gains from the whites (radiance E = 1 per band): the mask images are the
        # white captures divided by their white level w_l (DN at an open pixel), taken with
        # exposure s_l, so DN/s per unit radiance at an open pixel is w_l / s_l.
        levels = white_levels(whites)
        expo = np.array([m["radiance_scale"] for m in caps.meta["white"]], dtype=np.float64)
        gains0 = expo / levels
        # The bands' wavelength intervals are the band-pass filters' (a lab knows them from
        # the filters' datasheet): each band smears over phi(lo)..phi(hi), and its scene sits
        # at the mean of that smear, not where its nominal wavelength lands (measured on
        # `small`: 0.8 px apart for the 450 nm band; `tools/exp_calibration_gap.py`).
        intervals = band_intervals(design, wl)
        cal = build_calibration(
            view_ids=ids, view_boxes=boxes, box_homographies=hb, mask_images=masks,
            wavelengths=wl, dispersion=band_mean_positions(fit, intervals, SMEAR_SAMPLES),
            checker_dispersion=fit.positions([CHECKER_NM])[:, 0], phase=True,
            gains=gains0, design_hash=design.hash, captures=caps.names(), box_fields=fields,
            band_positions=(band_positions(fit, intervals, SMEAR_SAMPLES)
                            if "smeared" in extra else None))
        # Views whose light begins before their offsets (recon.calibration.extent: on `paper`
        # the left, top and bottom views code 13-19 columns there): the shifted model starts
        # their images that much earlier.
        cal = with_leads(cal)
        # The sensor's noise, which sets the reconstructions' TV weight (the ColorChecker's
        # radiometry below reconstructs already).
        cal = dataclasses.replace(cal, noise=sensor_noise(design, caps))
        if airy is not None:
            # The masks are now sharp, but the lens blurs the coded image after the mask: the
            # shifted and smeared models blur their measurement with the diffraction-limited
            # PSF again.  One PSF at the bands' mean radius: one a band (through a basis of
            # two PSFs) costs twice the time and gained nothing (docs/calibration.md).
            cal = dataclasses.replace(cal, psf=airy_kernel(float(np.mean(airy))))
            # Gains from the flat field through the model itself: the level of a blurred white
            # is below its deconvolution's, so expo / levels would make the model too dark and
            # every reconstruction as much too bright (recon.calibration.flat_field_gains).
            cal = dataclasses.replace(cal, gains=model_flat_gains(cal, whites, expo))
        del whites
        measured = Measured(design=design, captures=caps, boxes=boxes, centroids=cen, fit=fit,
                            radii=radii, airy=airy, intervals=intervals, exposures=expo,
                            repeats=repeats, progress=progress)
        for name in extra:
            cal = dataclasses.replace(cal, **STEPS[name][1](cal, measured))
            bar.update()
        # Radiometry, per model: the flat field's (the provisional gains, kept), or refitted
        # on the ColorChecker (RADIOMETRY).
        gains = {m: (_radiometry(design, caps, cal, m) if radiometry == "colorchecker"
                     else model_gains(cal, m)) for m in MODELS
                 if m == "shifted" or m in extra}
        bar.update()
    finally:
        bar.close()
    for name, g in gains.items():
        if not np.all(g > 0):
            prefix = "" if name == "shifted" else f"{name}-model "
            raise RuntimeError(f"radiometric calibration failed: {prefix}gains {g.tolist()}")
    return dataclasses.replace(cal, **{GAINS[m]: g for m, g in gains.items()})


def model_flat_gains(cal, whites, exposures) -> np.ndarray:
    """(L,) the shifted model's gains with which it reproduces the white captures
    (:func:`recon.calibration.flat_field_gains`; ``whites``: their (K, L, h, w) crops to the
    calibration's boxes, ``exposures``: their exposure factors)."""
    from recon.calibration import flat_field_gains, operator_from_calibration

    op = operator_from_calibration(cal, model="shifted")
    ones = np.ones(op.ishape[1:], np.float32)

    def band_white(l):
        # One band's model alone (the others add exact zeros): a 26th of the full forward.
        return op.band_forward(l, ones)

    return flat_field_gains(band_white, whites, exposures)


def floor_chrome(masks, out=None) -> np.ndarray:
    """``masks`` with every value below :data:`MASK_FLOOR` set to exactly zero (into ``out``
    when given, which may be ``masks``: the mask images are the calibration's largest array).

    Chrome cells are not perfectly dark in a capture (stray light, the sensor's blur): values
    near zero would give measurement pixels with a tiny row norm, which GAP-TV's
    diag(HH^T)^-1 step amplifies without bound.
    """
    if out is None:
        return np.where(masks >= MASK_FLOOR, masks, np.float32(0.0))
    np.copyto(out, masks)
    out[~(masks >= MASK_FLOOR)] = np.float32(0.0)
    return out


def sensor_noise(design, caps):
    """The sensor's photon-transfer curve ``[a, b]`` (:mod:`recon.calibration.noise`) from the
    captures' pairs of single frames, pooled; None without one (captures of fewer than 2
    repeats)."""
    from recon.calibration.noise import photon_transfer

    frames = caps.noise_frames
    if frames is None:
        return None
    return photon_transfer(frames[0::2], frames[1::2], design.max_dn)


def _radiometry(design, caps, cal, model) -> np.ndarray:
    """The gains of ``model`` refitted on the ColorChecker capture (per-band least squares of
    the reconstructed patches against their reference radiance)."""
    from recon.view_ids import VIEW_ORDER
    from kaleidospec.models import grid_offset, model_gains
    from kaleidospec.reconstruct import DEFAULTS, reconstruct_views
    from recon.calibration import fit_gains, patch_spectra

    ids = cal.view_ids
    n = min(RADIOMETRY_VIEWS, len(ids))
    n = max(i + 1 for i in range(n) if set(VIEW_ORDER[:i + 1]) <= set(ids))
    # The scalar step, whatever the default metric: the cached calibrations (keyed by the
    # calibration code's version) were fitted with it, and the fit runs to convergence.
    cube, _ = reconstruct_views(caps.colorchecker, caps.meta["colorchecker"], cal, n,
                                model=model, **dict(DEFAULTS, metric="scalar"))
    oy, ox = grid_offset(design, cal, model)
    pb = caps.patch_boxes.astype(np.float64).copy()
    pb[:, 0] -= oy
    pb[:, 1] -= ox
    pb = np.round(pb).astype(np.int64)
    # Patches that the reconstruction grid cuts (the guard stripe's columns) are left out.
    inside = ((pb[:, 0] >= 0) & (pb[:, 1] >= 0) & (pb[:, 0] + pb[:, 2] <= cube.shape[0])
              & (pb[:, 1] + pb[:, 3] <= cube.shape[1]))
    f = patch_spectra(cube, pb[inside])
    g0 = model_gains(cal, model)
    return g0 * fit_gains(f, caps.patch_radiance[inside])


def calibration_file(design, cache_dir=None) -> Path:
    """Where the calibration of ``design`` is stored (a video's workers load it from there);
    it must exist (:func:`calibrate` first)."""
    from kaleidospec.instrument import cache_dir as folder
    from recon.calibration import calibration_path

    p = calibration_path(folder(cache_dir), design.hash)
    if not p.is_file():
        raise RuntimeError(f"the calibration of design {design.hash} is not at {p}")
    return p


def is_cached(design, cache_dir=None) -> bool:
    """Whether a calibration of ``design`` is in the cache (:func:`calibrate` would load it; a
    cut or foreign entry is not, :func:`recon.calibration.store.is_cached`)."""
    from kaleidospec.instrument import cache_dir as folder
    from recon.calibration.store import is_cached as cached

    return cached(folder(cache_dir), design.hash)
