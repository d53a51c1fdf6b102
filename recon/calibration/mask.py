r"""Per-band mask images ("shifted masks") from monochromatic captures of a uniform white target.

Under a spatially uniform white of band :math:`l` the sensor records, inside view :math:`k`'s
box, :math:`I_{k,l} = E_l\, C_{k,l}` (plus dark level and noise): the band's illumination times
the calibrated mask image :math:`C_{k,l}` — the view's part of the mask, shifted by the band's
dispersion, with the view's throughput and blur — which is exactly what the calibrated operator
multiplies by.  :math:`E_l` is unknown, so every band is divided by its white level

.. math:: w_l = \mathrm{P}_{99}\{ I_{k,l}(p) : p \text{ open, all views } k \},

one level for all views so that their relative throughput (mirror losses, vignetting) stays in
:math:`C`; the result is clipped to [0, 1].  The absolute per-band scale is restored later by
the radiometric gains.

When the imaging lens blurs the mask (diffraction), :func:`mask_images` can first undo it with
an Airy kernel of first-zero radius :math:`R = 1.22\, \lambda N` (:math:`N = f/d`), converted
to pixels: by default with a total-variation-regularised deconvolution
(:func:`tv_deconvolve`, FISTA started from the Wiener filter's result), or with a Wiener
(Tikhonov) filter alone (:func:`wiener_deconvolve`), or with Richardson–Lucy
(:func:`deconvolve`: the kernels of :mod:`recon.kernels.deconvolve`,
``skimage.restoration.richardson_lucy`` as their reference).  Richardson–Lucy converges slowly
where the blur is widest (the reddest bands).  The filter must trade the capture noise it lets
through against the ringing and smoothing it leaves at the cells' edges; the TV term takes the
noise off the flat cells and keeps their edges, and the reconstructions from its masks are the
better ones (``docs/calibration.md``).
"""

from __future__ import annotations

import numpy as np
from scipy.special import j1

from recon import kernels
from recon.calibration.views import as_frame_stack, check_boxes, crop
from recon.errors import InputError

#: First zero of J1: the Airy pattern (2 J1(x)/x)^2 vanishes first at x = 3.8317.
_AIRY_ZERO = 3.831705970207512

#: The mask images' deconvolutions (:func:`white_views`).
DECONVOLUTIONS = ("tv", "wiener", "richardson-lucy")

#: :math:`\lambda` of :func:`wiener_deconvolve` on crops scaled to a unit maximum.  The mask
#: images' own error is least near 10⁻³ on ``paper`` (4 averaged captures per band), but a
#: reconstruction prefers them smoother: the capture noise the filter lets through is what
#: costs most there.
WIENER_BALANCE = 1e-2

#: :math:`\mu` of :func:`tv_deconvolve` (crops scaled to a unit maximum) and its FISTA
#: iterations from the Wiener filter's result.  Chosen by the reconstructions of five ``paper``
#: views of the natural scene: too little TV lets the capture noise through, too much lowers
#: the contrast of the 2×2-pixel cells.
TV_WEIGHT = 1e-2
TV_ITERATIONS = 40


def airy_radius_px(wavelength_nm, f_number: float, pixel_um: float) -> np.ndarray:
    r"""Airy first-zero radius in pixels, :math:`R = 1.22\, \lambda N / p`.

    With :math:`R = 1.22\, L \lambda / d` and the sensor at the focal distance
    :math:`L = f`, :math:`d = f/N` gives :math:`R = 1.22\, \lambda N`.

    Parameters
    ----------
    wavelength_nm : float or array
    f_number : float
        Working f-number of the lens that images the mask onto the sensor.
    pixel_um : float
        Sensor pixel pitch in µm.
    """
    if not (f_number > 0 and pixel_um > 0):
        raise InputError(f"f_number and pixel_um must be positive, got {f_number}, {pixel_um}")
    lam_um = np.asarray(wavelength_nm, dtype=np.float64) * 1e-3
    return 1.22 * lam_um * f_number / pixel_um


