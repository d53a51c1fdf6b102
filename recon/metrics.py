r"""Quality metrics for reconstructed hyperspectral cubes, and their sRGB rendering.

Every function takes cubes of shape (H, W, L) = (y, x, λ), the estimate first and the reference
("truth") second.  Arithmetic is done in float64 so that the metrics do not depend on the
precision of the inputs.

Scaling conventions (they change the numbers, so they are spelled out):

- :func:`psnr`, :func:`ssim` and :func:`rmse` (with ``scale=True``) divide *both* cubes by the
  maximum of the reference, :math:`s = \max(\text{truth})`.  A non-negative reference then lies
  in [0, 1] and a peak (data range) of 1 is used.  For the CASSI benchmark cubes (KAIST, CAVE as
  distributed by MST/TSA-Net), which are already in [0, 1] with maximum 1, this is the usual
  global PSNR.
- :func:`psnr_bandwise` follows the paper's protocol: each band of the reference is min–max
  normalised to [0, 1]; the estimate's band is mapped with the *same* affine map (by default, so
  that a wrong offset or gain in the estimate is penalised), the PSNR with peak 1 is computed per
  band and the per-band values are averaged.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError

__all__ = [
    "psnr",
    "psnr_bandwise",
    "ssim",
    "sam",
    "rmse",
    "cube_to_xyz",
    "cube_to_srgb",
    "delta_e2000",
    "all_metrics",
]

#: PSNR reported for identical inputs (MSE = 0) is ``inf``; callers that need a finite number
#: (JSON, plots) can clip it.
_CMFS_NAME = "CIE 1931 2 Degree Standard Observer"


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------
#: Rows of a cube per block of the metrics' float64 work (:func:`psnr`, :func:`rmse`,
#: :func:`psnr_bandwise`, :func:`sam`).
_ROWS = 64


def _checked(est, truth, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The two cubes as arrays of their own dtype, checked (shapes, dtypes, finite)."""
    est = np.asarray(est)
    truth = np.asarray(truth)
    if est.ndim != 3 or truth.ndim != 3:
        raise InputError(
            f"{name}: cubes must be (H, W, L); got {est.shape} and {truth.shape}"
        )
    if est.shape != truth.shape:
        raise InputError(f"{name}: shapes differ: estimate {est.shape} vs truth {truth.shape}")
    for a, what in ((est, "estimate"), (truth, "truth")):
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise InputError(f"{name}: {what} has unsupported dtype {a.dtype}")
        if not np.all(np.isfinite(a)):
            raise InputError(f"{name}: {what} contains NaN or Inf")
    return est, truth


def _rows64(a: np.ndarray, rows: slice) -> np.ndarray:
    """Rows of a cube in float64 (a float64 copy of the whole cube would be 0.17 GB on
    `paper`): every element the value the whole cube's conversion gives it."""
    return a[rows].astype(np.float64)


def _like64(a: np.ndarray) -> np.ndarray:
    """An empty float64 array laid out in memory as ``a.astype(np.float64)`` would be, so
    that a mean over it sums in the same order as over that conversion's results."""
    return np.empty_like(a, dtype=np.float64)


def _mean_squared_difference(e: np.ndarray, t: np.ndarray, scale: float | None = None) -> float:
    """The mean of ``((e - t) / scale)**2`` (no division when ``scale`` is None) in float64, a
    block of rows at a time into one array: element by element the operations of the whole
    cubes' expression, summed in the same order, without float64 copies of both cubes."""
    d = _like64(e)
    for a in range(0, e.shape[0], _ROWS):
        rows = slice(a, a + _ROWS)
        b = np.subtract(_rows64(e, rows), _rows64(t, rows))
        if scale is not None:
            b /= scale
        np.square(b, out=d[rows])
    return float(np.mean(d))


def _global_scale(truth: np.ndarray, name: str) -> float:
    s = float(truth.max())
    if s <= 0.0:
        raise InputError(f"{name}: the reference cube has no positive value to scale by")
    return s


def _psnr_from_mse(mse: float | np.ndarray, peak: float = 1.0):
    mse = np.asarray(mse, dtype=np.float64)
    with np.errstate(divide="ignore"):
        out = 10.0 * np.log10(peak**2 / mse)
    return out


