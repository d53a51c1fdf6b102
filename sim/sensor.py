"""The monochrome sensor: a NumPy post-process from spectral irradiance to 12-bit raw counts.

For band *l* (centre :math:`\\lambda_l`, width :math:`\\Delta\\lambda_l`) with spectral irradiance
:math:`E_l(x, y)` in W·m⁻²·nm⁻¹ on the sensor, the mean number of photo-electrons in a pixel of
area :math:`A` during the exposure :math:`t` is

.. math:: \\bar N_e(x, y) = \\sum_l \\eta(\\lambda_l)\\,
          \\frac{\\lambda_l}{h c}\\, A\\, t\\, \\Delta\\lambda_l\\, (K_l * E_l)(x, y),

where :math:`\\Delta\\lambda_l` is the width of the band's interval that reaches the sensor
(:func:`sim.bands.band_widths`: the end bands, cut by the filter, count half), :math:`\\eta` is the quantum efficiency and :math:`K_l` the optional Airy diffraction kernel
of band *l* (first dark ring at :math:`R_l = 1.22\\, \\lambda_l N`, :math:`N` the imaging lens's
f-number, i.e. :math:`L/d`), normalised to unit sum so blur moves light but never creates or
destroys it. The recorded count is then

.. math:: N_e \\sim \\min(\\text{Poisson}(\\bar N_e), FW) + \\mathcal N(0, \\sigma_r^2), \\qquad
          \\text{DN} = \\operatorname{clip}(\\operatorname{round}(N_e / G), 0, 2^{b} - 1),

with the full well :math:`FW`, read noise :math:`\\sigma_r` (e⁻), and conversion gain
:math:`G = FW / (2^b - 1)` e⁻/DN so that a full well reads as the top code.

The QE curve ``"mono_cmos"`` is a tabulated, *plausible* monochrome silicon sensor response over
400–720 nm (peak ≈ 0.68 near 520 nm, falling to ≈ 0.38 at 400 nm and ≈ 0.34 at 720 nm), shaped like
the published curves of Sony's monochrome CCD/CMOS sensors such as the ICX814 in the paper's
Grasshopper 3. It is not a measured curve of any one device. ``"flat"`` is an ideal QE of 1.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from recon.errors import InputError
from recon.kernels import each

__all__ = [
    "QE_CURVES",
    "quantum_efficiency",
    "electron_scale",
    "airy_kernel",
    "airy_blur",
    "BlurredSum",
    "ccs_multiplier",
    "mean_electrons",
    "digitise",
    "digitise_reference",
    "capture",
]

_H = 6.62607015e-34
_C = 2.99792458e8

_QE_WL = np.arange(400.0, 721.0, 20.0)
#: Tabulated QE curves: name → (wavelengths nm, QE). Linear interpolation, held at the ends.
QE_CURVES: dict[str, tuple[np.ndarray, np.ndarray]] = {
    "mono_cmos": (
        _QE_WL,
        np.array([0.38, 0.46, 0.53, 0.59, 0.63, 0.66, 0.68, 0.67, 0.65,
                  0.62, 0.58, 0.54, 0.50, 0.46, 0.42, 0.38, 0.34]),
    ),
    "flat": (np.array([300.0, 1100.0]), np.array([1.0, 1.0])),
}


def quantum_efficiency(name: str, wavelength_nm) -> np.ndarray:
    """QE η(λ) of the tabulated curve ``name`` at ``wavelength_nm`` (float64)."""
    if name not in QE_CURVES:
        raise InputError(f"unknown QE curve {name!r}; known: {', '.join(QE_CURVES)}")
    wl, qe = QE_CURVES[name]
    return np.interp(np.asarray(wavelength_nm, dtype=np.float64), wl, qe)


def electron_scale(design, wavelengths=None, widths=None) -> np.ndarray:
    """(L,) mean photo-electrons per unit spectral irradiance (W·m⁻²·nm⁻¹) of each band:
    :math:`\\eta(\\lambda_l)\\, A\\, t\\, \\Delta\\lambda_l\\, \\lambda_l / (hc)`.

    ``widths`` defaults to :func:`sim.bands.band_widths` (each band's interval inside the filter).
    """
    from sim.bands import band_widths

    wl = design.wavelengths if wavelengths is None else np.atleast_1d(
        np.asarray(wavelengths, dtype=np.float64))
    dl = band_widths(design, wl) if widths is None else np.asarray(widths, np.float64)
    qe = quantum_efficiency(design.qe_curve, wl)
    return qe * design.pixel_area_m2 * design.exposure_ms * 1e-3 * dl * (wl * 1e-9) / (_H * _C)


def airy_kernel(radius_px: float, oversample: int = 5, rings: float = 3.0) -> np.ndarray:
    """The sensor's blur: the pixel-integrated Airy PSF with first zero at ``radius_px``
    (:func:`recon.calibration.mask.airy_kernel`, the one the calibration deconvolves with), cut
    at ``rings`` × R (past the third dark ring for the default, which holds > 99 % of the
    energy) and renormalised.

    Returns
    -------
    numpy.ndarray
        float32 (2k+1, 2k+1), k = max(1, ceil(rings·R)).
    """
    from recon.calibration.mask import airy_kernel as pixel_airy

    return pixel_airy(radius_px, support=rings, oversample=oversample).astype(np.float32)


def airy_blur(image: np.ndarray, radius_px: float | None = None, *,
              kernel: np.ndarray | None = None) -> np.ndarray:
    """Convolve a 2-D image with :func:`airy_kernel` (zero outside the image: light that
    leaves the sensor is lost). Returns float32 of the same shape, non-negative for a
    non-negative image.

    A direct convolution (OpenCV) rather than an FFT: the kernel spans a few pixels, and the
    direct sum is several times faster on a full sensor and leaves no round-off negatives.
    ``kernel`` may replace ``radius_px`` with a precomputed :func:`airy_kernel` (a video
    renders many frames).
    """
    import cv2

    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise InputError(f"airy_blur needs a 2-D image, got shape {img.shape}")
    k = airy_kernel(radius_px) if kernel is None else kernel
    # The kernel is symmetric, so OpenCV's correlation is the convolution.
    return cv2.filter2D(img, -1, k, borderType=cv2.BORDER_CONSTANT)


class BlurredSum:
    r"""The blurred, weighted sum over bands of one view's images, by FFT:

    .. math:: S = \sum_l s_l\, (K_l * E_l) = \mathcal F^{-1}\Big[\sum_l
              s_l \hat K_l\, \mathcal F(E_l)\Big],

    one forward transform per band and one inverse per view, where a direct blur costs a
    forward and an inverse per band and its kernel's transform besides.  The images are padded
    with zeros to a fast transform size at least ``h + 2R`` (``R`` the widest kernel's half
    width, :meth:`shape`), so the circular convolution is the linear one.

    The kernels are centrally symmetric (:func:`airy_kernel`): centred on the origin (wrapped),
    each has a real spectrum :math:`\hat K_l`, so a band's product is a real one, element by
    element, in OpenCV's packed layout of a real image's transform (CCS: the real and imaginary
    parts of :math:`\mathcal F(E_l)` side by side, each times :math:`\hat K_l` at its
    frequency; :func:`ccs_multiplier`).  The spectrum is kept as it is, half the size of the
    packed layout (every factor but a few stands twice there), and the products of two bands
    are added in one pass (:func:`ccs_multiply_add`); OpenCV's real transform is faster than
    SciPy's on these images (``docs/simulator.md``).  The blur of
    the image's first pixel lands ``R`` before it, wrapped to the transform's far end; the
    result is rolled back.  The result (h + 2R, w + 2R) covers the view widened by ``R``: the
    whole of its blur.  Float32 transforms: round-off ~10⁻⁷ of the peak.

    Parameters
    ----------
    kernels : list of (k, k) arrays
        Each band's kernel (odd side, normalised, centrally symmetric), or None for no blur.
    scales : (L,) array
        Each band's weight :math:`s_l`.
    """

    def __init__(self, kernels, scales):
        self.kernels = kernels
        self.scales = np.asarray(scales, np.float32)
        self._fk = {}

    def reach(self, bands) -> int:
        """R: the half width of the widest kernel among ``bands``."""
        if self.kernels is None:
            return 0
        return max(self.kernels[l].shape[0] // 2 for l in bands)

    def shape(self, h: int, w: int, bands) -> tuple[int, int]:
        """The transforms' shape for (h, w) images of ``bands``: OpenCV's fast transform sizes,
        even, at least (h + 2R, w + 2R); (h, w) itself where no band is blurred."""
        R = self.reach(bands)
        if R == 0:
            return h, w
        return _fast_even(h + 2 * R), _fast_even(w + 2 * R)

    def prepare(self, bands, shape) -> None:
        """Each band's kernel spectrum for transforms of ``shape``, computed once and kept
        (before threads take :meth:`spectrum`, which would each compute the missing ones)."""
        for l in bands:
            self._kernel_spectrum(int(l), tuple(shape))

    def _kernel_spectrum(self, l, shape):
        r"""Band ``l``'s weighted kernel spectrum :math:`s_l \hat K_l` (H, W/2 + 1) float32
        for transforms of ``shape`` (H, W), real (:func:`ccs_multiplier` lays it out)."""
        key = (l, shape)
        if key not in self._fk:
            k = np.asarray(self.kernels[l], np.float64)
            if k.ndim != 2 or k.shape[0] != k.shape[1] or k.shape[0] % 2 == 0:
                raise ValueError(f"band {l}'s kernel must be square with an odd side, "
                                 f"got {k.shape}")
            if np.abs(k - k[::-1, ::-1]).max() > 1e-6 * np.abs(k).max():
                raise ValueError(f"band {l}'s kernel is not centrally symmetric")
            # The odd part left is round-off of the kernel's own sampling: dropped, so that
            # the spectrum is real.
            k = 0.5 * (k + k[::-1, ::-1]) * float(self.scales[l])
            r = k.shape[0] // 2
            pad = np.zeros(shape, np.float64)
            pad[:k.shape[0], :k.shape[1]] = k
            pad = np.roll(pad, (-r, -r), axis=(0, 1))
            self._fk[key] = np.fft.rfft2(pad).real.astype(np.float32)
        return self._fk[key]

    def __call__(self, images, bands, size=None) -> np.ndarray:
        """:math:`S` (h + 2R, w + 2R) float32 of ``images``, the bands ``bands``.

        ``images`` is (La, h, w); or, with ``size`` = (h, w), (La, *:meth:`shape`*) holding
        the (h, w) images in its top-left corner and zeros elsewhere, transformed as they are
        (a caller that integrates straight into such a buffer spares a copy of every band).

        The bands are split between two threads in a fixed way (:func:`halves`) and their
        spectra added in a fixed order (:meth:`spectrum`, then :meth:`image`), so the result
        does not depend on which thread finishes first, nor on the number of cores."""
        bands = [int(l) for l in bands]
        h, w = images.shape[1:] if size is None else (int(size[0]), int(size[1]))
        if self.reach(bands) == 0:
            out = np.zeros((h, w), np.float32)
            for i, l in enumerate(bands):
                out += images[i, :h, :w] * self.scales[l]
            return out
        shape = self.shape(h, w, bands)
        if size is not None and images.shape[1:] != shape:
            raise ValueError(f"images of size {tuple(size)} must come padded to {shape}")
        self.prepare(bands, shape)     # before the threads
        parts = _by_halves(lambda idx: self.spectrum(images, bands, idx, (h, w)), len(bands))
        return self.image(parts, bands, (h, w))

    def spectrum(self, images, bands, part, size, work=None):
        r"""The weighted spectra of the images ``part`` (indices into ``bands``) summed,
        :math:`\sum_{i \in \text{part}} s_l \hat K_l\, \mathcal F(E_i)` in OpenCV's packed
        layout (:meth:`shape`), or None for no images; ``images`` as in :meth:`__call__`
        (padded or not).  The blurred sum is :meth:`image` of such parts: a caller may compute
        them on threads of its own, e.g. while it integrates the next view.  ``work``, three
        float32 arrays of the transforms' shape, takes the sum (returned) and the transforms
        (a caller that blurs view after view spares their allocation and first touch)."""
        import cv2

        h, w = int(size[0]), int(size[1])
        shape = self.shape(h, w, bands)
        padded = images.shape[1:] == shape
        part = list(part)
        if not part:
            return None
        pad = None if padded else np.zeros(shape, np.float32)

        def transform(i, dst=None):
            if padded:
                return cv2.dft(images[i], dst=dst)
            pad[:h, :w] = images[i]
            return cv2.dft(pad, dst=dst)

        if work is None:
            work = [np.empty(shape, np.float32) for _ in range(3)]
        first = part[0]
        acc = transform(first, work[0])
        ccs_multiply(acc, acc, self._kernel_spectrum(bands[first], shape))
        # The rest two at a time: the sum read and written once a pair, in the bands' order.
        terms = work[1:]
        for n in range(1, len(part), 2):
            pair = part[n:n + 2]
            for i, t in zip(pair, terms):
                transform(i, t)
            ks = [self._kernel_spectrum(bands[i], shape) for i in pair]
            if len(pair) == 2:
                ccs_multiply_add(acc, terms[0], ks[0], terms[1], ks[1])
            else:
                ccs_multiply_add(acc, terms[0], ks[0], terms[0], ks[0], two=False)
        return acc

    def image(self, parts, bands, size) -> np.ndarray:
        """:math:`S` (h + 2R, w + 2R) float32 from :meth:`spectrum`'s ``parts`` (added in their
        order; None for an empty part): one inverse transform, rolled back by the reach
        (:meth:`add_image` into zeros)."""
        R = self.reach(bands)
        out = np.zeros((int(size[0]) + 2 * R, int(size[1]) + 2 * R), np.float32)
        self.add_image(parts, bands, size, out, (0, 0))
        return out

    def add_image(self, parts, bands, size, total, corner, buffer=None) -> None:
        """:meth:`image` of ``parts`` added into ``total`` with its first pixel at ``corner``
        (the view's first less the reach), clipped to ``total``: the wrapped blocks of the
        inverse transform added where they belong, with no image of their own in between
        (the same sums).  ``buffer``, the transforms' shape in float32, takes the inverse."""
        import cv2

        h, w = int(size[0]), int(size[1])
        R = self.reach(bands)
        parts = [p for p in parts if p is not None]
        spec = parts[0]
        for p in parts[1:]:
            spec += p
        full = cv2.dft(spec, dst=buffer,
                       flags=cv2.DFT_INVERSE | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
        # The kernels are centred on the origin: the blur's first R rows and columns wrapped
        # to the far end.
        S0, S1 = full.shape
        H, W = total.shape
        r0, c0 = int(corner[0]), int(corner[1])
        # (first pixel of the blur, its length, where it starts in the inverse transform)
        rows = ((R, h + R, 0), (0, R, S0 - R))
        cols = ((R, w + R, 0), (0, R, S1 - R))
        for i0, n, f0 in rows:
            a0, a1 = max(r0 + i0, 0), min(r0 + i0 + n, H)
            for j0, m, g0 in cols:
                b0, b1 = max(c0 + j0, 0), min(c0 + j0 + m, W)
                if a1 > a0 and b1 > b0:
                    fa, fb = f0 + a0 - (r0 + i0), g0 + b0 - (c0 + j0)
                    total[a0:a1, b0:b1] += full[fa:fa + a1 - a0, fb:fb + b1 - b0]

    def adjoint(self, image, bands, size) -> np.ndarray:
        r"""The adjoint of :meth:`__call__`: each band's image (La, h, w) float32,

        .. math:: E_l = s_l\, (K_l \star Y)\big|_{\text{view}},

        of ``image`` :math:`Y` (h + 2R, w + 2R), the view widened by the reach (the kernels
        are symmetric: the correlation is the convolution).  One forward transform for all
        bands and one inverse per band; the bands split between two threads as there."""
        import cv2

        bands = [int(l) for l in bands]
        h, w = int(size[0]), int(size[1])
        R = self.reach(bands)
        image = np.asarray(image, np.float32)
        if image.shape != (h + 2 * R, w + 2 * R):
            raise ValueError(f"the image must be the view widened by {R}: "
                             f"{(h + 2 * R, w + 2 * R)}, got {image.shape}")
        out = np.empty((len(bands), h, w), np.float32)
        if R == 0:
            for i, l in enumerate(bands):
                np.multiply(image, self.scales[l], out=out[i])
            return out
        shape = self.shape(h, w, bands)
        fk = [self._kernel_spectrum(l, shape) for l in bands]
        pad = np.zeros(shape, np.float32)
        pad[:h + 2 * R, :w + 2 * R] = image
        F = cv2.dft(pad)
        flags = cv2.DFT_INVERSE | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE

        def half(idx):
            prod = np.empty(shape, np.float32)
            back = np.empty(shape, np.float32)
            for i in idx:
                # The kernels are centred on the origin: view pixel (i, j) is the blur's
                # (i + R, j + R), and no sum wraps (the transform is at least h + 2R).
                ccs_multiply(prod, F, fk[i])
                cv2.dft(prod, dst=back, flags=flags)
                out[i] = back[R:R + h, R:R + w]

        _by_halves(half, len(bands))
        return out


def _by_halves(fn, n: int) -> list:
    """``fn`` of the first and second half of ``range(n)`` (:func:`halves`), in that order: a
    fixed split, so a sum of the results does not depend on which finishes first; on two
    threads where there are two cores and two bands (:func:`recon.kernels.each`)."""
    return each(fn, halves(n)) if n > 1 else [fn(h) for h in halves(n)]


def halves(n: int) -> list[range]:
    """``range(n)`` cut in two, the first half the longer: how the blurs split a view's
    bands between two threads, the same on any number of cores."""
    return [range(0, (n + 1) // 2), range((n + 1) // 2, n)]


def _fast_even(n: int) -> int:
    """The least even size at least ``n`` that OpenCV transforms fast (2^a 3^b 5^c)."""
    import cv2

    m = cv2.getOptimalDFTSize(int(n))
    while m % 2:
        m = cv2.getOptimalDFTSize(m + 1)
    return m


def ccs_multiplier(spectrum: np.ndarray) -> np.ndarray:
    """A real spectrum (H, W/2 + 1), as from ``rfft2`` of an even kernel, laid out as
    OpenCV's packed (CCS) transform of an (H, W) real image, both sizes even: the factor each
    element of such a transform is multiplied by.

    Columns ``2k−1, 2k`` hold frequency ``k``'s real and imaginary parts (0 < k < W/2); the
    first and last columns hold frequencies 0 and W/2 packed down the rows alike (row 0 and
    row H−1 the real values at 0 and H/2).
    """
    K = np.asarray(spectrum, np.float64)
    H, wh = K.shape
    W = 2 * (wh - 1)
    if H % 2 or W < 2:
        raise ValueError(f"even sizes only, got a ({H}, {wh}) half spectrum")
    out = np.empty((H, W), np.float64)
    out[:, 1:W - 1:2] = K[:, 1:W // 2]
    out[:, 2:W - 1:2] = K[:, 1:W // 2]
    for col, kx in ((0, 0), (W - 1, W // 2)):
        out[0, col] = K[0, kx]
        out[1:H - 1:2, col] = K[1:H // 2, kx]
        out[2:H - 1:2, col] = K[1:H // 2, kx]
        out[H - 1, col] = K[H // 2, kx]
    return out.astype(np.float32)


@njit(cache=True, nogil=True, inline="always")
def _packed_row(i, H):
    """The spectrum's row whose factor row ``i`` of the packed layout's first and last columns
    takes (row 0: frequency 0; rows 2m − 1, 2m: m; row H − 1: H/2)."""
    return 0 if i == 0 else (H // 2 if i == H - 1 else (i + 1) // 2)


@njit(cache=True, nogil=True, fastmath={"contract"})
def ccs_multiply(out, a, k):
    """``out = a · K`` for a packed (CCS) transform ``a`` (H, W) and a real spectrum ``k``
    (H, W/2 + 1): the element-wise product with :func:`ccs_multiplier` of ``k``, without
    laying it out (``out`` may be ``a``)."""
    H, W = a.shape
    for i in range(H):
        m = _packed_row(i, H)
        out[i, 0] = a[i, 0] * k[m, 0]
        out[i, W - 1] = a[i, W - 1] * k[m, W // 2]
        o, u, q = out[i], a[i], k[i]
        for kx in range(1, W // 2):
            f = q[kx]
            o[2 * kx - 1] = u[2 * kx - 1] * f
            o[2 * kx] = u[2 * kx] * f


@njit(cache=True, nogil=True, fastmath={"contract"})
def ccs_multiply_add(acc, a, k, b, kb, two=True):
    """``acc += a · K (+ b · Kb)``: :func:`ccs_multiply`'s products of one or two packed
    transforms added in one pass, ``a``'s first (the sum is the same to the bit as two
    passes: each product is added as it is, in that order)."""
    H, W = acc.shape
    for i in range(H):
        m = _packed_row(i, H)
        for c, kx in ((0, 0), (W - 1, W // 2)):
            x = acc[i, c] + a[i, c] * k[m, kx]
            if two:
                x = x + b[i, c] * kb[m, kx]
            acc[i, c] = x
        o, u, q = acc[i], a[i], k[i]
        if two:
            v, qb = b[i], kb[i]
            for kx in range(1, W // 2):
                f, g = q[kx], qb[kx]
                c = 2 * kx - 1
                o[c] = (o[c] + u[c] * f) + v[c] * g
                o[c + 1] = (o[c + 1] + u[c + 1] * f) + v[c + 1] * g
        else:
            for kx in range(1, W // 2):
                f = q[kx]
                c = 2 * kx - 1
                o[c] = o[c] + u[c] * f
                o[c + 1] = o[c + 1] + u[c + 1] * f


def _as_cube(irradiance: np.ndarray, wavelengths) -> tuple[np.ndarray, np.ndarray]:
    e = np.asarray(irradiance)
    if e.ndim == 2:
        e = e[:, :, None]
    wl = np.atleast_1d(np.asarray(wavelengths, dtype=np.float64))
    if e.ndim != 3 or e.shape[2] != wl.size:
        raise InputError(
            f"irradiance must be (H, W, L) with L = {wl.size} bands, got shape {np.shape(irradiance)}"
        )
    if not np.all(np.isfinite(e)) or np.any(e < 0):
        raise InputError("irradiance must be finite and non-negative")
    return e, wl


def mean_electrons(
    irradiance: np.ndarray,
    design,
    wavelengths=None,
    *,
    diffraction: bool = False,
    widths=None,
) -> np.ndarray:
    """Expected photo-electrons per pixel, :math:`\\bar N_e`, summed over bands.

    Parameters
    ----------
    irradiance : ndarray, (H, W, L) or (H, W)
        Spectral irradiance on the sensor per band, W·m⁻²·nm⁻¹.
    design : sim.optics.design.Design
        Pixel size, exposure, QE curve, imaging f-number, band step.
    wavelengths : array_like, optional
        Band centres (nm); the design's bands by default.
    diffraction : bool
        Blur each band with its Airy kernel before summation.
    widths : array_like (L,), optional
        Band widths Δλ (nm); :func:`electron_scale`'s default otherwise.

    Returns
    -------
    numpy.ndarray
        float32 (H, W).
    """
    wl = design.wavelengths if wavelengths is None else wavelengths
    e, wl = _as_cube(irradiance, wl)
    scale = electron_scale(design, wl, widths)
    out = np.zeros(e.shape[:2], dtype=np.float32)
    for band in range(wl.size):  # a loop over bands keeps memory to one image per step
        img = e[:, :, band].astype(np.float32, copy=False)
        if diffraction:
            r_px = float(design.airy_radius_um(wl[band])) / design.sensor_pixel_um
            img = airy_blur(img, r_px)
        out += np.float32(scale[band]) * img
    return out


#: Rows of a frame per block of :func:`digitise`'s read noise (the draws continue one stream,
#: so the block size does not change them): the frame's float64 normals are never all held.
_READOUT_ROWS = 256
# Below this share of lit pixels a block's Poisson counts are drawn for the lit ones only.
_SPARSE_FRACTION = 0.5


def digitise(
    electrons: np.ndarray,
    design,
    *,
    rng: np.random.Generator | None = None,
    seed: int | None = None,
    noise: bool = True,
) -> np.ndarray:
    """Shot noise, full-well clipping, read noise and the ADC: mean electrons → DN (float32).

    Without ``noise`` the mean is clipped at the full well and quantised. ``rng`` (or ``seed``)
    makes the noise reproducible.

    The draws are NumPy's (all the Poisson counts of the frame, then one normal a pixel, in
    the frame's order); the arithmetic after them runs in one compiled pass
    (:func:`_readout`) over blocks of rows, the read noise drawn block by block (the same
    stream), and gives the same frame to the bit as :func:`digitise_reference`, the plain
    NumPy expression of the model, which the tests compare it with.
    """
    ne = np.asarray(electrons)
    if not np.issubdtype(ne.dtype, np.floating):
        ne = ne.astype(np.float64)
    if not np.all(np.isfinite(ne)) or np.any(ne < 0):
        raise InputError("electron counts must be finite and non-negative")
    fw = float(design.full_well_e)
    gain = float(design.gain_e_per_dn)
    top = float(design.max_dn)
    if not noise:
        return digitise_reference(ne, design, noise=False)
    if rng is None:
        rng = np.random.default_rng(seed)
    shape = ne.shape
    flat = np.ascontiguousarray(ne).reshape(shape[0] if ne.ndim > 1 else 1, -1)
    rows = flat.shape[0]
    # The counts clipped at the full well, as float32 (half the memory of the draws' int64)
    # where every integer up to the full well is exact in it, float64 otherwise.
    counts = np.empty(flat.shape, np.float32 if fw <= 2.0 ** 24 else np.float64)
    for a in range(0, rows, _READOUT_ROWS):
        b = min(rows, a + _READOUT_ROWS)
        block = flat[a:b]
        lit = np.flatnonzero(block)
        if lit.size < _SPARSE_FRACTION * block.size:
            # NumPy's Poisson draw for a zero mean returns 0 without touching the stream, so
            # drawing only the lit pixels gives the same counts and leaves the stream where
            # the whole block would: a line capture is mostly dark, and a dark pixel's draw
            # costs a third of a lit one's.
            out_block = counts[a:b].reshape(-1)
            out_block[:] = 0
            if lit.size:
                drawn = np.empty(lit.size, counts.dtype)
                _clip_counts(rng.poisson(block.reshape(-1)[lit]), fw, drawn)
                out_block[lit] = drawn
        else:
            _clip_counts(rng.poisson(block), fw, counts[a:b])
    sigma = float(design.read_noise_e)
    out = np.empty(flat.shape, np.float32)
    for a in range(0, rows, _READOUT_ROWS):
        b = min(rows, a + _READOUT_ROWS)
        # normal(0, s) is 0 + s * standard_normal() draw for draw: the same stream.
        z = rng.standard_normal(size=(b - a, flat.shape[1])) if sigma > 0 else None
        _readout(counts[a:b], z if z is not None else counts[a:b], sigma if z is not None
                 else 0.0, z is not None, gain, top, out[a:b])
    return out.reshape(shape)


def digitise_reference(electrons: np.ndarray, design, *, rng: np.random.Generator | None = None,
                       seed: int | None = None, noise: bool = True) -> np.ndarray:
    """:func:`digitise` in plain NumPy (whole-frame float64 passes): the model as written in the
    module notes, the reference the compiled path is tested against."""
    ne = np.asarray(electrons, dtype=np.float64)
    if not np.all(np.isfinite(ne)) or np.any(ne < 0):
        raise InputError("electron counts must be finite and non-negative")
    fw = float(design.full_well_e)
    gain = design.gain_e_per_dn
    if noise:
        if rng is None:
            rng = np.random.default_rng(seed)
        e = np.minimum(rng.poisson(ne).astype(np.float64), fw)
        if design.read_noise_e > 0:
            e += rng.normal(0.0, design.read_noise_e, size=e.shape)
    else:
        e = np.minimum(ne, fw)
    return np.clip(np.rint(e / gain), 0, design.max_dn).astype(np.float32)


@njit(cache=True, nogil=True)
def _clip_counts(counts, full_well, out):
    """``out = min(counts, full_well)`` (exact: ``out`` holds every integer up to the full
    well)."""
    c, o = counts.reshape(-1), out.reshape(-1)
    for i in range(c.size):
        o[i] = min(np.float64(c[i]), full_well)


@njit(cache=True, nogil=True)
def _readout(counts, z, sigma, read_noise, gain, top, out):
    """``out = clip(rint((counts + sigma z) / gain), 0, top)`` in float64, then float32, element
    by element as NumPy's whole-array expression rounds it (no fast-math: the sum, the
    division and the rounding are IEEE's, so the frame is the same to the bit)."""
    c, o = counts.reshape(-1), out.reshape(-1)
    zz = z.reshape(-1)
    for i in range(c.size):
        e = np.float64(c[i])
        if read_noise:
            e = e + (0.0 + sigma * zz[i])
        d = np.rint(e / gain)
        o[i] = np.float32(min(max(d, 0.0), top))


def capture(
    irradiance: np.ndarray,
    design,
    wavelengths=None,
    *,
    rng: np.random.Generator | None = None,
    seed: int | None = None,
    diffraction: bool = False,
    noise: bool = True,
    auto_exposure: float | None = None,
) -> np.ndarray:
    """A raw frame in DN (float32, 0 … 2^bit_depth − 1) from spectral irradiance on the sensor.

    Parameters
    ----------
    irradiance, design, wavelengths, diffraction
        As in :func:`mean_electrons`.
    rng, seed
        Noise source (a ``numpy.random.Generator``, or a seed for one).
    noise
        Photon shot noise and read noise on (default) or off.
    auto_exposure : float, optional
        When given, rescale the irradiance so that the brightest pixel's expected charge is this
        fraction of the full well (the irradiance's units then no longer matter); useful for
        scenes in relative radiance.
    """
    ne = mean_electrons(irradiance, design, wavelengths, diffraction=diffraction)
    if auto_exposure is not None:
        if not 0 < auto_exposure:
            raise InputError("auto_exposure must be a positive fraction of the full well")
        peak = float(ne.max())
        if peak > 0:
            ne *= np.float32(auto_exposure * design.full_well_e / peak)
    return digitise(ne, design, rng=rng, seed=seed, noise=noise)
