r"""Radiometric calibration: per-band gains from the 24 ColorChecker patches (paper Sec. 4.2).

The reconstruction :math:`f` of a band is proportional to the incident radiance :math:`l` up to
the sensor's quantum efficiency and the optics' throughput, :math:`f = q e l`.  The gain
:math:`c = (q e)^{-1}` is found per band by least squares over the patches :math:`p`:

.. math::

    c_\lambda = \arg\min_c \sum_p w_p (l_{p,\lambda} - c\, f_{p,\lambda})^2
              = \frac{\sum_p w_p f_{p,\lambda} l_{p,\lambda}}{\sum_p w_p f_{p,\lambda}^2}.

The reference radiances :math:`l_{p,\lambda}` (patch reflectance × illuminant, or a
spectroradiometer's readings) are inputs: this module never looks them up.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError


def patch_spectra(cube, patch_boxes, trim: float = 0.2) -> np.ndarray:
    """Mean spectrum of every patch of a reconstructed cube.

    Parameters
    ----------
    cube : (H, W, L) array_like
        Reconstructed cube (the API layout).
    patch_boxes : (P, 4) array_like
        ``y0, x0, h, w`` per patch.
    trim : float
        Fraction of each side of a patch left out (edges mix neighbouring patches).

    Returns
    -------
    (P, L) float64
    """
    c = np.asarray(cube, dtype=np.float64)
    if c.ndim != 3:
        raise InputError(f"cube must be (H, W, L), got shape {c.shape}")
    b = np.asarray(patch_boxes)
    if b.ndim != 2 or b.shape[1] != 4 or b.shape[0] == 0:
        raise InputError(f"patch_boxes must be (P, 4), got shape {b.shape}")
    if not 0 <= trim < 0.5:
        raise InputError(f"trim must be in [0, 0.5), got {trim}")
    out = np.empty((b.shape[0], c.shape[2]), dtype=np.float64)
    for i, (y0, x0, h, w) in enumerate(b.astype(np.int64)):
        dy, dx = int(h * trim), int(w * trim)
        region = c[y0 + dy:y0 + h - dy, x0 + dx:x0 + w - dx]
        if region.size == 0 or y0 < 0 or x0 < 0 or y0 + h > c.shape[0] or x0 + w > c.shape[1]:
            raise InputError(f"patch box {i} ({y0}, {x0}, {h}, {w}) is empty or outside the "
                             f"{c.shape[0]}x{c.shape[1]} cube")
        out[i] = region.mean(axis=(0, 1))
    return out


def fit_gains(reconstructed, reference, weights=None) -> np.ndarray:
    r"""Per-band gains :math:`c` with :math:`l \approx c\, f` (least squares over patches).

    Parameters
    ----------
    reconstructed : (P, L) array_like
        Patch spectra :math:`f` from the reconstruction (:func:`patch_spectra`).
    reference : (P, L) array_like
        Reference radiances :math:`l` of the same patches at the same bands.
    weights : (P,) array_like, optional
        Non-negative patch weights (e.g. to down-weight saturated patches).

    Returns
    -------
    (L,) float64

    Raises
    ------
    InputError
        Shape mismatch, non-finite values, or a band where every patch reconstructs to 0.
    """
    f = np.asarray(reconstructed, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    if f.ndim != 2 or f.shape != r.shape:
        raise InputError(f"reconstructed {f.shape} and reference {r.shape} spectra must both be "
                         "(P, L)")
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(r))):
        raise InputError("patch spectra must be finite")
    w = np.ones(f.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (f.shape[0],) or np.any(w < 0) or not np.all(np.isfinite(w)):
        raise InputError(f"weights must be {f.shape[0]} non-negative numbers")
    den = (w[:, None] * f * f).sum(axis=0)
    if np.any(den <= 0):
        bad = np.nonzero(den <= 0)[0].tolist()
        raise InputError(f"bands {bad} reconstruct to zero on every patch: gain undefined")
    return (w[:, None] * f * r).sum(axis=0) / den


def apply_gains(cube, gains) -> np.ndarray:
    """Radiance :math:`l = c f` of an (H, W, L) cube, float32."""
    c = np.asarray(cube, dtype=np.float32)
    g = np.asarray(gains, dtype=np.float32)
    if c.ndim != 3 or g.shape != (c.shape[2],):
        raise InputError(f"gains must have one value per band: cube {c.shape}, gains {g.shape}")
    return c * g


def flat_field_gains(band_white, whites, exposures, margin: int = 10,
                     floor: float = 0.05) -> np.ndarray:
    r"""Per-band gains with which a calibrated model reproduces the flat field itself.

    Band :math:`l`'s white of unit radiance reads :math:`d_l = W_l / e_l` (the captured view
    crops over the capture's exposure factor); the model of that white with unit gains is
    :math:`m_l = H 1_l`.  The gain is the :math:`c_l` for which :math:`m_l / c_l` fits
    :math:`d_l` best in least squares,

    .. math:: c_l = \frac{\langle m_l, m_l\rangle}{\langle m_l, d_l\rangle},

    over the pixels where :math:`m_l` reaches ``floor`` × its maximum, ``margin`` pixels inside
    the crops' edges (where a model's image ends, light from beyond the box may not).  Where the
    model is the white itself (mask images that are the whites over their level) this is the
    level's own gain; where the model blurs deconvolved mask images again, it is not: the
    level of a blurred white is not the level of its deconvolution.

    Parameters
    ----------
    band_white : callable
        ``band_white(l)`` → (K, h, w) :math:`m_l`.
    whites : (K, L, h, w) array_like
        The whites' view crops (DN), the boxes the model measures.
    exposures : (L,) array_like
        :math:`e_l`, each white's exposure factor (radiance units per cube unit).

    Returns
    -------
    (L,) float64
    """
    w = np.asarray(whites)
    e = np.asarray(exposures, dtype=np.float64)
    if w.ndim != 4 or e.shape != (w.shape[1],) or not np.all(e > 0):
        raise InputError(f"whites (K, L, h, w) and L positive exposures, got {w.shape} and "
                         f"{e.shape}")
    if min(w.shape[2:]) <= 2 * margin:
        raise InputError(f"crops of {w.shape[2:]} px leave nothing inside a {margin} px margin")
    inner = (slice(None), slice(margin, -margin), slice(margin, -margin))
    out = np.empty(w.shape[1])
    for l in range(w.shape[1]):
        m = np.asarray(band_white(l), dtype=np.float64)[inner]
        d = w[:, l][inner].astype(np.float64) / e[l]
        sel = m > floor * m.max()
        num = float(np.vdot(m[sel], m[sel]))
        den = float(np.vdot(m[sel], d[sel]))
        if not (num > 0 and den > 0):
            raise InputError(f"band {l}: the model of the white or the white itself is dark")
        out[l] = num / den
    return out
