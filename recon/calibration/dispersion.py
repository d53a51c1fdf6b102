r"""Dispersion calibration: the shift :math:`\varphi_k(\lambda)` of every view from line captures.

A thin vertical line (a slit on a white target) is captured band by band.  In view :math:`k`
and band :math:`l` the line sits at column :math:`x_{k,l}`; the mask modulates it row by row,
but the mask acts *before* the prism, so every band of a view sees the same modulation and the
same profile, only shifted: :math:`x_{k,l} - x_{k,\mathrm{ref}} = \varphi_k(\lambda_l)`.

Centroid: the view's column profile :math:`p(x) = \sum_y I(y, x)` (the rows' sum averages the
mask's row-to-row modulation), background removed (median), then

.. math:: \bar x = \frac{\sum_x x\, p_+(x)}{\sum_x p_+(x)}

over a window of ``half_width`` px around the peak, :math:`p_+ = \max(p - b, 0)`.

Fit: :math:`\varphi_k` is smooth in wavelength; a glass's index, and so the deviation, is nearly
polynomial in :math:`u = 1/\lambda^2` (Cauchy), so :func:`fit_dispersion` fits a low-order
polynomial in :math:`u` per view, constrained to vanish at the reference wavelength.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.calibration.mask import view_stack
from recon.errors import InputError


def line_centroids(line_captures, view_boxes, dark=None, half_width: int = 6) -> np.ndarray:
    r"""Sub-pixel column of the line in every view and band (box coordinates).

    Parameters
    ----------
    line_captures : (L, H, W) or (L, N, H, W) array_like
        One monochromatic capture of the vertical line per band (N repeats averaged).
    view_boxes : (K, 4) array_like
    dark : (H, W) array_like, optional
    half_width : int
        The centroid sums over ``peak ± half_width`` columns.

    Returns
    -------
    (K, L) float64

    Raises
    ------
    InputError
        Bad shapes, or a view/band where no line is visible.

    Notes
    -----
    :func:`line_profiles` then :func:`profile_centroids`; a caller that gets the captures
    one at a time takes each one's profiles as it comes (the same numbers) and never holds the
    stack.
    """
    return profile_centroids(line_profiles(line_captures, view_boxes, dark), half_width)


def line_profiles(line_captures, view_boxes, dark=None) -> np.ndarray:
    r"""Every view's column profile of every line capture, :math:`p_{k,l}(x) = \sum_y
    I_{k,l}(y, x)` (float64 sums of the float32 crops, row after row), (K, L, w) float64.

    ``line_captures`` (L, H, W) or (L, N, H, W) as in :func:`line_centroids`; a band's
    profiles depend on its capture alone, so the captures can be given one at a time
    (``captures[None]``, L = 1) and the profiles stacked along the band axis.
    """
    views = view_stack(line_captures, view_boxes, dark, "line captures")   # (K, L, h, w)
    return views.sum(axis=2, dtype=np.float64)


def profile_centroids(profiles, half_width: int = 6) -> np.ndarray:
    r"""The line's sub-pixel column in every view and band from its column profiles
    (:func:`line_profiles`, (K, L, w)): the background (median) removed, the centroid of
    :math:`p_+` over ``peak ± half_width`` columns (module notes), (K, L) float64.

    Raises
    ------
    InputError
        A view/band where no line stands 5 robust standard deviations above the profile's
        background.
    """
    if half_width < 1:
        raise InputError(f"half_width must be >= 1, got {half_width}")
    profiles = np.asarray(profiles, dtype=np.float64)
    if profiles.ndim != 3:
        raise InputError(f"line profiles must be (K, L, w), got shape {profiles.shape}")
    n_views, n_bands = profiles.shape[:2]
    out = np.empty((n_views, n_bands), dtype=np.float64)
    for k in range(n_views):
        prof = profiles[k]                                    # (L, w)
        prof = prof - np.median(prof, axis=1, keepdims=True)
        w = prof.shape[1]
        x = np.arange(w, dtype=np.float64)
        peak = np.argmax(prof, axis=1)
        for l in range(n_bands):
            lo = max(0, peak[l] - half_width)
            hi = min(w, peak[l] + half_width + 1)
            p = np.maximum(prof[l, lo:hi], 0.0)
            s = p.sum()
            noise = 1.4826 * np.median(np.abs(prof[l] - np.median(prof[l])))
            if not s > 0 or prof[l, peak[l]] <= 5.0 * noise:
                raise InputError(f"no line found in view box {k}, band {l}")
            out[k, l] = float((x[lo:hi] * p).sum() / s)
    return out


@dataclass(frozen=True)
class DispersionFit:
    r"""Per-view dispersion :math:`\varphi_k(\lambda)` as polynomials in :math:`u = 1/\lambda^2`.

    Attributes
    ----------
    ref_nm : float
        Wavelength where :math:`\varphi_k = 0`.
    coeffs : (K, degree) float64
        :math:`\varphi_k(\lambda) = \sum_{j=1}^{d} a_{k,j} (u - u_\mathrm{ref})^j`, with
        :math:`u` in µm⁻² (so the coefficients are of order the shifts).
    rms_px : (K,) float64
        RMS residual of the fit at the measured wavelengths.
    intercept : (K,) float64 or None
        The fit's constant term: the line's column (box coordinates) at ``ref_nm``, so that
        :math:`\varphi_k + a_{k,0}` is the line's fitted position (:meth:`positions`).
    """

    ref_nm: float
    coeffs: np.ndarray
    rms_px: np.ndarray
    intercept: np.ndarray | None = None

    def positions(self, wavelengths_nm) -> np.ndarray:
        r"""(K, L) fitted line columns (box coordinates): :math:`a_{k,0} + \varphi_k(\lambda)`."""
        a0 = np.zeros(self.coeffs.shape[0]) if self.intercept is None else self.intercept
        return self(wavelengths_nm) + np.asarray(a0, dtype=np.float64)[:, None]

    def __call__(self, wavelengths_nm) -> np.ndarray:
        r"""Return :math:`\varphi_k(\lambda)`, shape (K, L) for L wavelengths."""
        du = _u(wavelengths_nm) - _u(self.ref_nm)
        powers = du[None, :] ** np.arange(1, self.coeffs.shape[1] + 1)[:, None]   # (d, L)
        return self.coeffs @ powers


def fit_dispersion(wavelengths_nm, centroids, ref_nm: float | None = 550.0,
                   degree: int = 3) -> DispersionFit:
    r"""Fit :math:`\varphi_k(\lambda)` to measured line centroids.

    Parameters
    ----------
    wavelengths_nm : (L,) array_like
        Band centres of the line captures.
    centroids : (K, L) array_like
        :func:`line_centroids`.
    ref_nm : float or None
        Reference wavelength (:math:`\varphi = 0` there): 550 nm by default; ``None`` takes the
        centre band.  It need not be one of the bands: the fit's constant term is free, and the
        curve is then re-expressed relative to it.
    degree : int
        Polynomial degree in :math:`1/\lambda^2` (1–4).  For a BK7 prism spreading 450–700 nm
        over 50 px the model error is 0.50 / 0.13 / 0.03 / 0.006 px for degrees 1 / 2 / 3 / 4
        (the Sellmeier infrared term is not a polynomial in :math:`1/\lambda^2`); 3 is the
        default, and needs at least 4 bands.

    Returns
    -------
    DispersionFit
    """
    lam = np.asarray(wavelengths_nm, dtype=np.float64)
    c = np.asarray(centroids, dtype=np.float64)
    if lam.ndim != 1 or c.ndim != 2 or c.shape[1] != lam.size:
        raise InputError(f"centroids must be (K, L) with L = {lam.size} wavelengths, "
                         f"got {c.shape}")
    if not (np.all(np.isfinite(lam)) and np.all(lam > 0) and np.all(np.isfinite(c))):
        raise InputError("wavelengths must be positive and centroids finite")
    if not 1 <= degree <= 4:
        raise InputError(f"degree must be 1..4, got {degree}")
    if lam.size < degree + 1:
        raise InputError(f"a degree-{degree} fit needs at least {degree + 1} bands, "
                         f"got {lam.size}")
    if ref_nm is None:
        ref_nm = float(lam[lam.size // 2])
    ref_nm = float(ref_nm)
    du = _u(lam) - _u(ref_nm)
    # Columns 1, du, du², ...: the constant absorbs the line's position in each view.
    a = du[:, None] ** np.arange(degree + 1)[None, :]
    sol, *_ = np.linalg.lstsq(a, c.T, rcond=None)            # (d+1, K)
    resid = c.T - a @ sol
    rms = np.sqrt(np.mean(resid ** 2, axis=0))
    return DispersionFit(ref_nm=ref_nm, coeffs=np.ascontiguousarray(sol[1:].T), rms_px=rms,
                         intercept=np.ascontiguousarray(sol[0]))


def band_positions(fit: DispersionFit, intervals_nm, samples: int = 32) -> np.ndarray:
    r"""Fitted line positions across every band: (K, L, S) box columns.

    A band of width :math:`[\lambda_\mathrm{lo}, \lambda_\mathrm{hi}]` (a band-pass filter's
    interval, or the midpoints between neighbouring band centres) lands on the sensor spread
    over :math:`\varphi(\lambda_\mathrm{lo}) \ldots \varphi(\lambda_\mathrm{hi})`.  The
    positions :meth:`DispersionFit.positions` at the midpoints of ``samples`` equal
    sub-intervals are the evenly weighted samples from which
    :func:`~recon.operators.smeared.taps_from_positions` builds the band's smear kernel.

    Parameters
    ----------
    fit : DispersionFit
    intervals_nm : (L, 2) array_like
        ``[lo, hi]`` per band, nm, ``lo <= hi``.
    samples : int
        Wavelengths per band (>= 1; 1 is the band centre of the interval).
    """
    lam = band_wavelengths(intervals_nm, samples)                          # (L, S)
    pos = fit.positions(lam.ravel())                                       # (K, L*S)
    return pos.reshape((pos.shape[0],) + lam.shape)


def band_wavelengths(intervals_nm, samples: int = 32) -> np.ndarray:
    """(L, S) wavelengths at the midpoints of ``samples`` equal parts of every band's interval.

    Raises
    ------
    InputError
        Intervals that are not (L, 2) positive ``[lo, hi]`` with ``lo <= hi``, or samples < 1.
    """
    iv = np.asarray(intervals_nm, dtype=np.float64)
    if iv.ndim != 2 or iv.shape[1] != 2 or not np.all(np.isfinite(iv)) \
            or np.any(iv[:, 0] <= 0) or np.any(iv[:, 1] < iv[:, 0]):
        raise InputError(f"band intervals must be (L, 2) positive [lo, hi], got shape {iv.shape}")
    if int(samples) < 1:
        raise InputError(f"samples must be >= 1, got {samples}")
    u = (np.arange(int(samples)) + 0.5) / int(samples)
    return iv[:, :1] + (iv[:, 1:] - iv[:, :1]) * u[None, :]


def band_mean_positions(fit: DispersionFit, intervals_nm, samples: int = 32) -> np.ndarray:
    r"""Where each band lands on average: (K, L) box columns.

    A band :math:`[\lambda_\mathrm{lo}, \lambda_\mathrm{hi}]` spreads over
    :math:`\varphi(\lambda_\mathrm{lo}) \ldots \varphi(\lambda_\mathrm{hi})`, and since
    :math:`\varphi` is not linear in :math:`\lambda` (steeper in the blue) the light's mean
    position is not the position of the band's nominal wavelength: for the first and last bands,
    whose nominal wavelengths sit at their intervals' edges, the two differ by most of the
    band's smear (0.8 px for the ``small`` design's 450 nm band).  The shifted-mask model puts a
    band's scene at one column, which should be the mean

    .. math:: \bar x_{k,l} = \frac{1}{\lambda_\mathrm{hi} - \lambda_\mathrm{lo}}
              \int_{\lambda_\mathrm{lo}}^{\lambda_\mathrm{hi}} x_k(\lambda)\, d\lambda,

    the mean of :func:`band_positions` (a flat spectrum within the band, which is what a band
    of a cube means).

    Parameters
    ----------
    fit : DispersionFit
    intervals_nm : (L, 2) array_like
        ``[lo, hi]`` per band (as for :func:`band_positions`).
    samples : int
        Wavelengths averaged per band.
    """
    return band_positions(fit, intervals_nm, samples).mean(axis=2)


def normalise_offsets_phase(offsets) -> tuple[np.ndarray, np.ndarray]:
    r"""Shift every view's row of a (K, L) table of *line positions* by a whole number of
    columns so that its smallest entry is in [0, 1).

    With the fitted line positions as offsets, the line (one scene column wide) falls on a
    whole view column in every band: the view grid keeps the sub-pixel phase of the scene and
    mask grid that the line shows, instead of an arbitrary one (a grid half a pixel off the
    mask cells mixes two mask cells into every model pixel).

    Returns
    -------
    offsets : (K, L) float64
    shift : (K,) float64
        The whole numbers subtracted per view.
    """
    o = np.asarray(offsets, dtype=np.float64)
    shift = np.floor(o.min(axis=1) + 1e-9)
    return o - shift[:, None], shift


def normalise_offsets(offsets) -> tuple[np.ndarray, float]:
    r"""Shift a (K, L) offset table so that its smallest entry is exactly 0.

    The calibrated operator puts view column :math:`x_v` of band :math:`l` on box column
    :math:`x_v + o_{k,l}`; with :math:`\min o = 0` the operator's own normalisation (which
    subtracts :math:`\lfloor\min o\rfloor`) leaves the table unchanged.

    Returns
    -------
    offsets : (K, L) float64
    shift : float
        The amount subtracted (:math:`\min`), to convert other offsets the same way.
    """
    o = np.asarray(offsets, dtype=np.float64)
    m = float(o.min())
    return o - m, m


def _u(wavelengths_nm) -> np.ndarray:
    """1/λ² in µm⁻²."""
    lam_um = np.asarray(wavelengths_nm, dtype=np.float64) * 1e-3
    return 1.0 / lam_um ** 2