# --------------------------------------------------------------------------------------------
# intensity metrics
# --------------------------------------------------------------------------------------------
def psnr(est, truth) -> float:
    r"""Global PSNR in dB, with both cubes scaled by the reference maximum and peak 1.

    .. math::

        s = \max \text{truth},\qquad
        \mathrm{PSNR} = 10\log_{10}\frac{1}{\tfrac{1}{HWL}\sum (\hat f/s - f/s)^2}

    Returns ``inf`` for identical cubes.
    """
    e, t = _checked(est, truth, "psnr")
    mse = _mean_squared_difference(e, t, _global_scale(t, "psnr"))
    return float(_psnr_from_mse(mse))


def psnr_bandwise(est, truth, *, normalise: str = "reference", return_bands: bool = False):
    r"""The paper's PSNR: each band min–max normalised, PSNR per band (peak 1), then averaged.

    For band :math:`l` with reference range :math:`[a_l, b_l]`,

    .. math::

        \mathrm{PSNR}_l = 10\log_{10}\frac{1}{\mathrm{mean}\big((\hat f_l - a_l)/(b_l-a_l)
        - (f_l - a_l)/(b_l - a_l)\big)^2},\qquad
        \mathrm{PSNR} = \tfrac1L \sum_l \mathrm{PSNR}_l .

    Parameters
    ----------
    normalise : {"reference", "each"}
        ``"reference"`` (default) maps the estimate's band with the reference band's min and max,
        so a gain or offset error counts.  ``"each"`` min–max normalises the estimate's band by
        its own range (insensitive to per-band gain and offset).
    return_bands : bool
        Also return the (L,) per-band values.

    Notes
    -----
    A constant reference band (:math:`b_l = a_l`) is normalised by a range of 1 (offset only).
    Identical bands give ``inf``, and so does the mean if any band is identical.
    """
    e, t = _checked(est, truth, "psnr_bandwise")
    if normalise not in ("reference", "each"):
        raise InputError(f"psnr_bandwise: normalise must be 'reference' or 'each', not {normalise!r}")
    # Extremes are exact in any precision; their differences are taken in float64.
    lo = t.min(axis=(0, 1)).astype(np.float64)
    rng = t.max(axis=(0, 1)).astype(np.float64) - lo
    rng = np.where(rng > 0, rng, 1.0)
    if normalise == "reference":
        elo, erng = lo, rng
    else:
        elo = e.min(axis=(0, 1)).astype(np.float64)
        erng = e.max(axis=(0, 1)).astype(np.float64) - elo
        erng = np.where(erng > 0, erng, 1.0)
    # ((e - elo) / erng - (t - lo) / rng)**2 a block of rows at a time, into one array laid
    # out as the cubes are (the mean then sums in the same order): the same numbers as the
    # whole-cube expression, one cube-sized temporary where it would hold five.
    sq = _like64(e)
    for a in range(0, e.shape[0], _ROWS):
        rows = slice(a, a + _ROWS)
        en = np.subtract(_rows64(e, rows), elo)
        en /= erng
        tn = np.subtract(_rows64(t, rows), lo)
        tn /= rng
        en -= tn
        np.square(en, out=sq[rows])
    mse = np.mean(sq, axis=(0, 1))
    bands = _psnr_from_mse(mse)
    mean = float(np.mean(bands))
    return (mean, bands) if return_bands else mean