def airy_kernel(radius_px: float, support: float = 2.0, oversample: int = 5) -> np.ndarray:
    r"""Normalised Airy point-spread function on the pixel grid.

    :math:`\mathrm{PSF}(r) \propto (2 J_1(x)/x)^2` with :math:`x = 3.8317\, r / R`, averaged
    over each pixel (``oversample``² sub-samples), truncated at ``support`` × R and summing to 1.

    Parameters
    ----------
    radius_px : float
        First-zero radius :math:`R` in pixels (> 0).
    support : float
        Kernel half-width in units of R (at least one pixel).
    oversample : int
        Sub-samples per pixel side.

    Returns
    -------
    (2n+1, 2n+1) float64
    """
    if not (np.isfinite(radius_px) and radius_px > 0):
        raise InputError(f"Airy radius must be positive, got {radius_px}")
    n = max(1, int(np.ceil(support * radius_px)))
    s = (np.arange(oversample) + 0.5) / oversample - 0.5
    ax = (np.arange(-n, n + 1)[:, None] + s[None, :]).ravel()
    yy, xx = np.meshgrid(ax, ax, indexing="ij")
    x = _AIRY_ZERO * np.hypot(xx, yy) / radius_px
    with np.errstate(invalid="ignore", divide="ignore"):
        psf = np.where(x > 1e-8, (2.0 * j1(x) / x) ** 2, 1.0)
    m = 2 * n + 1
    psf = psf.reshape(m, oversample, m, oversample).mean(axis=(1, 3))
    return psf / psf.sum()


def white_levels(views: np.ndarray, open_fraction: float = 0.5,
                 percentile: float = 99.0) -> np.ndarray:
    r"""Per-band white level :math:`w_l` of (K, L, h, w) view crops.

    Open pixels are those above ``open_fraction`` × the band's 99.9th percentile; the level is
    the ``percentile``-th percentile of those (all views together).
    """
    k, n_bands = views.shape[:2]
    out = np.empty(n_bands, dtype=np.float64)
    for l in range(n_bands):
        band = views[:, l].ravel()
        top = float(np.percentile(band, 99.9))
        if not top > 0:
            raise InputError(f"white capture of band {l} is dark")
        out[l] = float(np.percentile(band[band > open_fraction * top], percentile))
    return out


def mask_images(white_captures, view_boxes, dark=None, airy_radius=None, rl_iterations: int = 30,
                percentile: float = 99.0, progress: bool = False, deconvolution: str = "tv",
                balance: float = WIENER_BALANCE, tv_weight: float = TV_WEIGHT) -> np.ndarray:
    r"""Every view's mask image per band, normalised to [0, 1].

    Parameters
    ----------
    white_captures : (L, H, W) or (L, N, H, W) array_like
        Monochromatic captures of a uniform white target, one per band (or N repeats per band,
        averaged to lower the noise).
    view_boxes : (K, 4) array_like
        ``y0, x0, h, w`` per view, all the same size
        (:func:`~recon.calibration.views.find_view_boxes`).
    dark : (H, W) array_like, optional
        Dark frame subtracted first.
    airy_radius : float or (L,) array_like, optional
        Airy first-zero radius in pixels per band (:func:`airy_radius_px`); when given, every
        view and band is deconvolved before normalisation.
    rl_iterations : int
        Richardson–Lucy iterations.
    percentile : float
        Percentile of the open pixels taken as the white level (see the module docstring).
    progress : bool
        A progress bar over the deconvolved crops.
    deconvolution : {"tv", "wiener", "richardson-lucy"}
        :func:`tv_deconvolve`, :func:`wiener_deconvolve` or :func:`deconvolve` (module notes).
    balance : float
        The Wiener filter's :math:`\lambda` (:data:`WIENER_BALANCE`; also the TV
        deconvolution's start).
    tv_weight : float
        The TV deconvolution's :math:`\mu` (:data:`TV_WEIGHT`).

    Returns
    -------
    (K, L, Hv, Wm) float32
        :math:`C_{k,l}` in box coordinates.

    Raises
    ------
    InputError
        Bad shapes, boxes of different sizes or outside the frame, non-positive radii.
    """
    views = white_views(white_captures, view_boxes, dark, airy_radius, rl_iterations, progress,
                        deconvolution, balance, tv_weight)
    return normalise_mask_images(views, percentile)


def normalise_mask_images(views: np.ndarray, percentile: float = 99.0) -> np.ndarray:
    """(K, L, h, w) float32 white crops divided, in place, by their bands' white levels
    (:func:`white_levels`, all views together) and clipped to [0, 1]: the mask images."""
    levels = white_levels(views, percentile=percentile)
    # In place: the (K, L, h, w) stack is the calibration's largest array (0.45 GB for five
    # paper views), so no second one is made.
    views /= levels.astype(np.float32)[None, :, None, None]
    return np.clip(views, 0.0, 1.0, out=views)


