r"""The sensor's noise, measured as a lab does it: a photon-transfer curve from a pair of frames.

A raw pixel with mean :math:`\mu` (DN) has variance

.. math:: \sigma^2(\mu) = \frac{\mu}{G} + \frac{\sigma_r^2}{G^2} + \frac{1}{12}
          \;=\; a\,\mu + b,

shot noise (:math:`G` e⁻/DN, the conversion gain), read noise :math:`\sigma_r` (e⁻) and the
ADC's rounding (EMVA 1288).  Two frames :math:`A, B` of one static target with one exposure
give, per pixel, :math:`(A + B)/2` for :math:`\mu` and :math:`(A - B)^2 / 2` for
:math:`\sigma^2`, free of the target's pattern and of the optics (the difference cancels
both); grouping pixels by their mean and fitting a line through the groups' mean variances
gives :math:`(a, b)`.  A coded capture shows every level from the chrome's dark to the open
cells' bright in one frame, so one pair covers the curve; more pairs of the same target are
pooled (their pixels grouped together), which narrows the fit's spread by about the square
root of their number.

:func:`noise_rms` then gives the noise a measurement carries, which sets the reconstruction's
TV weight (:func:`kaleidospec.reconstruct.tv_weight`).
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError

__all__ = ["photon_transfer", "noise_rms", "check_noise_model"]

#: Pixels within this fraction of the top code are left out of the fit (the full well clips
#: the shot noise there), and those below ``DARK`` of it (the ADC clips the read noise at 0).
SATURATION = 0.9
DARK = 0.02


def photon_transfer(a, b, max_dn: float, *, bins: int = 64, min_pixels: int = 200
                    ) -> np.ndarray:
    r"""Fit :math:`\sigma^2(\mu) = a\mu + b` to a pair of raw frames of one static target.

    Parameters
    ----------
    a, b : array_like
        Two raw frames (DN) of the same target with the same exposure, any shape, equal; or
        stacks of such pairs (``a[i]``, ``b[i]``), pooled.
    max_dn : float
        The ADC's top code: pixels above :data:`SATURATION` of it, whose noise the full well
        clips, are left out; so are pixels below :data:`DARK` of it (the ADC clips at 0).
    bins : int
        Groups of pixels with equal counts, by their mean.
    min_pixels : int
        Fewest pixels a group needs.

    Returns
    -------
    (2,) float64
        ``[a, b]``: DN per DN of signal (:math:`1/G`) and the signal-free variance (DN²).

    Raises
    ------
    InputError
        Frames of other shapes or non-finite values, or too few levels to fit a line.
    """
    fa = np.asarray(a, dtype=np.float64).ravel()
    fb = np.asarray(b, dtype=np.float64).ravel()
    if fa.shape != fb.shape:
        raise InputError(f"a photon-transfer pair needs frames of one shape, got "
                         f"{np.shape(a)} and {np.shape(b)}")
    if not (np.all(np.isfinite(fa)) and np.all(np.isfinite(fb))):
        raise InputError("the photon-transfer frames must be finite")
    if not max_dn > 0:
        raise InputError(f"max_dn must be positive, got {max_dn}")
    mean = 0.5 * (fa + fb)
    # Selected and grouped by the pair's mean, which for Gaussian noise is independent of its
    # difference: a cut on either frame would truncate the differences near the cut.
    keep = (mean > DARK * max_dn) & (mean < SATURATION * max_dn)
    mean, var = mean[keep], 0.5 * (fa[keep] - fb[keep]) ** 2
    n_groups = min(int(bins), mean.size // max(int(min_pixels), 1))
    if n_groups < 4:
        raise InputError(f"too few unclipped pixels for a photon-transfer fit "
                         f"({mean.size}, at least {4 * int(min_pixels)})")
    order = np.argsort(mean, kind="stable")
    groups = np.array_split(order, n_groups)
    mu = np.array([mean[g].mean() for g in groups])
    v = np.array([var[g].mean() for g in groups])
    if np.ptp(mu) <= 0:
        raise InputError("the photon-transfer frames show a single level: no slope to fit")
    # Each group's mean variance has a relative error of about sqrt(2/n): weigh by 1/σ², σ ∝
    # the variance.  The weights come from the fitted line, not from the groups' own noisy
    # variances: those would favour the groups that came out low and bias the slope down
    # (by ~1 % with groups of a few hundred pixels).  A fit weighted by n first, then twice
    # reweighted by the line.
    n = np.array([len(g) for g in groups], np.float64)
    x = np.stack([mu, np.ones_like(mu)], axis=1)
    w = n / np.mean(v) ** 2
    for _ in range(3):
        coef = np.linalg.lstsq(x * np.sqrt(w)[:, None], v * np.sqrt(w), rcond=None)[0]
        w = n / np.maximum(x @ coef, 1e-6 * np.max(v)) ** 2
    return np.array([max(coef[0], 0.0), max(coef[1], 0.0)], np.float64)


def check_noise_model(model) -> np.ndarray:
    """``model`` as a (2,) float64 ``[a, b]``, both finite, ``a`` > 0, ``b`` >= 0."""
    m = np.asarray(model, dtype=np.float64)
    if m.shape != (2,) or not np.all(np.isfinite(m)) or m[0] <= 0 or m[1] < 0:
        raise InputError(f"a noise model is [a > 0, b >= 0] (variance a·DN + b), got "
                         f"{np.asarray(model).tolist()}")
    return m


def noise_rms(frame_dn, model) -> float:
    r"""The root-mean-square noise (DN) of a raw frame's pixels: :math:`\sqrt{\overline{a
    \max(\mu, 0) + b}}`, the frame standing in for its own mean (its noise barely moves the
    average of :math:`a\mu`)."""
    a, b = check_noise_model(model)
    g = np.asarray(frame_dn, dtype=np.float32)
    if g.size == 0:
        raise InputError("noise_rms needs a non-empty frame")
    mean_dn = float(np.maximum(g, 0.0).mean(dtype=np.float64))
    return float(np.sqrt(a * mean_dn + b))