def ssim(est, truth, *, return_bands: bool = False):
    r"""Mean SSIM over bands, Wang et al. (2004) settings.

    Both cubes are divided by the reference maximum (data range 1); each band is compared with
    :func:`skimage.metrics.structural_similarity` using an 11×11 Gaussian window of
    :math:`\sigma = 1.5`, population covariances, :math:`K_1 = 0.01`, :math:`K_2 = 0.03`:

    .. math::

        \mathrm{SSIM}(x, y) = \frac{(2\mu_x\mu_y + C_1)(2\sigma_{xy} + C_2)}
        {(\mu_x^2 + \mu_y^2 + C_1)(\sigma_x^2 + \sigma_y^2 + C_2)},\quad
        C_i = (K_i \cdot 1)^2 .

    The images must be at least 11×11 pixels.
    """
    from skimage.metrics import structural_similarity

    from recon.kernels import each

    e, t = _checked(est, truth, "ssim")
    if min(t.shape[:2]) < 11:
        raise InputError(f"ssim: images must be at least 11x11 pixels, got {t.shape[:2]}")
    s = _global_scale(t, "ssim")

    def band(l):
        # In float64 (the values of the whole cubes' conversion, divided by s).
        return structural_similarity(t[:, :, l].astype(np.float64) / s,
                                     e[:, :, l].astype(np.float64) / s, data_range=1.0,
                                     gaussian_weights=True, sigma=1.5,
                                     use_sample_covariance=False)

    # A band a thread, a thread per CPU: the Gaussian filters release the GIL; the same
    # values, in the bands' order.
    bands = np.array(each(band, range(t.shape[2])))
    mean = float(np.mean(bands))
    return (mean, bands) if return_bands else mean


def sam(est, truth, *, return_map: bool = False):
    r"""Spectral angle mapper in degrees, averaged over pixels.

    .. math::

        \theta(x, y) = \arccos\frac{\langle \hat f(x,y), f(x,y)\rangle}
        {\lVert \hat f(x,y)\rVert\,\lVert f(x,y)\rVert}

    Pixels where either spectrum is all zero have no defined angle: they are left out of the mean
    (and are NaN in the map).  If no pixel is left, the result is NaN.
    """
    e, t = _checked(est, truth, "sam")
    # theta = 2 arcsin(|e/|e| - t/|t|| / 2): the same angle as arccos of the normalised dot
    # product, but accurate near 0 where arccos loses half the digits.  Each pixel's norms and
    # angle are its own, so they are taken in float64 a block of rows at a time (float64
    # copies of both cubes and their unit spectra would be 0.8 GB on `paper`).
    ang = np.full(e.shape[:2], np.nan)
    valid = np.zeros(e.shape[:2], bool)
    for a in range(0, e.shape[0], _ROWS):
        rows = slice(a, a + _ROWS)
        eb, tb = _rows64(e, rows), _rows64(t, rows)
        ne = np.sqrt(np.einsum("ijk,ijk->ij", eb, eb))
        nt = np.sqrt(np.einsum("ijk,ijk->ij", tb, tb))
        v = valid[rows]
        np.logical_and(ne > 0, nt > 0, out=v)
        ue = eb[v] / ne[v][:, None]
        ue -= tb[v] / nt[v][:, None]
        chord = np.linalg.norm(ue, axis=-1)
        ang[rows][v] = np.degrees(2.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0)))
    mean = float(np.mean(ang[valid])) if np.any(valid) else float("nan")
    return (mean, ang) if return_map else mean


def rmse(est, truth, *, scale: bool = False) -> float:
    r"""Root-mean-square error, :math:`\sqrt{\mathrm{mean}(\hat f - f)^2}`.

    With ``scale=True`` both cubes are first divided by the reference maximum (as for
    :func:`psnr`), so that ``psnr == -20 log10(rmse(scale=True))``.
    """
    e, t = _checked(est, truth, "rmse")
    s = _global_scale(t, "rmse") if scale else None
    return float(np.sqrt(_mean_squared_difference(e, t, s)))


# --------------------------------------------------------------------------------------------
# colour
# --------------------------------------------------------------------------------------------
def _cmfs_at(wavelengths) -> np.ndarray:
    import colour

    wl = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    cmfs = colour.MSDS_CMFS[_CMFS_NAME]
    lo, hi = cmfs.shape.start, cmfs.shape.end
    if wl.size == 0 or np.any(wl < lo) or np.any(wl > hi) or not np.all(np.isfinite(wl)):
        raise InputError(
            f"wavelengths must lie within the CIE 1931 range {lo:g}-{hi:g} nm, got "
            f"{wl.min() if wl.size else 'none'}-{wl.max() if wl.size else ''}"
        )
    return np.asarray(cmfs[wl], dtype=np.float64)  # (L, 3), linear interpolation