def view_masks(white_captures, view_boxes, tap_start, tap_weights, view_width: int, *,
               dark=None, airy_radius=None, rl_iterations: int = 30, percentile: float = 99.0,
               rounds: int = 3, iterations: int = 100, deconvolution: str = "wiener",
               balance: float = WIENER_BALANCE) -> tuple[np.ndarray, np.ndarray]:
    r"""Every view's mask :math:`M_k` in view coordinates, jointly from all per-band whites.

    Under the uniform white of band :math:`l` the box of view :math:`k` records
    :math:`I_{k,l} = E_l\, D_{k,l} M_k` (the mask, then the band's dispersion smear
    :math:`D_{k,l}`, :class:`~recon.operators.smeared.SmearedCassi`).  With
    :math:`C_{k,l} = I_{k,l} / w_l` (:func:`white_levels`) and per-band scales
    :math:`\alpha_l` (the percentile level of a band whose smear is wider than the mask cells
    is lower than :math:`E_l`), each view's mask solves

    .. math:: \min_{0 \le M_k \le u} \sum_l \|\alpha_l D_{k,l} M_k - C_{k,l}\|^2,

    row by row with one normal matrix :math:`N_k = \sum_l \alpha_l^2 D_{k,l}^\top D_{k,l}`
    (:math:`W_v \times W_v`, shared by the rows): the unconstrained solution
    :math:`M_k = B_k N_k^{-1}` clipped, then accelerated projected-gradient steps
    :math:`M \leftarrow \Pi(M - (MN - B)/\|N\|)` for all rows at once.  Then
    :math:`\alpha_l = \sum_k\langle D M_k, C_{k,l}\rangle / \sum_k\|D M_k\|^2` and the masks are
    scaled so that their open level (``percentile`` of the open pixels, all views) is 1; this
    alternates ``rounds`` times, the last one with the bound :math:`u = 1` (before it
    :math:`u = \infty`, so that the scale is not clipped away).  Averaging over all bands lowers
    the noise of :math:`M_k` below that of any one capture.

    Parameters
    ----------
    white_captures : (L, H, W) or (L, N, H, W) array_like
        As for :func:`mask_images`.
    view_boxes : (K, 4) array_like
    tap_start : (K, L) array_like of int
        First box column of each band's kernel (view column 0 lands there with the first tap).
    tap_weights : (K, L, T) array_like
        The kernels (:func:`~recon.operators.smeared.taps_from_positions`).
    view_width : int
        :math:`W_v`; every kernel must fit: :math:`s + j + W_v \le W_m`.
    dark, airy_radius, rl_iterations, percentile, deconvolution, balance
        As for :func:`mask_images`; the deconvolution is the Wiener filter by default here, the
        one this model was measured with; the TV deconvolution is not measured with it.
    rounds : int
        Alternations between the masks and the per-band scales (>= 1).
    iterations : int
        Projected-gradient iterations per solve.

    Returns
    -------
    masks : (K, Hv, Wv) float32
        :math:`M_k` in [0, 1] (relative view throughput kept, as in :func:`mask_images`).
    levels : (L,) float64
        Effective white level of each band: DN at an open mask pixel, :math:`w_l \alpha_l`,
        so that :math:`I_{k,l} \approx \mathrm{levels}_l\, D_{k,l} M_k`.
    """
    from recon.operators.smeared import smear_matrix

    views = white_views(white_captures, view_boxes, dark, airy_radius, rl_iterations,
                        deconvolution=deconvolution, balance=balance)
    k_, n_bands, hv, wm = views.shape
    start = np.asarray(tap_start)
    weights = np.asarray(tap_weights, dtype=np.float64)
    wv = int(view_width)
    if start.shape != (k_, n_bands) or weights.ndim != 3 or weights.shape[:2] != (k_, n_bands):
        raise InputError(f"tap_start must be (K={k_}, L={n_bands}) and tap_weights "
                         f"(K, L, T), got {start.shape} and {weights.shape}")
    if not 1 <= wv <= wm:
        raise InputError(f"view_width must be in 1..{wm}, got {view_width}")
    if rounds < 1 or iterations < 0:
        raise InputError(f"rounds must be >= 1 and iterations >= 0, got {rounds}, {iterations}")
    reach = start + np.array([[np.max(np.nonzero(w)[0], initial=0) for w in row]
                              for row in weights])
    if np.min(start) < 0 or np.max(reach) + wv > wm:
        raise InputError(f"smear kernels reach column {int(np.max(reach))}: with view width "
                         f"{wv} they do not fit in boxes {wm} px wide")
    levels = white_levels(views, percentile=percentile)
    c = views / levels[None, :, None, None]
    d = [[smear_matrix(int(start[k, l]), weights[k, l], wv, wm) for l in range(n_bands)]
         for k in range(k_)]                                         # (Wm, Wv) each
    alpha = np.ones(n_bands)
    masks = np.zeros((k_, hv, wv))
    for r in range(rounds):
        upper = 1.0 if r == rounds - 1 else np.inf
        for k in range(k_):
            n = sum(alpha[l] ** 2 * d[k][l].T @ d[k][l] for l in range(n_bands))
            b = sum(alpha[l] * c[k, l] @ d[k][l] for l in range(n_bands))      # (Hv, Wv)
            masks[k] = _box_lsq(n, b, upper, iterations)
        pred = np.einsum("khv,klmv->klhm", masks, np.asarray(d))            # D_kl M_k
        num = np.einsum("klhm,klhm->l", pred, c)
        den = np.einsum("klhm,klhm->l", pred, pred)
        if not np.all(den > 0):
            raise InputError("white captures: a band's mask model is dark everywhere")
        alpha = num / den
        if r < rounds - 1:
            top = float(np.percentile(masks, 99.9))
            if not top > 0:
                raise InputError("white captures: the recovered masks are dark")
            q = float(np.percentile(masks[masks > 0.5 * top], percentile))
            masks /= q
            alpha *= q
    return masks.astype(np.float32), levels * alpha


