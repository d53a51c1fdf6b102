"""The design's spectral bands: their edges, the wavelength interval each one integrates, and
the check that a scene cube's bands are the design's.

A band is a box in wavelength: band *l* (centre :math:`\\lambda_l`) holds the scene's radiance
over :math:`[e_l, e_{l+1})`, the edges half-way between neighbouring centres and half a step
beyond the outer ones (:func:`band_edges`).  The UV-IR cut filter passes only
``[filter_min_nm, filter_max_nm]``, so a sensor pixel integrates band *l* over the interval
:func:`band_intervals` gives: the band's box clipped to the filter.  With bands centred on the
filter's edges (450 and 700 nm in both presets) the first and last intervals are half as wide
as the others, and they receive half the photons (:func:`band_widths`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from recon.errors import InputError

__all__ = ["band_edges", "band_intervals", "band_widths", "check_cube"]


def band_edges(wavelengths, design) -> np.ndarray:
    """Band boundaries (L+1,) nm: midpoints between centres, half a step beyond the ends."""
    wl = np.asarray(wavelengths, dtype=np.float64)
    step = float(design.band_step_nm)
    if wl.size == 1:
        return np.array([wl[0] - step / 2, wl[0] + step / 2])
    mids = 0.5 * (wl[1:] + wl[:-1])
    return np.concatenate([[wl[0] - (mids[0] - wl[0])], mids, [wl[-1] + (wl[-1] - mids[-1])]])


def band_intervals(design, wavelengths=None, sampling: str = "box") -> np.ndarray:
    """Wavelength interval (L, 2) sampled for each band.

    ``box``: the whole band, between midpoints of neighbouring centres, clipped to the filter
    (what a sensor pixel integrates; bands then carry their own dispersion blur). ``centre``:
    the band centre only (a monochromatic image per band, the discrete forward model of
    paper Eq. 1-5).
    """
    wl = design.wavelengths if wavelengths is None else np.asarray(wavelengths, np.float64)
    if sampling == "centre":
        return np.stack([wl, wl], axis=1)
    if sampling != "box":
        raise InputError(f"band sampling must be 'box' or 'centre', got {sampling!r}")
    e = band_edges(wl, design)
    lo = np.maximum(e[:-1], design.filter_min_nm)
    hi = np.minimum(e[1:], design.filter_max_nm)
    return np.stack([lo, hi], axis=1)


def band_widths(design, wavelengths=None) -> np.ndarray:
    """(L,) nm of each band that reaches the sensor: its interval's width (:func:`band_intervals`,
    the box clipped to the filter; never negative).

    The sensor counts :math:`\\Delta\\lambda_l\\,\\bar E_l` photons' worth of irradiance from a
    band whose mean spectral irradiance over its interval is :math:`\\bar E_l`, so an end band
    cut in half by the filter counts half.
    """
    iv = band_intervals(design, wavelengths, "box")
    return np.maximum(iv[:, 1] - iv[:, 0], 0.0)


@njit(cache=True, nogil=True)
def _scan(c):
    """One pass over a cube (H, W, L): (any non-finite value, any negative one, each band's
    maximum); numpy would take three passes and two temporaries the cube's size.  Each band
    keeps its own maximum, minimum and sum of x − x (NaN for a NaN or an infinity) and the
    flags come from those at the end: selects and per-band sums, so that the loop over the
    bands is vectorised (one flag updated at every value is a chain that is not)."""
    H, W, L = c.shape
    hi = np.full(L, -np.inf, np.float32)
    lo = np.full(L, np.inf, np.float32)
    z = np.zeros(L, np.float32)
    for i in range(H):
        for j in range(W):
            for l in range(L):
                x = c[i, j, l]
                z[l] += x - x
                h = hi[l]
                hi[l] = x if x > h else h
                m = lo[l]
                lo[l] = x if x < m else m
    bad = False
    neg = False
    for l in range(L):
        bad |= not (z[l] == 0.0)
        neg |= lo[l] < 0.0
    return bad, neg, hi


def _scan_halves(c):
    """:func:`_scan` on two threads, a half of the rows each, where the cube is large: the
    check is serial work before a frame's threads start (a `paper` scene at twice the view
    grid holds 1800² × 26 values)."""
    from recon.kernels import cores, each

    n = c.shape[0]
    if c.size < (1 << 22) or n < 2 or cores() < 2:
        return _scan(c)
    a, b = each(_scan, (c[:n // 2], c[n // 2:]))
    return a[0] or b[0], a[1] or b[1], np.maximum(a[2], b[2])


def check_cube(design, cube, wavelengths, *, peaks: bool = False):
    """Validate a scene cube against the design; returns (cube float32 (H, W, L), wavelengths),
    and each band's maximum (L,) float32 as well with ``peaks=True`` (the same pass).

    Raises :class:`InputError` for a wrong shape, non-finite or negative values (after the
    conversion to float32: a value beyond its range is infinite there), or wavelengths that
    are not bands of the design (tolerance 1e-3 nm).
    """
    c = np.asarray(cube)
    if c.ndim == 2:
        c = c[:, :, None]
    wl = np.atleast_1d(np.asarray(wavelengths, dtype=np.float64))
    if c.ndim != 3 or c.shape[2] != wl.size or c.shape[0] < 1 or c.shape[1] < 1:
        raise InputError(
            f"the scene cube must be (H, W, L) with L = {wl.size} wavelengths, got shape {c.shape}"
        )
    if not np.all(np.isfinite(wl)):
        raise InputError("the cube's wavelengths must be finite")
    if not (np.issubdtype(c.dtype, np.number) or c.dtype == bool) \
            or np.issubdtype(c.dtype, np.complexfloating):
        raise InputError(f"the scene cube must hold real numbers, got {c.dtype}")
    with np.errstate(over="ignore"):         # out of range: inf, refused below
        c = c.astype(np.float32, copy=False)
    bad, neg, peak = _scan_halves(c)
    if bad:
        raise InputError("the scene cube has non-finite values (NaN or inf)")
    if neg:
        raise InputError("the scene cube has negative radiance")
    bands = design.wavelengths
    for x in wl:
        if np.min(np.abs(bands - x)) > 1e-3:
            raise InputError(
                f"wavelength {x:g} nm is not a band of the design "
                f"({bands[0]:g}–{bands[-1]:g} nm, step {design.band_step_nm:g})"
            )
    return (c, wl, peak) if peaks else (c, wl)