def _band_widths(wl: np.ndarray) -> np.ndarray:
    """Quadrature weights Δλ_l (trapezoid-like): half the distance to each neighbour."""
    if wl.size == 1:
        return np.ones(1)
    if np.any(np.diff(wl) <= 0):
        raise InputError("wavelengths must be strictly increasing")
    return np.gradient(wl)


def cube_to_xyz(cube, wavelengths) -> np.ndarray:
    r"""CIE 1931 2° XYZ of a radiance cube, with no illuminant.

    .. math::

        (X, Y, Z)(x, y) = k \sum_l f(x, y, \lambda_l)\,
        (\bar x, \bar y, \bar z)(\lambda_l)\,\Delta\lambda_l,\qquad
        k = 1 \Big/ \sum_l \bar y(\lambda_l)\,\Delta\lambda_l

    The colour-matching functions are linearly interpolated at the cube's wavelengths and
    :math:`\Delta\lambda_l` is half the distance between the neighbouring bands (the band width
    of a uniform grid).  The normalisation :math:`k` gives a flat spectrum of value 1 the
    luminance :math:`Y = 1`, whatever the band count.

    Parameters
    ----------
    cube : array (H, W, L)
    wavelengths : array (L,)
        In nm, increasing, within 360–830.

    Returns
    -------
    xyz : float64 array (H, W, 3)
    """
    cube = np.asarray(cube, dtype=np.float64)
    wl = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    if cube.ndim != 3 or cube.shape[2] != wl.size:
        raise InputError(f"cube_to_xyz: cube {cube.shape} does not match {wl.size} wavelengths")
    w = _cmfs_at(wl) * _band_widths(wl)[:, None]
    w /= w[:, 1].sum()
    return cube @ w


def _white_xyz(xyz: np.ndarray, wavelengths, white) -> np.ndarray | None:
    if white is None:
        return None
    if isinstance(white, str):
        if white == "flat":
            # XYZ of a flat unit spectrum sampled at these wavelengths (equal-energy white).
            return cube_to_xyz(np.ones((1, 1, np.size(wavelengths))), wavelengths)[0, 0]
        if white == "gray-world":
            return xyz.reshape(-1, 3).mean(axis=0)
        raise InputError(f"white must be 'flat', 'gray-world', None or an XYZ triple, not {white!r}")
    return np.asarray(white, dtype=np.float64).reshape(3)


def _xyz_to_linear_srgb(xyz: np.ndarray, white_xyz: np.ndarray | None) -> np.ndarray:
    import colour

    if white_xyz is not None:
        # Bradford (von Kries) adaptation from the scene white to D65, the sRGB white; the
        # scene white keeps its luminance.
        d65 = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS[_CMFS_NAME]["D65"]) * white_xyz[1]
        m = colour.adaptation.matrix_chromatic_adaptation_VonKries(
            white_xyz, d65, transform="Bradford"
        )
        xyz = xyz @ np.asarray(m).T
    m_rgb = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB)
    return xyz @ m_rgb.T


def _render(cube, wavelengths, white, peak, gamma):
    xyz = cube_to_xyz(cube, wavelengths)
    wxyz = _white_xyz(xyz, wavelengths, white)
    if wxyz is not None and (not np.all(np.isfinite(wxyz)) or wxyz[1] <= 0):
        raise InputError("cube_to_srgb: the white point has no positive luminance")
    if peak is None:
        peak = float(np.percentile(xyz[..., 1], 99.0))
    peak = float(peak)
    if not np.isfinite(peak) or peak <= 0:
        peak = 1.0  # an all-black cube renders black
    rgb = np.clip(_xyz_to_linear_srgb(xyz / peak, wxyz), 0.0, 1.0)
    return rgb, peak