def white_views(white_captures, view_boxes, dark=None, airy_radius=None,
                rl_iterations: int = 30, progress: bool = False,
                deconvolution: str = "tv", balance: float = WIENER_BALANCE,
                tv_weight: float = TV_WEIGHT) -> np.ndarray:
    """(K, L, h, w) float32 non-negative view crops of the per-band whites
    (:func:`view_stack`), deconvolved in place when ``airy_radius`` is given: with
    ``deconvolution`` ``"tv"`` (:func:`tv_deconvolve`, ``tv_weight``, started from the Wiener
    filter with ``balance``), ``"wiener"`` (:func:`wiener_deconvolve`, ``balance``) or
    ``"richardson-lucy"`` (:func:`deconvolve`, ``rl_iterations``), with a progress bar if
    ``progress``."""
    _check_deconvolution(deconvolution)
    views = view_stack(white_captures, view_boxes, dark, "white captures")
    return deconvolve_views(views, airy_radius, rl_iterations, progress, deconvolution,
                            balance, tv_weight)


def _check_deconvolution(deconvolution: str) -> None:
    if deconvolution not in DECONVOLUTIONS:
        raise InputError(f"unknown deconvolution {deconvolution!r}; known: "
                         f"{', '.join(DECONVOLUTIONS)}")


def deconvolve_views(views: np.ndarray, airy_radius=None, rl_iterations: int = 30,
                     progress: bool = False, deconvolution: str = "tv",
                     balance: float = WIENER_BALANCE, tv_weight: float = TV_WEIGHT) -> np.ndarray:
    """:func:`white_views` of crops already taken (:func:`view_stack`'s (K, L, h, w) float32),
    in place: negative values set to zero, then each crop deconvolved as there.  A caller
    that holds the crops anyway (the flat-field gains read them) makes its mask images from
    a copy of them, without the full white frames."""
    _check_deconvolution(deconvolution)
    if views.dtype != np.float32 or views.ndim != 4:
        raise InputError(f"view crops must be (K, L, h, w) float32, got {views.dtype} "
                         f"{views.shape}")
    np.maximum(views, 0.0, out=views)
    if airy_radius is not None:
        radii = np.broadcast_to(np.asarray(airy_radius, dtype=np.float64), (views.shape[1],))
        if not np.all(radii > 0):
            raise InputError(f"Airy radii must be positive, got {radii}")
        if deconvolution == "tv":
            views = tv_deconvolve(views, radii, tv_weight, balance=balance, out=views,
                                  progress=progress)
        elif deconvolution == "wiener":
            views = wiener_deconvolve(views, radii, balance, out=views, progress=progress)
        else:
            views = deconvolve(views, radii, rl_iterations, out=views, progress=progress)
        # The filter rings a little below zero next to chrome; no light is negative.
        np.maximum(views, 0.0, out=views)
    return views


def _box_lsq(n: np.ndarray, b: np.ndarray, upper: float, iterations: int) -> np.ndarray:
    r"""Rows :math:`m` of :math:`\arg\min_{0\le m\le u} \tfrac12 m N m^\top - b\, m^\top`
    (``b`` (R, W), ``n`` (W, W) symmetric positive definite), all rows at once."""
    m = np.clip(np.linalg.solve(n, b.T).T, 0.0, upper)
    step = 1.0 / float(np.linalg.eigvalsh(n)[-1])
    y, t = m.copy(), 1.0
    for _ in range(iterations):
        m_new = np.clip(y - step * (y @ n - b), 0.0, upper)
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        y = m_new + ((t - 1.0) / t_new) * (m_new - m)
        m, t = m_new, t_new
    return m


def wiener_deconvolve(views: np.ndarray, radii: np.ndarray, balance: float = WIENER_BALANCE,
                      out: np.ndarray | None = None, progress: bool = False) -> np.ndarray:
    r"""Wiener (Tikhonov-regularised inverse) filter of (K, L, h, w) crops with the band's Airy
    kernel :math:`k` (:func:`airy_kernel` cut at three radii).

    Each crop, scaled to a unit maximum and reflect-padded by the kernel half-width, becomes

    .. math:: u = \mathcal{F}^{-1}\Big[\frac{\overline{\hat k}\, \hat d}
              {|\hat k|^2 + \lambda}\Big],

    the minimiser of :math:`\|k * u - d\|^2 + \lambda \|u\|^2` (white noise over a white
    signal; ``skimage.restoration.wiener`` with the identity as its regulariser), cropped and
    scaled back.  One pass, where Richardson–Lucy needs hundreds of iterations to sharpen the
    widest kernels (module notes).

    Parameters
    ----------
    views, radii, out, progress
        As for :func:`deconvolve`.
    balance : float
        :math:`\lambda > 0` (:data:`WIENER_BALANCE`).

    Returns
    -------
    (K, L, h, w) ndarray
        ``out``.
    """
    from skimage.restoration import wiener

    _check_positive(balance, "the Wiener balance")
    identity = np.ones((1, 1), np.float32)

    def solve(p, psf):
        # float32 throughout (complex64 spectra): a paper crop's transforms are the
        # calibration's largest temporaries at this step.
        return wiener(p, psf.astype(np.float32), float(balance), reg=identity, clip=False)

    return _crop_by_crop(views, radii, out, progress, solve, support=3.0, float32=True)