def cube_to_srgb(cube, wavelengths, *, white="flat", peak=None,
                 gamma: float | str = 2.2) -> np.ndarray:
    r"""Display sRGB rendering of a radiance cube, values in [0, 1].

    Steps: :func:`cube_to_xyz`; exposure: divide by ``peak`` (default: the 99th percentile of
    Y, so a few hot pixels do not darken the image); white balance by a Bradford adaptation from
    the chosen scene white to D65; the sRGB (linear) primaries; clip to [0, 1]; display encoding
    :math:`v^{1/\gamma}` with :math:`\gamma = 2.2`, or the sRGB curve of IEC 61966-2-1
    (:math:`12.92\,v` up to :math:`v = 0.0031308`, :math:`1.055\,v^{1/2.4} - 0.055` above).

    Parameters
    ----------
    white : {"flat", "gray-world"} or None or array (3,)
        Scene white: ``"flat"`` (default) takes the XYZ of an equal-energy spectrum on the cube's
        wavelengths, so a flat spectrum renders neutral grey; ``"gray-world"`` the mean XYZ of
        the image; ``None`` no balance (an equal-energy spectrum then looks slightly pink);
        an explicit XYZ triple.
    peak : float, optional
        Luminance mapped to 1.
    gamma : float or "srgb"
        Display gamma (1 gives linear sRGB), or ``"srgb"``: the standard's encoding curve
        (what an sRGB file's values mean).

    Returns
    -------
    rgb : float32 array (H, W, 3)
    """
    if isinstance(gamma, str) and gamma != "srgb":
        raise InputError(f"gamma must be a number or 'srgb', not {gamma!r}")
    rgb, _ = _render(cube, wavelengths, white, peak, 1.0)
    if gamma == "srgb":
        rgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * rgb ** (1 / 2.4) - 0.055)
    else:
        rgb = np.power(rgb, 1.0 / gamma)
    return rgb.astype(np.float32)


def delta_e2000(cube_a, cube_b, wavelengths, *, white="flat", peak=None):
    r"""CIEDE2000 colour difference of the sRGB renderings of two cubes.

    Both cubes are rendered as in :func:`cube_to_srgb` with the *same* exposure (``peak``,
    by default taken from ``cube_b``, the reference) and white balance (taken from ``cube_b``
    for ``"gray-world"``), clipped to the sRGB gamut, converted back to XYZ and to CIELAB with
    the D65 white, and compared pixel by pixel with :math:`\Delta E_{00}`.  The gamma encoding
    plays no part: it is undone exactly before the comparison.

    Returns
    -------
    mean : float
        Mean :math:`\Delta E_{00}` over pixels.
    per_pixel : float64 array (H, W)
    """
    import colour

    a = np.asarray(cube_a)
    b = np.asarray(cube_b)
    if a.shape != b.shape or a.ndim != 3:
        raise InputError(f"delta_e2000: cube shapes differ or are not (H, W, L): {a.shape} vs {b.shape}")
    xyz_b = cube_to_xyz(b, wavelengths)
    wxyz = _white_xyz(xyz_b, wavelengths, white)
    rgb_b, peak = _render(b, wavelengths, wxyz, peak, 1.0)
    rgb_a, _ = _render(a, wavelengths, wxyz, peak, 1.0)
    m = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ)
    wp = colour.CCS_ILLUMINANTS[_CMFS_NAME]["D65"]
    lab_a = colour.XYZ_to_Lab(rgb_a @ m.T, wp)
    lab_b = colour.XYZ_to_Lab(rgb_b @ m.T, wp)
    de = np.asarray(colour.delta_E(lab_a, lab_b, method="CIE 2000"), dtype=np.float64)
    return float(de.mean()), de


def all_metrics(est, truth, wavelengths=None) -> dict:
    """Every metric in this module as a JSON-friendly dict.

    Keys: ``psnr`` (global, see :func:`psnr`), ``psnr_bandwise`` (the paper's protocol),
    ``ssim``, ``sam_deg``, ``rmse`` (unscaled), and, when ``wavelengths`` are given and lie in the
    visible range, ``delta_e2000``.  SSIM is omitted (None) for images smaller than 11×11.
    """
    out = {
        "psnr": psnr(est, truth),
        "psnr_bandwise": psnr_bandwise(est, truth),
        "ssim": None,
        "sam_deg": sam(est, truth),
        "rmse": rmse(est, truth),
    }
    if min(np.shape(truth)[:2]) >= 11:
        out["ssim"] = ssim(est, truth)
    if wavelengths is not None:
        wl = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
        if wl.size == np.shape(truth)[2] and wl.min() >= 360.0 and wl.max() <= 830.0:
            out["delta_e2000"] = delta_e2000(est, truth, wl)[0]
    return out