def tv_deconvolve(views: np.ndarray, radii: np.ndarray, weight: float = TV_WEIGHT,
                  iterations: int = TV_ITERATIONS, balance: float = WIENER_BALANCE,
                  out: np.ndarray | None = None, progress: bool = False) -> np.ndarray:
    r"""Total-variation-regularised deconvolution of (K, L, h, w) crops with the band's Airy
    kernel :math:`k_l` (:func:`airy_kernel` cut at three radii).

    Every crop :math:`d`, scaled to a unit maximum and reflect-padded, becomes

    .. math:: u = \arg\min_u \tfrac12 \|k_l * u - d\|^2 + \mu\, \mathrm{TV}(u)

    (isotropic TV, :class:`recon.prox.tv.TVProx`), approximated by ``iterations`` FISTA steps
    started from the Wiener filter's result (:func:`wiener_deconvolve`'s formula, balance
    :math:`\lambda`), cropped and scaled back.  The blur is circular on the padded crop and
    applied in the Fourier domain; its Lipschitz constant is :math:`\max|\hat k|^2 = 1` (a
    non-negative kernel summing to one), so every step is
    :math:`u \leftarrow \mathrm{prox}_{\mu\mathrm{TV}}(z - k^\flat * (k * z - d))`.

    Why: a mask image is the binary mask shifted by the band's dispersion, times a smooth
    throughput: flat cells with sharp edges, what TV favours.  The Wiener filter treats it as
    white noise over a white signal, so it must choose between the capture noise it lets
    through and the ringing and smoothing it leaves at the cells' edges; the TV term removes
    noise on the flat cells without blurring the edges back.

    Parameters
    ----------
    views : (K, L, h, w) ndarray
    radii : (L,) array_like
        Airy first-zero radius per band, pixels.
    weight : float
        :math:`\mu > 0` on crops scaled to a unit maximum (:data:`TV_WEIGHT`).
    iterations : int
        FISTA iterations (>= 0; 0 returns the Wiener filter's result).
    balance : float
        The starting Wiener filter's :math:`\lambda` (:data:`WIENER_BALANCE`).
    out, progress
        As for :func:`deconvolve`.

    Returns
    -------
    (K, L, h, w) ndarray
        ``out``.
    """
    import scipy.fft as sfft

    _check_positive(weight, "the TV weight")
    _check_positive(balance, "the Wiener balance")
    if not (isinstance(iterations, (int, np.integer)) and iterations >= 0):
        raise InputError(f"TV deconvolution iterations must be an integer >= 0, got {iterations}")
    out, bar = _output_and_bar(views, out, progress, "deconvolution (TV)")
    n_views, n_bands, h, w = views.shape
    psfs = [airy_kernel(float(r), support=3.0) for r in radii]
    pad = max(k.shape[0] // 2 for k in psfs)
    hp = sfft.next_fast_len(h + 2 * pad, real=True)
    wp = sfft.next_fast_len(w + 2 * pad, real=True)
    workers = kernels.cores()

    def rfft(x):
        return sfft.rfft2(x, workers=workers)

    def irfft(x):
        return inverse_rfft2(x, (hp, wp), workers)

    def irfft_unscaled(x):
        return _inverse_rfft2_unscaled(x, (hp, wp), workers)

    # The transfer functions, one per band, shared by the views: each kernel centred on the
    # origin of the padded (circular) domain.
    tf = np.empty((n_bands, hp, wp // 2 + 1), np.complex64)
    for l, psf in enumerate(psfs):
        n = psf.shape[0] // 2
        z = np.zeros((hp, wp), np.float32)
        z[:2 * n + 1, :2 * n + 1] = psf
        tf[l] = rfft(np.roll(z, (-n, -n), axis=(0, 1)))
    power = (tf.real ** 2 + tf.imag ** 2).astype(np.float32)
    # Bands in chunks: every array of the solve is (chunk, hp, wp), ~32 MB each.
    chunk = max(1, min(n_bands, (8 << 20) // (hp * wp)))
    with bar:
        for k in range(n_views):
            for b0 in range(0, n_bands, chunk):
                sl = slice(b0, min(b0 + chunk, n_bands))
                crops = views[k, sl]
                tops = crops.reshape(crops.shape[0], -1).max(axis=1).astype(np.float32)
                lit = tops > 0
                scale = np.where(lit, tops, 1.0).astype(np.float32)[:, None, None]
                d = np.pad((crops / scale).astype(np.float32, copy=False),
                           ((0, 0), (pad, hp - h - pad), (pad, wp - w - pad)), mode="reflect")
                kd = np.conj(tf[sl]) * rfft(d)            # k^flat * d, in Fourier
                del d
                u = irfft(kd / (power[sl] + np.float32(balance))).astype(np.float32)
                u = _fista_tv_deconvolve(u, kd, power[sl], float(weight), int(iterations),
                                         rfft, irfft_unscaled,
                                         _inverse_factor(np.float32, (hp, wp)))
                u = u[:, pad:pad + h, pad:pad + w] * scale
                u[~lit] = 0.0
                out[k, sl] = u
                bar.update(crops.shape[0])
    return out


def inverse_rfft2(x: np.ndarray, shape, workers: int | None = None) -> np.ndarray:
    r""":func:`scipy.fft.irfft2` ``(x, s=shape)`` over the last two axes, to the bit, in two
    calls: the inverse complex transform along the rows' axis, then the complex-to-real one
    along the last axis, both unscaled, then the factor :math:`1/(h w)`.

    That is how the library's one call computes it (a complex pass over the leading axis,
    then the real one with the factor), so every value is the same; the one call is the
    slower (docs/speed_product.md, "Calibration time"), and its time varies from call to
    call on a batch of crops.
    """
    out = _inverse_rfft2_unscaled(x, shape, workers)
    out *= _inverse_factor(out.dtype, shape)
    return out


def _inverse_rfft2_unscaled(x: np.ndarray, shape, workers: int | None) -> np.ndarray:
    """:func:`inverse_rfft2` without its factor :func:`_inverse_factor`."""
    import scipy.fft as sfft

    h, w = (int(n) for n in shape)
    t = sfft.ifft(x, n=h, axis=-2, norm="forward", workers=workers)
    return sfft.irfft(t, n=w, axis=-1, norm="forward", workers=workers, overwrite_x=True)


def _inverse_factor(dtype, shape):
    """The inverse transform's :math:`1/(h w)` in ``dtype``, as the library applies it."""
    h, w = (int(n) for n in shape)
    return np.dtype(dtype).type(1.0 / (h * w))


def _check_positive(value, what: str) -> None:
    if not (np.isfinite(value) and value > 0):
        raise InputError(f"{what} must be positive, got {value}")


def _fista_tv_deconvolve(u, kd, power, weight, iterations, rfft, irfft_unscaled, factor):
    r"""FISTA for :math:`\tfrac12\|k * u - d\|^2 + \mu\mathrm{TV}(u)` from ``u``, step 1,
    with ``kd`` = :math:`\hat k^* \hat d` and ``power`` = :math:`|\hat k|^2` (bands along
    the first axis, each with its own kernel); ``irfft_unscaled`` the inverse transform
    without its ``factor``.

    The element-wise passes between the transforms run as threaded kernels that give the
    NumPy expressions' bits (:mod:`recon.kernels.deconvolve`) where the kernels run, else as
    those expressions (the reference)."""
    from recon.prox.tv import TVProx

    if iterations == 0:
        return u
    prox = TVProx(u.shape)
    z = u.copy()
    v = np.empty_like(u)
    nxt = np.empty_like(u)
    t = 1.0
    # tv_deconvolve's arrays are float32 and complex64, its factor float32: the kernels run
    # wherever Numba does.
    fused = kernels.usable(u, power)
    if fused:
        from recon.kernels import deconvolve as kdec

        power_f = power.reshape(-1)
        kd_f = kd.reshape(-1).view(np.float32)
    for _ in range(iterations):
        spec = rfft(z)
        if fused:
            with kernels.threads():
                kdec.residual_spectrum(spec.reshape(-1).view(np.float32), power_f, kd_f)
            r = irfft_unscaled(spec)
            with kernels.threads():
                kdec.residual(z.reshape(-1), r.reshape(-1), factor, v.reshape(-1))
        else:
            spec *= power
            spec -= kd
            r = irfft_unscaled(spec)
            r *= factor
            np.subtract(z, r, out=v)
        # Two warm dual iterations per step: an even count (recon.prox.tv's notes).
        prox(v, weight, n_iter=2, out=nxt)
        t_next = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        c = np.float32((t - 1.0) / t_next)
        if fused:
            with kernels.threads():
                kdec.momentum(nxt.reshape(-1), u.reshape(-1), c, z.reshape(-1))
        else:
            np.subtract(nxt, u, out=z)
            z *= c
            z += nxt
        u, nxt = nxt, u
        t = t_next
    return u


def deconvolve(views: np.ndarray, radii: np.ndarray, iterations: int = 30,
               out: np.ndarray | None = None, progress: bool = False) -> np.ndarray:
    r"""Richardson–Lucy deconvolution of (K, L, h, w) crops with the band's Airy kernel.

    Each crop is scaled to a unit maximum (RL's multiplicative update needs a non-negative image
    and skimage clips to [-1, 1]), reflected-padded by the kernel half-width :math:`n` so that
    the box edge does not ring, deconvolved from the estimate :math:`u_0 = 1/2`,

    .. math:: u \leftarrow u \odot \Bigl(k^\flat * \frac{d}{k * u + \epsilon}\Bigr)
              \quad (\epsilon = 10^{-12}),

    cropped and scaled back.  With Numba (:mod:`recon.kernels`) the two convolutions of every
    iteration run as direct correlations in float32 (:mod:`recon.kernels.deconvolve`: the Airy
    kernels are 7x7 to 11x11, where that beats the FFTs ``scipy.signal.convolve`` picks);
    otherwise, and inside :func:`recon.kernels.numpy_only`, through
    ``skimage.restoration.richardson_lucy``, their tested reference.

    Parameters
    ----------
    views : (K, L, h, w) ndarray
    radii : (L,) array_like
        Airy first-zero radius per band, pixels.
    iterations : int
    out : (K, L, h, w) ndarray, optional
        Where to write the result; may be ``views`` (deconvolved in place, crop by crop: the
        calibration holds no second stack).  Default: a new float32 array.
    progress : bool
        Report progress over the crops on stderr (:func:`recon.progress.progress_bar`).

    Returns
    -------
    (K, L, h, w) ndarray
        ``out``.
    """
    if iterations < 1:
        raise InputError(f"rl_iterations must be >= 1, got {iterations}")
    fast = kernels.enabled()

    def solve(p, psf):
        return (_richardson_lucy(p, psf, iterations) if fast
                else _skimage_rl(p, psf, iterations))

    return _crop_by_crop(views, radii, out, progress, solve, float32=fast)


def _crop_by_crop(views, radii, out, progress, solve, *, support: float = 2.0,
                  float32: bool = False):
    """``solve(padded crop / its maximum, band's Airy kernel)`` for every crop of (K, L, h, w)
    ``views`` into ``out``, scaled back (a dark crop stays 0); the crop reflect-padded by the
    kernel half-width so that its edge does not ring."""
    out, bar = _output_and_bar(views, out, progress, "deconvolution")
    with bar:
        for l in range(views.shape[1]):
            psf = airy_kernel(float(radii[l]), support=support)
            pad = psf.shape[0] // 2
            for k in range(views.shape[0]):
                v = views[k, l]
                top = float(v.max())
                if top > 0:
                    p = np.pad(v / np.float32(top) if float32 else v / top, pad, mode="reflect")
                    d = solve(p, psf)
                    np.multiply(d[pad:pad + v.shape[0], pad:pad + v.shape[1]], top,
                                out=out[k, l], casting="unsafe")
                else:
                    out[k, l] = 0.0
                bar.update(1)
    return out


def _output_and_bar(views, out, progress: bool, desc: str):
    """``out`` for (K, L, h, w) ``views`` (a new float32 stack when None; refused when its
    shape differs) and a progress bar over the crops, silent unless ``progress``."""
    from recon.progress import progress_bar

    out = np.empty(views.shape, dtype=np.float32) if out is None else out
    if out.shape != views.shape:
        raise InputError(f"out has shape {out.shape}, views {views.shape}")
    bar = progress_bar(total=views.shape[0] * views.shape[1], desc=desc, unit="crop",
                       show=progress)
    return out, bar


def _skimage_rl(image, psf, iterations):
    """The reference: ``skimage.restoration.richardson_lucy`` without clipping."""
    from skimage.restoration import richardson_lucy

    return richardson_lucy(image, psf, num_iter=iterations, clip=False)


def _richardson_lucy(image, psf, iterations):
    """``skimage.restoration.richardson_lucy(image, psf, iterations, clip=False)`` in float32
    through :mod:`recon.kernels.deconvolve`."""
    from recon.kernels import deconvolve as kdec

    d = np.ascontiguousarray(image, dtype=np.float32)
    k = np.ascontiguousarray(psf, dtype=np.float32)
    kflip = np.ascontiguousarray(k[::-1, ::-1])
    u = np.full(d.shape, 0.5, dtype=np.float32)
    r = np.empty_like(u)
    eps = np.float32(1e-12)
    with kernels.threads():
        for _ in range(iterations):
            kdec.ratio(u, d, kflip, eps, r)          # r = d / (k * u + eps)
            kdec.update(u, r, k)                     # u *= k_flip * r
    return u


def view_stack(captures, view_boxes, dark=None, name: str = "captures") -> np.ndarray:
    """Crop (L, H, W) or (L, N, H, W) captures to (K, L, h, w) float32 view stacks.

    Repeats (N) are averaged and the dark frame subtracted on the crops only, so memory stays
    proportional to the views, not to L full frames.  float32, like the captures: a float64
    stack of the paper design's five views would be 0.9 GB, and every step that sums over it
    accumulates in float64 itself.
    """
    caps = np.asarray(captures)
    if caps.ndim == 4:
        caps = caps.mean(axis=1, dtype=np.float32)
    caps = as_frame_stack(caps, name)
    boxes = check_boxes(view_boxes, caps.shape[1:])
    d = None
    if dark is not None:
        d = as_frame_stack(dark, "dark frame").mean(axis=0)
        if d.shape != caps.shape[1:]:
            raise InputError(f"dark frame shape {d.shape} != capture shape {caps.shape[1:]}")
    out = np.stack([crop(caps, b) for b in boxes])
    if d is not None:
        out -= np.stack([crop(d, b) for b in boxes]).astype(np.float32)[:, None]
    return out
